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
#include <tuple>
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

// The text as a --config file; an error from the reader itself (not YAML) names the file.
omni::Result<omni::ConfigReader> Open(const std::string& text) {
  auto r = omni::ConfigReader::FromString(text, "fuzz.yaml");
  if (!r.ok()) OMNI_FUZZ_CHECK(r.error().message.find("fuzz.yaml") != std::string::npos);
  return r;
}

// Loaders that read the text themselves, or an open reader into one struct.
template <class Options>
void CheckLoaded(const omni::Result<Options>& o) {
  if (!o.ok()) CheckError(o.error().message);
}

template <class Options>
void Load(const std::string& text) {
  if (auto r = Open(text); r.ok()) CheckLoaded(Options::Load(*r));
}

// Loaders that fill several option structs from a reader and Finish() it (the pose graph's
// slam/batch/node, each driver's driver/node).
template <class... Out>
void LoadInto(const std::string& text, omni::Status (*load)(omni::ConfigReader&, Out*...)) {
  auto r = Open(text);
  if (!r.ok()) return;
  std::tuple<Out...> out;
  const omni::Status s = std::apply([&](Out&... o) { return load(*r, &o...); }, out);
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
    case kPoseGraph:
      LoadInto(text, &omni::pgm::LoadSlamConfig);
      break;
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
    case kBaseBridge:
      CheckLoaded(omni::base_bridge::LoadBaseBridgeOptionsFromString(text, "fuzz.yaml"));
      break;
    case kRplidar:
      LoadInto(text, &omni::rplidar::LoadRplidarOptions);
      break;
    case kImu:
      LoadInto(text, &omni::imu::LoadImuOptions);
      break;
    case kKinect:
      LoadInto(text, &omni::kinect::LoadKinectOptions);
      break;
    default:
      CheckLoaded(omni::firmware::sim::LoadSimOptionsFromString(text, "fuzz.yaml"));
      break;
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
