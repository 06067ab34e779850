// omni-slam: `./omni slam rbpf INPUT --out DIR [--seed N] [--config FILE]` maps a recorded log
// offline with the same library the rbpf_mapper process runs (no bus).
//
// INPUT: a CARMEN log (.clf, .log, optionally .gz; FLASER/RLASER/ROBOTLASER1 with the odometry
// pose on each laser line, ODOM lines) or an LCM log (LIDAR_SCAN laser_scan_t, WHEEL_ODOM
// odometry_t, IMU imu_t; detected by its sync word). Writes DIR/trajectory.txt
// (`scan_index timestamp x y theta` of every accepted scan, 0-based in input order, the best
// particle's final path), DIR/map.{pgm,yaml,png} and DIR/stats.json.
//
// `omni-slam posegraph ...` hands over to build/bin/omni-posegraph-slam (the pose-graph
// mapper's own runner) when it exists.
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "omni/bus/slam_log.h"
#include "omni/common/config.h"
#include "omni/common/geometry.h"
#include "omni/common/time.h"
#include "omni/io/grid.h"
#include "omni/io/image_io.h"
#include "omni/io/trajectory_io.h"
#include "omni/rbpf_mapper/rbpf.h"

namespace fs = std::filesystem;

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-slam rbpf INPUT --out DIR [--seed N] [--config FILE] [--particles N]\n"
      "                 [--threads N] [--max-scans N] [--quiet]\n"
      "  Maps INPUT offline with the RBPF mapper library (the rbpf_mapper process's algorithm).\n"
      "  INPUT: CARMEN log (.clf/.log, optionally gzip) or LCM log (LIDAR_SCAN, WHEEL_ODOM, IMU).\n"
      "  Writes DIR/trajectory.txt (scan_index timestamp x y theta, every accepted scan, 0-based\n"
      "  in input order; the final estimate), DIR/live_trajectory.txt (the pose the filter\n"
      "  returned at each scan, what the process publishes on POSE_RBPF), DIR/map.pgm + map.yaml\n"
      "  (ROS map_server), DIR/map.png, DIR/map_trajectory.png, DIR/stats.json.\n"
      "  --config FILE   rbpf_mapper YAML (default: built-in defaults = config/rbpf_mapper.yaml)\n"
      "  --seed N        overrides the config's seed\n"
      "  --particles N, --threads N   override the config\n"
      "  --max-scans N   stop after N laser scans (a prefix of the log)\n"
      "usage: omni-slam posegraph ...   runs omni-posegraph-slam (pose-graph mapper) if built\n");
}

struct Input {
  std::vector<double> scan_time_s;  // by scan index
};

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
    Usage(stdout);
    return 0;
  }
  if (argc < 2) {
    Usage(stderr);
    return 2;
  }
  const std::string mapper = argv[1];
  if (mapper == "posegraph") {
    const fs::path self = fs::path(argv[0]).parent_path();
    const fs::path pg = self / "omni-posegraph-slam";
    if (!fs::exists(pg)) {
      std::fprintf(stderr,
                   "omni-slam: the pose-graph mapper's runner (%s) is not built; `omni-slam "
                   "posegraph` is provided by host/pose_graph_mapper\n",
                   pg.c_str());
      return 2;
    }
    std::vector<char*> args;
    std::string name = pg.string();
    args.push_back(name.data());
    for (int i = 2; i < argc; ++i) args.push_back(argv[i]);
    args.push_back(nullptr);
    execv(name.c_str(), args.data());
    std::fprintf(stderr, "omni-slam: cannot run %s: %s\n", name.c_str(), std::strerror(errno));
    return 1;
  }
  if (mapper != "rbpf") {
    std::fprintf(stderr,
                 "omni-slam: unknown mapper '%s' (the mappers are 'rbpf', run here, and "
                 "'posegraph', handed to omni-posegraph-slam)\n",
                 mapper.c_str());
    return 2;
  }
  std::string input, out_dir, config_path;
  long long seed = -1, particles = -1, threads = -1, max_scans = -1;
  bool quiet = false;
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    auto val = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "omni-slam: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    auto num = [&](const std::string& v) -> long long {
      char* end = nullptr;
      const long long x = std::strtoll(v.c_str(), &end, 10);
      if (v.empty() || *end != '\0' || x < 0) {
        std::fprintf(stderr, "omni-slam: %s expects a non-negative integer, got '%s'\n", a.c_str(),
                     v.c_str());
        std::exit(2);
      }
      return x;
    };
    if (a == "--help" || a == "-h") {
      Usage(stdout);
      return 0;
    } else if (a == "--out")
      out_dir = val();
    else if (a == "--config")
      config_path = val();
    else if (a == "--seed")
      seed = num(val());
    else if (a == "--particles")
      particles = num(val());
    else if (a == "--threads")
      threads = num(val());
    else if (a == "--max-scans")
      max_scans = num(val());
    else if (a == "--quiet")
      quiet = true;
    else if (!a.empty() && a[0] == '-') {
      std::fprintf(stderr, "omni-slam: unknown option '%s'\n", a.c_str());
      Usage(stderr);
      return 2;
    } else if (input.empty())
      input = a;
    else {
      std::fprintf(stderr, "omni-slam: unexpected argument '%s'\n", a.c_str());
      return 2;
    }
  }
  if (input.empty() || out_dir.empty()) {
    std::fprintf(stderr, "omni-slam: INPUT and --out DIR are required\n");
    Usage(stderr);
    return 2;
  }
  if (!fs::exists(input)) {
    std::fprintf(stderr, "omni-slam: input '%s' does not exist\n", input.c_str());
    return 1;
  }
  omni::rbpf::RbpfOptions opt;
  if (!config_path.empty()) {
    auto reader = omni::ConfigReader::FromFile(config_path);
    if (!reader.ok()) {
      std::fprintf(stderr, "omni-slam: %s\n", reader.error().message.c_str());
      return 1;
    }
    auto loaded = omni::rbpf::RbpfOptions::Load(*reader);
    if (!loaded.ok()) {
      std::fprintf(stderr, "omni-slam: bad config:\n%s\n", loaded.error().message.c_str());
      return 1;
    }
    opt = *loaded;
  }
  if (seed >= 0) opt.seed = static_cast<uint64_t>(seed);
  // -1: not given (the config's value); an explicit 0 is an error, not "use the config".
  if (particles == 0 || threads == 0) {
    std::fprintf(stderr, "omni-slam: --%s must be at least 1\n",
                 particles == 0 ? "particles" : "threads");
    return 2;
  }
  // The config's ranges (rbpf.cc): 100000 threads aborted, 4294967297 particles became 1.
  if (particles > 1000 || threads > 256) {
    std::fprintf(stderr, "omni-slam: --%s must be in [1, %d]\n",
                 particles > 1000 ? "particles" : "threads", particles > 1000 ? 1000 : 256);
    return 2;
  }
  if (particles > 0) opt.particles = static_cast<int>(particles);
  if (threads > 0) opt.threads = static_cast<int>(threads);
  if (omni::Status s = opt.Validate(); !s.ok()) {
    std::fprintf(stderr, "omni-slam: %s\n", s.message().c_str());
    return 2;
  }
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (ec) {
    std::fprintf(stderr, "omni-slam: cannot create '%s': %s\n", out_dir.c_str(),
                 ec.message().c_str());
    return 1;
  }

  const int64_t t_start = omni::MonotonicMicros();
  omni::rbpf::RbpfSlam slam(opt);
  int64_t scans = 0;
  std::vector<omni::io::TrajectoryEntry> live;  // the pose returned at each scan (POSE_RBPF)
  auto report = [&](const omni::rbpf::ScanResult& r) {
    if (!quiet && r.scan_index % 500 == 0)
      std::fprintf(stderr, "omni-slam: scan %lld  pose %.2f %.2f %.3f\n",
                   static_cast<long long>(r.scan_index), r.pose.x, r.pose.y, r.pose.theta);
  };
  omni::bus::SlamLogChannels channels;
  channels.scan = opt.scan_channel;
  channels.odom = opt.odom_channel;
  channels.imu = opt.imu_channel;
  omni::bus::SlamLogHandlers handlers;
  handlers.scan = [&](const omni::bus::SlamScan& in) {
    if (max_scans >= 0 && scans >= max_scans) return false;
    omni::rbpf::ScanInput s;
    s.utime = in.utime;
    s.sensor_in_base = in.sensor_in_base;
    s.angle_min_rad = in.angle_min_rad;
    s.angle_increment_rad = in.angle_increment_rad;
    if (in.range_min_m) s.range_min_m = *in.range_min_m;
    s.range_max_m = in.range_max_m;
    s.ranges_m = in.ranges_m;
    s.scan_time_s = in.scan_time_s;
    s.odom = in.odom;
    const omni::rbpf::ScanResult r = slam.AddScan(s);
    if (r.accepted && r.in_map_frame)  // as POSE_RBPF: none before the map frame exists
      live.push_back(omni::io::MakeEntry2D(r.scan_index, omni::UtimeToSeconds(s.utime), r.pose));
    report(r);
    return !(max_scans >= 0 && ++scans >= max_scans);
  };
  handlers.odom = [&](int64_t utime, const omni::Pose2& p) { slam.AddOdometry(utime, p); };
  handlers.imu = [&](int64_t utime, double rate) { slam.AddImuYawRate(utime, rate); };
  auto read = omni::bus::ReadSlamLog(input, channels, handlers);
  if (!read.ok()) {
    std::fprintf(stderr, "omni-slam: %s\n", read.error().message.c_str());
    return 1;
  }
  omni::bus::ReportSlamLogProblems("omni-slam", input, *read);
  const int64_t decode_errors = read->decode_errors;
  const auto& c = slam.counters();
  const auto traj = slam.BestTrajectory();
  const auto map = slam.BestMap();
  const double wall_s = static_cast<double>(omni::MonotonicMicros() - t_start) * 1e-6;
  if (traj.empty() || map.width == 0) {
    std::fprintf(stderr,
                 "omni-slam: no scan could be used (scans %lld, no odometry %lld, too few beams "
                 "%lld, time backwards %lld, undecodable messages %lld)\n",
                 static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_no_odom),
                 static_cast<long long>(c.scans_too_few_beams),
                 static_cast<long long>(c.scans_time_backwards),
                 static_cast<long long>(decode_errors));
    return 1;
  }
  std::vector<omni::io::TrajectoryEntry> entries;
  omni::io::Polyline line;
  for (const auto& e : traj) {
    entries.push_back(omni::io::MakeEntry2D(e.scan_index, omni::UtimeToSeconds(e.utime), e.pose));
    line.poses.push_back(e.pose);
  }
  omni::Status s = omni::io::WriteTrajectory2D(
      out_dir + "/trajectory.txt", entries,
      "scan_index timestamp x y theta (RBPF best particle, final estimate)");
  if (s.ok())
    s = omni::io::WriteTrajectory2D(
        out_dir + "/live_trajectory.txt", live,
        "scan_index timestamp x y theta (RBPF reported particle at each scan, as POSE_RBPF)");
  if (s.ok()) s = omni::io::WriteMapServer(map, out_dir + "/map");
  if (s.ok()) s = omni::io::WritePng(out_dir + "/map.png", omni::io::RenderGrid(map, {}, 1));
  if (s.ok())
    s = omni::io::WritePng(out_dir + "/map_trajectory.png", omni::io::RenderGrid(map, {line}, 1));
  if (!s.ok()) {
    std::fprintf(stderr, "omni-slam: %s\n", s.message().c_str());
    return 1;
  }
  const omni::rbpf::RbpfSlam::PathMemory paths = slam.path_memory();
  const omni::rbpf::RbpfSlam::MapMemory maps = slam.map_memory();
  std::FILE* f = std::fopen((out_dir + "/stats.json").c_str(), "w");
  if (!f) {
    std::fprintf(stderr, "omni-slam: cannot write %s/stats.json: %s\n", out_dir.c_str(),
                 std::strerror(errno));
    return 1;
  }
  std::fprintf(
      f,
      "{\"system\": \"omni-rbpf\", \"input\": \"%s\", \"seed\": %llu, \"particles\": %d, "
      "\"threads\": %d, \"wall_s\": %.3f, \"scans\": %lld, \"scans_processed\": %lld, "
      "\"scans_gated\": %lld, \"scans_too_few_beams\": %lld, \"scans_time_backwards\": %lld, "
      "\"scans_no_odom\": %lld, \"scans_bad_geometry\": %lld, \"invalid_beams\": %lld, "
      "\"odom_jumps\": %lld, \"odom_invalid\": %lld, \"odom_out_of_order\": %lld, "
      "\"time_rebases\": %lld, \"decode_errors\": %lld, \"resamplings\": %lld, "
      "\"reported_switches\": %lld, \"match_failures\": "
      "%lld, "
      "\"match_searches\": %lld, \"trajectory_poses\": %zu, \"distinct_tiles\": %zu, "
      "\"packed_tiles\": %zu, \"map_bytes\": %zu, \"tile_refs\": %zu, \"path_poses\": %zu, "
      "\"path_bytes\": %zu, \"sweeps_corrected\": %lld, "
      "\"sweeps_uncorrected\": %lld, "
      "\"skipped_bytes\": %llu, \"stopped_early\": %s, \"scans_repeated\": %lld, "
      "\"scans_lost_in_log\": %lld",
      input.c_str(), static_cast<unsigned long long>(opt.seed), opt.particles, opt.threads, wall_s,
      static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_processed),
      static_cast<long long>(c.scans_gated), static_cast<long long>(c.scans_too_few_beams),
      static_cast<long long>(c.scans_time_backwards), static_cast<long long>(c.scans_no_odom),
      static_cast<long long>(c.scans_bad_geometry), static_cast<long long>(c.invalid_beams),
      static_cast<long long>(c.odom_jumps), static_cast<long long>(c.odom_invalid),
      static_cast<long long>(c.odom_out_of_order), static_cast<long long>(c.time_rebases),
      static_cast<long long>(decode_errors), static_cast<long long>(c.resamplings),
      static_cast<long long>(c.reported_switches), static_cast<long long>(c.match_failures),
      static_cast<long long>(c.match_searches), traj.size(), maps.tiles, maps.packed, maps.bytes,
      slam.total_tile_refs(), paths.poses, paths.bytes, static_cast<long long>(c.sweeps_corrected),
      static_cast<long long>(c.sweeps_uncorrected),
      static_cast<unsigned long long>(read->skipped_bytes),
      read->stopped_early.empty() ? "false" : "true", static_cast<long long>(read->scans_repeated),
      static_cast<long long>(read->scans_lost));
  std::fprintf(f,
               ", \"imu_in\": %lld, \"imu_invalid\": %lld, \"imu_bias_samples\": %lld, "
               "\"imu_bias_refused\": %lld, \"imu_bias_rad_s\": %.7f, "
               "\"imu_uncovered_updates\": %lld",
               static_cast<long long>(c.imu_in), static_cast<long long>(c.imu_invalid),
               static_cast<long long>(c.imu_bias_samples),
               static_cast<long long>(c.imu_bias_refused), slam.imu_bias_rad_s(),
               static_cast<long long>(c.imu_uncovered_updates));
  {
    // How far the published (reported) particle ends from the final estimate's particle.
    const omni::Pose2& fin = slam.particles()[static_cast<size_t>(slam.final_index())].pose;
    const omni::Pose2 rep = slam.ReportedPose();
    std::fprintf(f, ", \"reported_to_final_m\": %.4f, \"reported_to_final_rad\": %.5f",
                 std::hypot(rep.x - fin.x, rep.y - fin.y),
                 std::fabs(omni::WrapAngle(rep.theta - fin.theta)));
  }
  const omni::rbpf::ResolutionChoice& choice = slam.resolution_choice();
  std::fprintf(f,
               ", \"grid_resolution_m\": %.4f, \"likelihood_gain\": %.6g, "
               "\"resolution_choice\": {\"decided\": %s, "
               "\"switched\": %s, \"travel_m\": %.3f, \"moving_scans\": %lld, "
               "\"spacing_m\": %.4f}",
               slam.options().grid.resolution_m, slam.options().likelihood_gain,
               choice.decided ? "true" : "false", choice.switched ? "true" : "false",
               choice.travel_m, static_cast<long long>(choice.moving_scans), choice.spacing_m());
  const omni::OdometryCalibrator& oc = slam.odometry_calibrator();
  const omni::OdometryCalibration& cal = oc.calibration();
  std::fprintf(f,
               ", \"odom_calibration\": {\"enabled\": %s, \"active\": %s, \"pairs_used\": %lld, "
               "\"pairs_gated\": %lld, \"updates\": %lld, \"x_scale\": %.6f, \"y_per_x\": %.6f, "
               "\"theta_scale\": %.6f, \"theta_per_x\": %.6f}}\n",
               opt.odometry_calibration.enabled ? "true" : "false", oc.active() ? "true" : "false",
               static_cast<long long>(oc.pairs_used()), static_cast<long long>(oc.pairs_gated()),
               static_cast<long long>(oc.updates()), cal.x_scale, cal.y_per_x, cal.theta_scale,
               cal.theta_per_x);
  std::fclose(f);
  std::printf(
      "omni-slam rbpf: %lld scans (%lld updates), %d particles, %.3f m cells, %lld resamplings, "
      "%lld match failures, %.1f s -> %s/{trajectory.txt,live_trajectory.txt,map.*,stats.json}\n",
      static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_processed), opt.particles,
      slam.options().grid.resolution_m, static_cast<long long>(c.resamplings),
      static_cast<long long>(c.match_failures), wall_s, out_dir.c_str());
  return 0;
}
