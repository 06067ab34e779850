// omni-posegraph-slam: the online pose-graph mapper run offline over a log, as fast as it can.
// `./omni slam posegraph INPUT --out DIR` reaches it through omni-slam.
//   INPUT: CARMEN (.clf, .log, gzip too) or an LCM log (LIDAR_SCAN + WHEEL_ODOM).
//   DIR/trajectory.txt   scan_index timestamp x y theta, every accepted scan, final estimate
//   DIR/map.{pgm,yaml,png}, DIR/map_trajectory.png   grid of the optimised keyframes
//   DIR/graph.g2o        keyframe graph at the final estimate
//   DIR/stats.json       counters, wall time, window-update latency
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "omni/bus/slam_log.h"
#include "omni/common/time.h"
#include "omni/io/g2o.h"
#include "omni/io/grid.h"
#include "omni/io/image_io.h"
#include "omni/io/trajectory_io.h"
#include "omni/pose_graph_mapper/pose_graph_slam.h"

namespace fs = std::filesystem;

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-posegraph-slam INPUT --out DIR [--config FILE] [--max-scans N] [--quiet]\n"
      "  Online pose-graph SLAM (keyframes, scan matching, sliding window, verified loop\n"
      "  closures with global optimisation) over a CARMEN log (.clf/.log, gzip too) or an LCM\n"
      "  log (LIDAR_SCAN + WHEEL_ODOM). Writes DIR/trajectory.txt (every scan), DIR/map.pgm,\n"
      "  map.yaml, map.png, map_trajectory.png, DIR/graph.g2o and DIR/stats.json.\n"
      "  --config FILE   default: the built-in defaults (see config/pose_graph_mapper.yaml)\n");
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
  return v[i];
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
    // A CARMEN laser line carries the odometry pose at the scan.
    if (in.odom) slam.AddOdometry(s.utime, *in.odom);
    slam.AddScan(scans, s);
    ++scans;
    progress();
    return !(max_scans >= 0 && scans >= max_scans);
  };
  handlers.odom = [&](int64_t utime, const omni::Pose2& p) { slam.AddOdometry(utime, p); };
  auto read = omni::bus::ReadSlamLog(input, omni::bus::SlamLogChannels{}, handlers);
  if (!read.ok()) {
    std::fprintf(stderr, "omni-posegraph-slam: %s\n", read.error().message.c_str());
    return 1;
  }
  if (!read->stopped_early.empty())
    std::fprintf(stderr, "omni-posegraph-slam: %s (stopping there)\n", read->stopped_early.c_str());
  const int64_t decode_errors = read->decode_errors;
  slam.Finish();
  const auto traj = slam.Trajectory();
  const auto& c = slam.counters();
  if (traj.empty()) {
    std::fprintf(stderr,
                 "omni-posegraph-slam: no scan could be used (scans %lld, no odometry %lld, too "
                 "few beams %lld, time backwards %lld)\n",
                 static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_no_odom),
                 static_cast<long long>(c.scans_too_few_beams),
                 static_cast<long long>(c.scans_time_backwards));
    return 1;
  }
  std::vector<omni::io::TrajectoryEntry> entries;
  omni::io::Polyline line;
  for (const auto& e : traj) {
    entries.push_back(omni::io::MakeEntry2D(e.scan_index, omni::UtimeToSeconds(e.utime), e.pose));
    line.poses.push_back(e.pose);
  }
  const omni::io::GridMap map = slam.RenderMap({});
  omni::Status s = omni::io::WriteTrajectory2D(
      out_dir + "/trajectory.txt", entries,
      "scan_index timestamp x y theta (pose-graph SLAM, final optimised estimate)");
  if (s.ok()) s = omni::io::WriteMapServer(map, out_dir + "/map");
  if (s.ok()) s = omni::io::WritePng(out_dir + "/map.png", omni::io::RenderGrid(map, {}, 1));
  if (s.ok())
    s = omni::io::WritePng(out_dir + "/map_trajectory.png", omni::io::RenderGrid(map, {line}, 1));
  if (s.ok()) s = omni::io::WriteG2o(out_dir + "/graph.g2o", slam.Graph());
  if (!s.ok()) {
    std::fprintf(stderr, "omni-posegraph-slam: %s\n", s.message().c_str());
    return 1;
  }
  const double wall_s = static_cast<double>(omni::MonotonicMicros() - t_start) * 1e-6;
  const auto& lat = slam.window_latency_ms();
  const auto& glat = slam.global_latency_ms();
  std::FILE* f = std::fopen((out_dir + "/stats.json").c_str(), "w");
  if (!f) {
    std::fprintf(stderr, "omni-posegraph-slam: cannot write %s/stats.json: %s\n", out_dir.c_str(),
                 std::strerror(errno));
    return 1;
  }
  std::fprintf(
      f,
      "{\"system\": \"omni-posegraph\", \"input\": \"%s\", \"window_size\": %d, \"wall_s\": "
      "%.3f, \"scans\": %lld, \"scans_used\": %lld, \"scans_time_backwards\": %lld, "
      "\"scans_too_few_beams\": %lld, \"scans_no_odom\": %lld, \"invalid_beams\": %lld, "
      "\"odom_invalid\": %lld, \"odom_out_of_order\": %lld, \"odom_jumps\": %lld, "
      "\"decode_errors\": %lld, \"keyframes\": %lld, \"scan_match_factors\": %lld, "
      "\"scan_match_failures\": %lld, \"loops_accepted\": %lld, \"loops_rejected\": %lld, "
      "\"window_updates\": %lld, \"window_failures\": %lld, \"latency_p50_ms\": %.3f, "
      "\"latency_p99_ms\": %.3f, \"latency_max_ms\": %.3f, \"global_optimizations\": %lld, "
      "\"global_failures\": %lld, \"global_p50_ms\": %.3f, \"global_max_ms\": %.3f}\n",
      input.c_str(), opt.window_size, wall_s, static_cast<long long>(c.scans_in),
      static_cast<long long>(c.scans_used), static_cast<long long>(c.scans_time_backwards),
      static_cast<long long>(c.scans_too_few_beams), static_cast<long long>(c.scans_no_odom),
      static_cast<long long>(c.invalid_beams), static_cast<long long>(c.odom_invalid),
      static_cast<long long>(c.odom_out_of_order), static_cast<long long>(c.odom_jumps),
      static_cast<long long>(decode_errors), static_cast<long long>(c.keyframes),
      static_cast<long long>(c.scan_match_factors), static_cast<long long>(c.scan_match_failures),
      static_cast<long long>(c.loops_accepted), static_cast<long long>(c.loops_rejected),
      static_cast<long long>(c.window_updates), static_cast<long long>(c.window_failures),
      Percentile(lat, 0.5), Percentile(lat, 0.99), Percentile(lat, 1.0),
      static_cast<long long>(c.global_optimizations), static_cast<long long>(c.global_failures),
      Percentile(glat, 0.5), Percentile(glat, 1.0));
  std::fclose(f);
  std::printf(
      "omni-posegraph-slam: %lld scans (%lld used), %lld keyframes, %lld loops (%lld rejected), "
      "%lld global optimisations, window p50/p99 %.2f/%.2f ms, %.1f s -> "
      "%s/{trajectory.txt,map.pgm,map.yaml,map.png,graph.g2o,stats.json}\n",
      static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_used),
      static_cast<long long>(c.keyframes), static_cast<long long>(c.loops_accepted),
      static_cast<long long>(c.loops_rejected), static_cast<long long>(c.global_optimizations),
      Percentile(lat, 0.5), Percentile(lat, 0.99), wall_s, out_dir.c_str());
  return 0;
}
