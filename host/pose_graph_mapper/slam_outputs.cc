#include "omni/pose_graph_mapper/slam_outputs.h"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>

#include "omni/common/json.h"
#include "omni/common/time.h"
#include "omni/io/g2o.h"
#include "omni/io/grid.h"
#include "omni/io/image_io.h"
#include "omni/io/trajectory_io.h"

namespace omni::pgm {

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
  return v[i];
}

namespace {

// Written beside and renamed over: a kill mid-write leaves the previous stats.json whole.
Status WriteStats(const PoseGraphSlam& slam, const std::string& path, const SlamRunInfo& info) {
  const std::string tmp = path + ".tmp";
  std::FILE* f = std::fopen(tmp.c_str(), "w");
  if (!f) return MakeError(ErrorCode::kIo, "cannot write " + tmp + ": " + std::strerror(errno));
  const SlamCounters& c = slam.counters();
  const auto& lat = slam.window_latency_ms();
  const auto& glat = slam.global_latency_ms();
  const auto& wait = slam.global_wait_ms();
  auto ll = [](int64_t v) { return static_cast<long long>(v); };
  std::fprintf(
      f,
      "{\"system\": \"%s\", \"input\": \"%s\", \"window_size\": %d, \"wall_s\": "
      "%.3f, \"scans\": %lld, \"scans_used\": %lld, \"scans_time_backwards\": %lld, "
      "\"scans_too_few_beams\": %lld, \"scans_bad_geometry\": %lld, \"scans_no_odom\": %lld, "
      "\"invalid_beams\": %lld, "
      "\"odom_invalid\": %lld, \"odom_out_of_order\": %lld, \"odom_jumps\": %lld, "
      "\"time_rebases\": %lld, \"decode_errors\": %lld, \"keyframes\": %lld, "
      "\"scan_match_factors\": %lld, "
      "\"scan_match_failures\": %lld, \"loops_accepted\": %lld, \"loops_rejected\": %lld, "
      "\"loops_inconsistent\": %lld, \"window_updates\": %lld, \"window_failures\": %lld, "
      "\"covariance_failures\": %lld, \"latency_p50_ms\": %.3f, "
      "\"latency_p99_ms\": %.3f, \"latency_max_ms\": %.3f, \"global_optimizations\": %lld, "
      "\"global_failures\": %lld, \"global_p50_ms\": %.3f, \"global_max_ms\": %.3f, "
      "\"global_recent_p50_ms\": %.3f, \"global_wait_p50_ms\": %.3f, "
      "\"global_wait_max_ms\": %.3f, \"global_time_limited\": %lld",
      JsonEscape(info.system).c_str(), JsonEscape(info.input).c_str(), info.window_size,
      info.wall_s, ll(c.scans_in), ll(c.scans_used), ll(c.scans_time_backwards),
      ll(c.scans_too_few_beams), ll(c.scans_bad_geometry), ll(c.scans_no_odom), ll(c.invalid_beams),
      ll(c.odom_invalid), ll(c.odom_out_of_order), ll(c.odom_jumps), ll(c.time_rebases),
      ll(info.decode_errors), ll(c.keyframes), ll(c.scan_match_factors), ll(c.scan_match_failures),
      ll(c.loops_accepted), ll(c.loops_rejected), ll(c.loops_inconsistent), ll(c.window_updates),
      ll(c.window_failures), ll(c.covariance_failures), Percentile(lat, 0.5), Percentile(lat, 0.99),
      Percentile(lat, 1.0), ll(c.global_optimizations), ll(c.global_failures),
      Percentile(glat, 0.5), Percentile(glat, 1.0),
      // The last ten solves: what a global optimisation costs now, the graph as large as it got.
      Percentile(std::vector<double>(
                     glat.end() - static_cast<std::ptrdiff_t>(std::min<size_t>(glat.size(), 10)),
                     glat.end()),
                 0.5),
      // How long the mapping waited for them (less than their time when run in the background
      // and the scans before the next keyframe came in real time; offline, scans come at once).
      Percentile(wait, 0.5), Percentile(wait, 1.0), ll(c.global_time_limited));
  std::fprintf(
      f,
      ", \"absolute_in\": %lld, \"absolute_attached\": %lld, \"absolute_spliced\": %lld, "
      "\"absolute_queued\": %lld, \"absolute_rejected\": %lld, \"absolute_invalid\": %lld, "
      "\"keyframes_for_absolute\": %lld, \"keyframes_for_odometry\": %lld, "
      "\"keyframes_retired\": %lld, \"keyframes_removed\": %lld, \"removals_refused\": %lld",
      ll(c.absolute_in), ll(c.absolute_attached), ll(c.absolute_spliced), ll(c.absolute_queued),
      ll(c.absolute_rejected), ll(c.absolute_invalid), ll(c.keyframes_for_absolute),
      ll(c.keyframes_for_odometry), ll(c.keyframes_retired), ll(c.keyframes_removed),
      ll(c.removals_refused));
  std::fprintf(f, ", \"clock_steps_back\": %lld, \"scans_replayed\": %lld", ll(c.clock_steps_back),
               ll(c.scans_replayed));
  std::fprintf(f, ", \"sweeps_corrected\": %lld, \"sweeps_uncorrected\": %lld",
               ll(c.sweeps_corrected), ll(c.sweeps_uncorrected));
  std::fprintf(f, ", \"imu_in\": %lld, \"imu_rejected\": %lld, \"gyro_missing_steps\": %lld",
               ll(c.imu_in), ll(c.imu_rejected),
               ll(static_cast<int64_t>(slam.gyro_missing_steps())));
  std::fprintf(f,
               ", \"gyro_bias_samples\": %lld, \"gyro_bias_refused\": %lld, "
               "\"gyro_bias_rad_s\": %.7f",
               ll(c.gyro_bias_samples), ll(c.gyro_bias_refused), slam.gyro_bias_rad_s());
  const OdometryCalibrator& oc = slam.odometry_calibrator();
  const OdometryCalibration& cal = oc.calibration();
  std::fprintf(f,
               ", \"odom_calibration\": {\"active\": %s, \"pairs_used\": %lld, "
               "\"pairs_gated\": %lld, \"updates\": %lld, \"x_scale\": %.6f, "
               "\"y_per_x\": %.6f, \"theta_scale\": %.6f, \"theta_per_x\": %.6f, "
               "\"noise_scale\": %.4f, \"suggested_noise_scale\": %.4f}",
               oc.active() ? "true" : "false", ll(oc.pairs_used()), ll(oc.pairs_gated()),
               ll(oc.updates()), cal.x_scale, cal.y_per_x, cal.theta_scale, cal.theta_per_x,
               oc.noise_scale(), oc.suggested_noise_scale());
  for (const auto& [k, v] : info.extra)
    std::fprintf(f, ", \"%s\": %lld", JsonEscape(k).c_str(), ll(v));
  std::fprintf(f, "}\n");
  const bool failed = std::ferror(f) != 0;
  if (std::fclose(f) != 0 || failed || std::rename(tmp.c_str(), path.c_str()) != 0)
    return MakeError(ErrorCode::kIo, "cannot write " + path + ": " + std::strerror(errno));
  return Status();
}

}  // namespace

Status WriteSlamOutputs(const PoseGraphSlam& slam, const std::string& dir,
                        const SlamRunInfo& info) {
  const auto traj = slam.Trajectory();
  if (traj.empty()) {
    const SlamCounters& c = slam.counters();
    return MakeError(ErrorCode::kNotFound,
                     "no scan could be used (scans " + std::to_string(c.scans_in) +
                         ", no odometry " + std::to_string(c.scans_no_odom) + ", too few beams " +
                         std::to_string(c.scans_too_few_beams) + ", time backwards " +
                         std::to_string(c.scans_time_backwards) + "): nothing to write to " + dir);
  }
  std::vector<io::TrajectoryEntry> entries;
  io::Polyline line;
  for (const auto& e : traj) {
    entries.push_back(io::MakeEntry2D(e.scan_index, UtimeToSeconds(e.utime), e.pose));
    line.poses.push_back(e.pose);
  }
  io::LogOddsOptions grid_options;
  grid_options.resolution_m = info.grid_resolution_m;
  const io::GridMap map = slam.RenderMap(grid_options);
  Status s = io::WriteTrajectory2D(
      dir + "/trajectory.txt", entries,
      "scan_index timestamp x y theta (pose-graph SLAM, final optimised estimate)");
  if (s.ok()) s = io::WriteMapServer(map, dir + "/map");
  if (s.ok()) s = io::WritePng(dir + "/map.png", io::RenderGrid(map, {}, 1));
  if (s.ok()) s = io::WritePng(dir + "/map_trajectory.png", io::RenderGrid(map, {line}, 1));
  if (s.ok()) s = io::WriteG2o(dir + "/graph.g2o", slam.Graph());
  if (s.ok()) s = WriteStats(slam, dir + "/stats.json", info);
  return s;
}

}  // namespace omni::pgm
