// pose_graph_mapper process: LIDAR_SCAN + WHEEL_ODOM -> POSE_PG, TRAJECTORY_PG, GRID_PG,
// HEARTBEAT; on SIGINT/SIGTERM, at the end of a file:// log, or after --idle-exit seconds
// without messages, writes DIR/{trajectory.txt, map.pgm, map.yaml, map.png, map_trajectory.png,
// graph.g2o, stats.json}.
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/bus/bus.h"
#include "omni/bus/map_save.h"
#include "omni/bus/node_loop.h"
#include "omni/common/cli.h"
#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/common/time.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/previous_outputs.h"
#include "omni/pose_graph_mapper/pose_graph_node.h"

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: pose_graph_mapper [--config FILE] [--out DIR] [--url LCM_URL] [--idle-exit S]\n"
      "  Pose-graph SLAM on the bus: LIDAR_SCAN + WHEEL_ODOM -> POSE_PG at every accepted scan,\n"
      "  TRAJECTORY_PG and GRID_PG at the intervals of the config's `node` section, HEARTBEAT.\n"
      "  On SIGINT/SIGTERM, when a file:// log ends, or S seconds after the last message,\n"
      "  writes DIR/trajectory.txt, map.{pgm,yaml,png}, map_trajectory.png, graph.g2o and\n"
      "  stats.json (default DIR: out/posegraph); while mapping, on a MAP_SAVE request (omni\n"
      "  save-map) too. DIR is this process's while it runs: another process writing it is\n"
      "  refused.\n"
      "  --config FILE   config/pose_graph_mapper.yaml form; default: built-in defaults\n");
}

}  // namespace

int main(int argc, char** argv) {
  omni::MapperArgs m;
  m.out = "out/posegraph";
  omni::ArgReader args(argc, argv, "pose_graph_mapper", Usage);
  while (args.Next()) {
    if (omni::ReadMapperArg(args, &m)) continue;
    args.Unknown();
  }
  std::string config_path = m.config, out_dir = m.out, url = m.url;
  const double idle_exit_s = m.idle_exit_s;
  omni::SetLogProcessName("pose_graph_mapper");
  omni::pgm::PoseGraphSlamOptions slam_opt;
  omni::pgm::BatchOptions batch;
  omni::pgm::PoseGraphNodeOptions node_opt;
  if (!config_path.empty()) {
    if (omni::Status s = omni::pgm::LoadSlamConfigFile(config_path, &slam_opt, &batch, &node_opt);
        !s.ok()) {
      std::fprintf(stderr, "pose_graph_mapper: bad config:\n%s\n", s.message().c_str());
      return 1;
    }
  }
  if (omni::Status s = slam_opt.Validate(); !s.ok()) {
    std::fprintf(stderr, "pose_graph_mapper: %s\n", s.message().c_str());
    return 2;
  }
  const auto out_lock = omni::io::ClaimOutputFolder(out_dir, "pose_graph_mapper",
                                                    omni::pgm::PoseGraphNode::OutputFiles());
  if (!out_lock.ok()) {
    std::fprintf(stderr, "pose_graph_mapper: %s\n", out_lock.error().message.c_str());
    return 1;
  }
  auto bus_or = omni::bus::Bus::Create(url);
  if (!bus_or.ok()) {
    std::fprintf(stderr, "pose_graph_mapper: %s\n", bus_or.error().message.c_str());
    return 1;
  }
  auto& bus = **bus_or;
  const int64_t t_start = omni::MonotonicMicros();
  omni::SystemClock clock;
  omni::pgm::PoseGraphNode node(&bus, node_opt, slam_opt, batch, &clock);
  omni::bus::InstallStopSignals();
  omni::FixMallocThresholds();  // large buffers go back to the system when freed
  LOG_INFO << "listening on " << node_opt.scan_channel << " + " << node_opt.odom_channel << " (bus "
           << (url.empty() ? "default" : url) << "), window of " << slam_opt.window_size
           << " keyframes";
  node.set_deferred(true);
  auto run_info = [&] {
    omni::pgm::SlamRunInfo info;
    info.system = "pose_graph_mapper";
    info.input = url.empty() ? "bus (default url)" : url;
    info.window_size = slam_opt.window_size;
    info.wall_s = static_cast<double>(omni::MonotonicMicros() - t_start) * 1e-6;
    return info;
  };
  omni::bus::MapSaveService saver(&bus, "pose_graph_mapper", out_dir, &clock, &node.heartbeat());
  omni::bus::NodeLoopOptions loop;
  loop.idle_exit_s = idle_exit_s;
  const omni::bus::LoopEnd end = omni::bus::RunNodeLoop(
      bus, loop, [&] { return node.ProcessReady(1); },
      [&] {
        node.Tick();
        saver.Serve([&](const std::string& dir) { return node.SaveMaps(dir, run_info()); });
      });
  LOG_INFO << "stopping (" << omni::bus::LoopEndName(end) << "); optimising and writing the map";
  node.heartbeat().SetState(omni::heartbeat_t::STATE_STOPPING, "writing map");
  const omni::Status s = node.WriteOutputs(out_dir, run_info());
  const auto& c = node.slam().counters();
  if (!s.ok()) {
    std::fprintf(stderr, "pose_graph_mapper: %s\n", s.message().c_str());
    return omni::bus::NothingToWriteExit(end, c.scans_in);
  }
  std::printf(
      "pose_graph_mapper: %lld scans (%lld used, %lld lost on the bus, %lld without odometry), "
      "%lld keyframes, %lld loops, %lld poses, %lld trajectories and %lld grids published, %lld "
      "decode errors -> %s/{trajectory.txt,map.pgm,map.yaml,map.png,graph.g2o,stats.json}\n",
      static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_used),
      static_cast<long long>(node.scans_lost()), static_cast<long long>(c.scans_no_odom),
      static_cast<long long>(c.keyframes), static_cast<long long>(c.loops_accepted),
      static_cast<long long>(node.poses_published()),
      static_cast<long long>(node.trajectories_published()),
      static_cast<long long>(node.grids_published()),
      static_cast<long long>(bus.counters().decode_errors.load()), out_dir.c_str());
  return 0;
}
