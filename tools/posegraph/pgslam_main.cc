// omni-posegraph-slam: the online pose-graph mapper run offline over a log, as fast as it can.
// `./omni slam posegraph INPUT --out DIR` reaches it through omni-slam.
//   INPUT: CARMEN (.clf, .log, gzip too) or an LCM log (LIDAR_SCAN + WHEEL_ODOM).
//   DIR/trajectory.txt   scan_index timestamp x y theta, every accepted scan, final estimate
//   DIR/live_trajectory.txt   the same form: each scan's estimate when it was accepted (POSE_PG)
//   DIR/map.{pgm,yaml,png}, DIR/map_trajectory.png   grid of the optimised keyframes
//   DIR/graph.g2o        keyframe graph at the final estimate
//   DIR/stats.json       counters, wall time, window-update latency
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "omni/bus/slam_log.h"
#include "omni/common/time.h"
#include "omni/io/trajectory_io.h"
#include "omni/pose_graph_mapper/pose_graph_slam.h"
#include "omni/pose_graph_mapper/slam_outputs.h"

namespace fs = std::filesystem;

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-posegraph-slam INPUT --out DIR [--config FILE] [--max-scans N] [--quiet]\n"
      "  Online pose-graph SLAM (keyframes, scan matching, sliding window, verified loop\n"
      "  closures with global optimisation) over a CARMEN log (.clf/.log, gzip too) or an LCM\n"
      "  log (LIDAR_SCAN + WHEEL_ODOM). Writes DIR/trajectory.txt (every scan, the final\n"
      "  estimate), DIR/live_trajectory.txt (each scan's estimate when it was accepted, what the\n"
      "  process publishes on POSE_PG), DIR/map.pgm, map.yaml, map.png, map_trajectory.png,\n"
      "  DIR/graph.g2o and DIR/stats.json.\n"
      "  --config FILE   default: the built-in defaults (see config/pose_graph_mapper.yaml)\n");
}

}  // namespace

int main(int argc, char** argv) {
  std::string input, out_dir, config_path;
  long long max_scans = -1;
  bool quiet = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto val = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "omni-posegraph-slam: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--help" || a == "-h") {
      Usage(stdout);
      return 0;
    } else if (a == "--out") {
      out_dir = val();
    } else if (a == "--config") {
      config_path = val();
    } else if (a == "--max-scans") {
      const std::string v = val();
      char* end = nullptr;
      max_scans = std::strtoll(v.c_str(), &end, 10);
      if (v.empty() || *end != '\0' || max_scans < 0) {
        std::fprintf(stderr, "omni-posegraph-slam: --max-scans expects a count, got '%s'\n",
                     v.c_str());
        return 2;
      }
    } else if (a == "--quiet") {
      quiet = true;
    } else if (!a.empty() && a[0] == '-') {
      std::fprintf(stderr, "omni-posegraph-slam: unknown option '%s'\n", a.c_str());
      Usage(stderr);
      return 2;
    } else if (input.empty()) {
      input = a;
    } else {
      std::fprintf(stderr, "omni-posegraph-slam: unexpected argument '%s'\n", a.c_str());
      return 2;
    }
  }
  if (input.empty() || out_dir.empty()) {
    std::fprintf(stderr, "omni-posegraph-slam: INPUT and --out DIR are required\n");
    Usage(stderr);
    return 2;
  }
  if (!fs::exists(input)) {
    std::fprintf(stderr, "omni-posegraph-slam: input '%s' does not exist\n", input.c_str());
    return 1;
  }
  omni::pgm::PoseGraphSlamOptions opt;
  omni::pgm::BatchOptions batch;
  if (!config_path.empty()) {
    if (omni::Status s = omni::pgm::LoadSlamConfigFile(config_path, &opt, &batch); !s.ok()) {
      std::fprintf(stderr, "omni-posegraph-slam: bad config:\n%s\n", s.message().c_str());
      return 1;
    }
  }
  if (omni::Status s = opt.Validate(); !s.ok()) {
    std::fprintf(stderr, "omni-posegraph-slam: %s\n", s.message().c_str());
    return 2;
  }
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (ec) {
    std::fprintf(stderr, "omni-posegraph-slam: cannot create '%s': %s\n", out_dir.c_str(),
                 ec.message().c_str());
    return 1;
  }

  const int64_t t_start = omni::MonotonicMicros();
  omni::SystemClock clock;
  omni::pgm::PoseGraphSlam slam(opt, batch, &clock);
  int64_t scans = 0;
  std::vector<omni::io::TrajectoryEntry> live;  // each scan's pose when accepted (POSE_PG)
  auto record_live = [&]() {
    omni::pgm::ScanPose sp;
    if (slam.LastScanPose(&sp))
      live.push_back(omni::io::MakeEntry2D(sp.scan_index, omni::UtimeToSeconds(sp.utime), sp.pose));
  };
  // Odometry as the node hands it over: when it proves a clock step back, the scans held
  // meanwhile are mapped and the newest one's pose is what the node publishes.
  auto add_odometry = [&](int64_t utime, const omni::Pose2& p) {
    const int64_t replayed = slam.counters().scans_replayed;
    slam.AddOdometry(utime, p);
    if (slam.counters().scans_replayed > replayed) record_live();
  };
  auto progress = [&]() {
    if (!quiet && scans % 1000 == 0)
      std::fprintf(stderr, "omni-posegraph-slam: scan %lld, %zu keyframes, %lld loops\n",
                   static_cast<long long>(scans), slam.keyframes().size(),
                   static_cast<long long>(slam.counters().loops_accepted));
  };
  omni::bus::SlamLogHandlers handlers;
  handlers.scan = [&](const omni::bus::SlamScan& in) {
    if (max_scans >= 0 && scans >= max_scans) return false;
    omni::pgm::LaserScan2 s;
    s.utime = in.utime;
    s.laser_in_base = in.sensor_in_base;
    s.angle_min_rad = in.angle_min_rad;
    s.angle_increment_rad = in.angle_increment_rad;
    if (in.range_min_m) s.min_range_m = *in.range_min_m;
    s.max_range_m = in.range_max_m;
    s.ranges_m = in.ranges_m;
    s.scan_time_s = in.scan_time_s;
    // A CARMEN laser line carries the odometry pose at the scan.
    if (in.odom) add_odometry(s.utime, *in.odom);
    if (slam.AddScan(scans, s)) record_live();
    ++scans;
    progress();
    return !(max_scans >= 0 && scans >= max_scans);
  };
  handlers.odom = add_odometry;
  // The gyro (an LCM log's IMU channel) is read only when the config enables it.
  if (opt.use_gyro)
    handlers.imu = [&](int64_t utime, double rate) { slam.AddImuYawRate(utime, rate); };
  auto read = omni::bus::ReadSlamLog(input, omni::bus::SlamLogChannels{}, handlers);
  if (!read.ok()) {
    std::fprintf(stderr, "omni-posegraph-slam: %s\n", read.error().message.c_str());
    return 1;
  }
  omni::bus::ReportSlamLogProblems("omni-posegraph-slam", input, *read);
  slam.Finish();
  omni::pgm::SlamRunInfo info;
  info.input = input;
  info.decode_errors = read->decode_errors;
  info.extra.emplace_back("skipped_bytes", static_cast<int64_t>(read->skipped_bytes));
  info.extra.emplace_back("stopped_early", read->stopped_early.empty() ? 0 : 1);
  info.extra.emplace_back("scans_repeated", read->scans_repeated);
  info.extra.emplace_back("scans_lost_in_log", read->scans_lost);
  info.window_size = opt.window_size;
  info.wall_s = static_cast<double>(omni::MonotonicMicros() - t_start) * 1e-6;
  omni::Status written = omni::pgm::WriteSlamOutputs(slam, out_dir, info);
  if (written.ok())
    written = omni::io::WriteTrajectory2D(
        out_dir + "/live_trajectory.txt", live,
        "scan_index timestamp x y theta (pose-graph SLAM, each scan when accepted, as POSE_PG)");
  if (omni::Status s = written; !s.ok()) {
    std::fprintf(stderr, "omni-posegraph-slam: %s\n", s.message().c_str());
    return 1;
  }
  const auto& c = slam.counters();
  const auto& lat = slam.window_latency_ms();
  using omni::pgm::Percentile;
  const double wall_s = info.wall_s;
  std::printf(
      "omni-posegraph-slam: %lld scans (%lld used), %lld keyframes (%lld retired, %lld removed), "
      "%lld loops "
      "(%lld rejected), %lld global optimisations, window p50/p99 %.2f/%.2f ms, %.1f s -> "
      "%s/{trajectory.txt,live_trajectory.txt,map.*,graph.g2o,stats.json}\n",
      static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_used),
      static_cast<long long>(c.keyframes), static_cast<long long>(c.keyframes_retired),
      static_cast<long long>(c.keyframes_removed), static_cast<long long>(c.loops_accepted),
      static_cast<long long>(c.loops_rejected), static_cast<long long>(c.global_optimizations),
      Percentile(lat, 0.5), Percentile(lat, 0.99), wall_s, out_dir.c_str());
  return 0;
}
