// rbpf_mapper process: LIDAR_SCAN + WHEEL_ODOM (+ IMU) -> POSE_RBPF, GRID_RBPF, HEARTBEAT; on
// SIGINT/SIGTERM, at the end of a file:// log, or after --idle-exit seconds without messages,
// writes DIR/map.{pgm,yaml,png} and DIR/trajectory.txt.
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>

#include "omni/bus/bus.h"
#include "omni/bus/map_save.h"
#include "omni/bus/node_loop.h"
#include "omni/common/cli.h"
#include "omni/common/config.h"
#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/previous_outputs.h"
#include "omni/rbpf_mapper/rbpf_node.h"

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: rbpf_mapper [--config FILE] [--out DIR] [--url LCM_URL] [--idle-exit S]\n"
      "                   [--seed N]\n"
      "  RBPF SLAM on the bus: LIDAR_SCAN + WHEEL_ODOM (+ IMU with use_imu) ->\n"
      "  POSE_RBPF at every scan, GRID_RBPF every grid_publish_interval_s, HEARTBEAT.\n"
      "  On SIGINT/SIGTERM, when a file:// log ends, or S seconds after the last\n"
      "  message, writes DIR/map.{pgm,yaml,png} and DIR/trajectory.txt (default\n"
      "  out/rbpf); while mapping, on a MAP_SAVE request (omni save-map) too. DIR is this\n"
      "  process's while it runs: another process writing it is refused.\n");
}

}  // namespace

int main(int argc, char** argv) {
  omni::MapperArgs m;
  m.out = "out/rbpf";
  long long seed = -1;
  omni::ArgReader args(argc, argv, "rbpf_mapper", Usage);
  while (args.Next()) {
    if (omni::ReadMapperArg(args, &m)) continue;
    if (args.Is("--seed")) {
      seed = args.Integer(0, std::numeric_limits<int64_t>::max());
    } else {
      args.Unknown();
    }
  }
  std::string config_path = m.config, out_dir = m.out, url = m.url;
  const double idle_exit_s = m.idle_exit_s;
  omni::SetLogProcessName("rbpf_mapper");
  omni::rbpf::RbpfOptions opt;
  if (!config_path.empty()) {
    auto reader = omni::ConfigReader::FromFile(config_path);
    if (!reader.ok()) {
      std::fprintf(stderr, "rbpf_mapper: %s\n", reader.error().message.c_str());
      return 1;
    }
    auto loaded = omni::rbpf::RbpfOptions::Load(*reader);
    if (!loaded.ok()) {
      std::fprintf(stderr, "rbpf_mapper: bad config:\n%s\n", loaded.error().message.c_str());
      return 1;
    }
    opt = *loaded;
  }
  if (seed >= 0) opt.seed = static_cast<uint64_t>(seed);
  const auto out_lock =
      omni::io::ClaimOutputFolder(out_dir, "rbpf_mapper", omni::rbpf::RbpfNode::OutputFiles());
  if (!out_lock.ok()) {
    std::fprintf(stderr, "rbpf_mapper: %s\n", out_lock.error().message.c_str());
    return 1;
  }
  auto bus_or = omni::bus::Bus::Create(url);
  if (!bus_or.ok()) {
    std::fprintf(stderr, "rbpf_mapper: %s\n", bus_or.error().message.c_str());
    return 1;
  }
  auto& bus = **bus_or;
  omni::SystemClock clock;
  omni::rbpf::RbpfNode node(&bus, opt, &clock);
  omni::bus::InstallStopSignals();
  omni::FixMallocThresholds();  // large buffers go back to the system when freed
  LOG_INFO << "listening on " << opt.scan_channel << " + " << opt.odom_channel << " (bus "
           << (url.empty() ? "default" : url) << "), " << opt.particles << " particles";
  node.set_deferred(true);
  omni::bus::MapSaveService saver(&bus, "rbpf_mapper", out_dir, &clock, &node.heartbeat());
  omni::bus::NodeLoopOptions loop;
  loop.idle_exit_s = idle_exit_s;
  const omni::bus::LoopEnd end = omni::bus::RunNodeLoop(
      bus, loop, [&] { return node.ProcessReady(1); },
      [&] {
        node.Tick();
        saver.Serve([&](const std::string& dir) { return node.SaveMaps(dir); });
      });
  LOG_INFO << "stopping (" << omni::bus::LoopEndName(end) << "); writing the map";
  node.heartbeat().SetState(omni::heartbeat_t::STATE_STOPPING, "writing map");
  const omni::Status s = node.WriteOutputs(out_dir);
  const auto& c = node.slam().counters();
  if (!s.ok()) {
    std::fprintf(stderr, "rbpf_mapper: %s (scans in %lld, no odometry %lld, too few beams %lld)\n",
                 s.message().c_str(), static_cast<long long>(c.scans_in),
                 static_cast<long long>(c.scans_no_odom),
                 static_cast<long long>(c.scans_too_few_beams));
    return omni::bus::NothingToWriteExit(end, c.scans_in);
  }
  std::printf(
      "rbpf_mapper: %lld scans (%lld filter updates, %lld lost on the bus, %lld without "
      "odometry), %lld poses and %lld grids published, %lld resamplings, %lld match failures, "
      "%lld decode errors -> %s/{map.pgm,map.yaml,map.png,trajectory.txt}\n",
      static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_processed),
      static_cast<long long>(node.scans_lost()), static_cast<long long>(c.scans_no_odom),
      static_cast<long long>(node.poses_published()),
      static_cast<long long>(node.grids_published()), static_cast<long long>(c.resamplings),
      static_cast<long long>(c.match_failures),
      static_cast<long long>(bus.counters().decode_errors.load()), out_dir.c_str());
  return 0;
}
