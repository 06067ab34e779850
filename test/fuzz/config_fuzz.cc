// YAML text into the processes' option loaders, as each process reads its --config file: the
// first byte picks the loader (RBPF mapper, pose-graph mapper, OctoMap builder, map fusion,
// odometry mapper, supervisor, base bridge, the RPLidar, IMU and Kinect drivers, the firmware
// simulator), the rest is the file. What must hold: a loader
// returns options or an error, never an exception or a crash, whatever the text (lists or maps
// as keys, anchors and aliases, tags, deep nesting, numbers out of range, wrong types); and an
// error from the reader names the file. Seeds: the shipped files in config/ and a few
// hand-made ones.
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "fuzz.h"
#include "omni/base_bridge/base_bridge.h"
#include "omni/common/config.h"
#include "omni/imu/driver.h"
#include "omni/kinect/kinect_driver.h"
#include "omni/map_fusion/fusion.h"
#include "omni/octomap_builder/octomap_builder.h"
#include "omni/odom_mapper/odom_mapper.h"
#include "omni/pose_graph_mapper/pose_graph_slam.h"
#include "omni/rbpf_mapper/rbpf.h"
#include "omni/rplidar/driver.h"
#include "omni/supervisor/supervisor.h"
#include "sim_config.h"

namespace {

enum Loader : uint8_t {
  kRbpf,
  kPoseGraph,
  kOctomap,
  kFusion,
  kOdomMapper,
  kSupervisor,
  kBaseBridge,
  kRplidar,
  kImu,
  kKinect,
  kFirmwareSim,
  kLoaders
};

// The loaders' own messages (cross-field rules) need not name the file; the reader's do.
void CheckError(const std::string& message) { OMNI_FUZZ_CHECK(!message.empty()); }

template <class Options>
void Load(const std::string& text) {
  auto r = omni::ConfigReader::FromString(text, "fuzz.yaml");
  if (!r.ok()) {
    OMNI_FUZZ_CHECK(r.error().message.find("fuzz.yaml") != std::string::npos);
    return;
  }
  auto o = Options::Load(*r);
  if (!o.ok()) CheckError(o.error().message);
}

// The drivers' loaders fill a driver and a node struct from a reader and Finish() it.
template <class Driver, class Node>
void LoadPair(const std::string& text, omni::Status (*load)(omni::ConfigReader&, Driver*, Node*)) {
  auto r = omni::ConfigReader::FromString(text, "fuzz.yaml");
  if (!r.ok()) return;
  Driver driver;
  Node node;
  const omni::Status s = load(*r, &driver, &node);
  if (!s.ok()) CheckError(s.message());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::string text(reinterpret_cast<const char*>(data) + 1, size - 1);
  switch (data[0] % kLoaders) {
    case kRbpf:
      Load<omni::rbpf::RbpfOptions>(text);
      break;
    case kPoseGraph: {
      auto r = omni::ConfigReader::FromString(text, "fuzz.yaml");
      if (!r.ok()) break;
      omni::pgm::PoseGraphSlamOptions slam;
      omni::pgm::BatchOptions batch;
      omni::pgm::PoseGraphNodeOptions node;
      const omni::Status s = omni::pgm::LoadSlamConfig(*r, &slam, &batch, &node);
      if (!s.ok()) CheckError(s.message());
      break;
    }
    case kOctomap:
      Load<omni::octo::OctomapBuilderOptions>(text);
      break;
    case kFusion:
      Load<omni::map_fusion::FusionOptions>(text);
      break;
    case kOdomMapper:
      Load<omni::odom_mapper::OdomMapperOptions>(text);
      break;
    case kSupervisor:
      Load<omni::supervisor::SupervisorOptions>(text);
      break;
    case kBaseBridge: {
      auto o = omni::base_bridge::LoadBaseBridgeOptionsFromString(text, "fuzz.yaml");
      if (!o.ok()) CheckError(o.error().message);
      break;
    }
    case kRplidar:
      LoadPair(text, &omni::rplidar::LoadRplidarOptions);
      break;
    case kImu:
      LoadPair(text, &omni::imu::LoadImuOptions);
      break;
    case kKinect:
      LoadPair(text, &omni::kinect::LoadKinectOptions);
      break;
    default: {
      auto o = omni::firmware::sim::LoadSimOptionsFromString(text, "fuzz.yaml");
      if (!o.ok()) CheckError(o.error().message);
      break;
    }
  }
  return 0;
}

void omni::fuzz::Seeds(SeedList* seeds) {
  // The shipped files, each with the byte of its loader (read in place from the source tree).
  const std::pair<Loader, const char*> shipped[] = {
      {kRbpf, "rbpf_mapper.yaml"},        {kPoseGraph, "pose_graph_mapper.yaml"},
      {kOctomap, "octomap_builder.yaml"}, {kFusion, "map_fusion.yaml"},
      {kOdomMapper, "odom_mapper.yaml"},  {kSupervisor, "supervisor.yaml"},
      {kBaseBridge, "base_bridge.yaml"},  {kRplidar, "rplidar_driver.yaml"},
      {kImu, "imu_driver.yaml"},          {kKinect, "kinect_driver.yaml"},
      {kFirmwareSim, "firmware_sim.yaml"}};
  for (const auto& [loader, file] : shipped) {
    const std::string path = std::string(OMNI_SOURCE_DIR) + "/config/" + file;
    std::ifstream in(path, std::ios::binary);
    if (!in) {
      seeds->missing.push_back(path);
      continue;
    }
    std::ostringstream text;
    text << in.rdbuf();
    seeds->Add(std::string(1, static_cast<char>(loader)) + text.str());
  }
  // What YAML allows and a config file should not hold.
  for (uint8_t loader = 0; loader < kLoaders; ++loader) {
    const std::string l(1, static_cast<char>(loader));
    seeds->Add(l + "? [a, b]\n: 1\n");
    seeds->Add(l + "{x: 1}: 2\nparticles: 3\n");
    seeds->Add(l + "a: &x {b: 1, c: [1, 2]}\nd: *x\ne: !!binary aGVsbG8=\n");
    seeds->Add(l + "particles: 1e400\nthreads: -0\nseed: 0x7fffffffffffffff\n");
    seeds->Add(l + std::string(40, '[') + std::string(40, ']') + "\n");
    seeds->Add(l + "slam: [1, 2]\nbatch: 3\nnode: ~\n");
  }
}
