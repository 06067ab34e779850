// omni-match-reference: how far the pose-graph keyframe matcher's answer is from a corrected
// log's own relative poses, when the submap is placed at the *corrected* poses (so no mapping
// error enters it). On the Radish logs this measures the corrected poses' scan-to-scan noise as
// much as the matcher's (docs/posegraph.md, "Freiburg 079: what the 0.05 m goal measures").
//
// usage: omni-match-reference LOG [--truth FILE] [--gap N] [--submap K] [--icp]
//   LOG: CARMEN log whose laser poses are corrected (../shared/datasets/carmen-corrected), or
//        an LCM log with --truth: the simulator's sim.lcmlog and truth.txt (exact poses)
//   --gap N: scans between the pair (1: consecutive; 6: about a keyframe step), default 6
//   --submap K: the previous K scans (N apart) form the submap, default 3 (as the mapper)
//   --icp: point-to-line ICP polish after the correlative search
//   --cubic: the polish on the bicubic field (SearchWindow::cubic_polish)
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/io/carmen.h"
#include "omni/io/lcm_log.h"
#include "omni/io/trajectory_io.h"
#include "omni/laser_scan_t.hpp"
#include "omni/pose_graph_mapper/pose_graph_slam.h"
#include "omni/pose_graph_mapper/scan_plugins.h"

namespace {

int Usage() {
  std::fprintf(stderr,
               "usage: omni-match-reference LOG [--truth FILE] [--gap N] [--submap K] [--icp]\n"
               "       [--cubic]\n"
               "  The keyframe matcher against submaps at a corrected log's poses: its error\n"
               "  relative to the log's own relative poses (RMS, median, mean). With --truth,\n"
               "  LOG is an LCM log (omni-sim's sim.lcmlog) and FILE its true poses by scan\n"
               "  index (truth.txt).\n");
  return 2;
}

double Rms(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return v.empty() ? 0.0 : std::sqrt(s / static_cast<double>(v.size()));
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  using namespace omni;
  using namespace omni::pgm;
  if (argc >= 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
    Usage();
    return 0;  // asked for: not a mistake
  }
  if (argc < 2) return Usage();
  const std::string path = argv[1];
  int gap = 6, submap = 3;
  std::string truth_path;
  bool cubic = false;
  bool icp = false;
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--truth" && i + 1 < argc) {
      truth_path = argv[++i];
    } else if (a == "--cubic") {
      cubic = true;
    } else if (a == "--gap" && i + 1 < argc) {
      gap = std::atoi(argv[++i]);
    } else if (a == "--submap" && i + 1 < argc) {
      submap = std::atoi(argv[++i]);
    } else if (a == "--icp") {
      icp = true;
    } else {
      std::fprintf(stderr, "omni-match-reference: unknown option '%s'\n", a.c_str());
      return Usage();
    }
  }
  if (gap < 1 || submap < 1) return Usage();
  // Every laser scan as a keyframe at its corrected (or true) pose, end points in the laser's
  // frame.
  const KeyframeMatchOptions mapper = PoseGraphSlamOptions().match;
  std::vector<Keyframe> scans;
  auto add_scan = [&](const Pose2& laser_pose, const std::vector<float>& ranges, double angle_min,
                      double increment, double max_range) {
    Keyframe k;
    k.estimate = laser_pose;
    for (size_t i = 0; i < ranges.size(); ++i) {
      const double d = ranges[i];
      if (!(d > 0.05) || d >= max_range || d > mapper.max_range_m) continue;
      const double a = angle_min + static_cast<double>(i) * increment;
      k.points.emplace_back(d * std::cos(a), d * std::sin(a));
    }
    scans.push_back(std::move(k));
  };
  if (!truth_path.empty()) {
    auto truth = io::ReadTrajectory(truth_path);
    auto reader = io::LcmLogReader::Open(path);
    if (!truth.ok() || !reader.ok()) {
      std::fprintf(stderr, "omni-match-reference: %s\n",
                   (!truth.ok() ? truth.error() : reader.error()).message.c_str());
      return 1;
    }
    std::vector<const io::TrajectoryEntry*> by_index;
    for (const auto& e : truth->entries) {
      if (e.index < 0) continue;
      if (by_index.size() <= static_cast<size_t>(e.index)) by_index.resize(e.index + 1, nullptr);
      by_index[static_cast<size_t>(e.index)] = &e;
    }
    io::LcmLogEvent ev;
    for (;;) {
      auto more = reader->Next(&ev);
      if (!more.ok()) {
        std::fprintf(stderr, "omni-match-reference: %s\n", more.error().message.c_str());
        return 1;
      }
      if (!*more) break;
      if (ev.channel != "LIDAR_SCAN") continue;
      omni::laser_scan_t m;
      if (omni::bus::DecodeMessage(&m, ev.data.data(), static_cast<int>(ev.data.size())) < 0)
        continue;
      if (m.seq < 0 || static_cast<size_t>(m.seq) >= by_index.size() || !by_index[m.seq]) continue;
      const Pose2 laser =
          by_index[m.seq]->pose2() * Pose2(m.sensor_x_m, m.sensor_y_m, m.sensor_yaw_rad);
      std::vector<float> r = m.ranges_m;
      for (float& x : r)
        if (!std::isfinite(x)) x = 0.f;
      add_scan(laser, r, m.angle_min_rad, m.angle_increment_rad, m.range_max_m);
    }
  } else {
    auto log = io::ReadCarmenLog(path);
    if (!log.ok()) {
      std::fprintf(stderr, "omni-match-reference: %s\n", log.error().message.c_str());
      return 1;
    }
    for (const auto& r : log->records) {
      if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
      const io::CarmenLaser& l = r.laser;
      std::vector<float> ranges(l.ranges_m.begin(), l.ranges_m.end());
      add_scan(l.laser_pose, ranges, l.angle_min_rad, l.angle_increment_rad, l.max_range_m);
    }
  }
  std::vector<double> et, er;
  double bx = 0, by = 0, bt = 0, tt = 0, te = 0;
  int rejected = 0;
  const size_t first = static_cast<size_t>(gap) * static_cast<size_t>(submap);
  for (size_t cur = first; cur < scans.size(); cur += static_cast<size_t>(gap)) {
    std::vector<Keyframe> sub;
    for (int j = submap; j >= 0; --j) sub.push_back(scans[cur - static_cast<size_t>(j * gap)]);
    const int prev = submap - 1;
    const auto points = BuildSubmap(sub, 0, prev, prev, mapper.max_range_m, mapper.fill_gap_m,
                                    mapper.field.resolution_m);
    const LikelihoodField field(points, mapper.field);
    const Pose2 truth = sub[prev].estimate.Between(sub.back().estimate);
    // The search starts off the answer, as an odometry guess would.
    const Pose2 guess = truth * Pose2(0.03, -0.02, 0.015);
    SearchWindow w = mapper.window;
    w.min_score = mapper.min_score;
    w.icp_polish = icp;
    w.cubic_polish = cubic;
    w.icp_pair_m = 0.1;
    if (field.empty() || sub.back().points.empty()) {
      ++rejected;
      continue;
    }
    const MatchResult m = MatchScan(field, sub.back().points, guess, w);
    if (m.score < mapper.min_score || m.inlier_fraction < mapper.min_inlier_fraction ||
        m.on_window_edge) {
      ++rejected;
      continue;
    }
    const Pose2 e = truth.Between(m.pose);
    et.push_back(std::hypot(e.x, e.y));
    er.push_back(std::abs(e.theta));
    bx += e.x;
    by += e.y;
    bt += e.theta;
    // Heading error against the pair's true turn: a matcher that under- or over-states turns.
    tt += truth.theta * truth.theta;
    te += truth.theta * e.theta;
  }
  if (et.empty()) {
    std::fprintf(stderr, "omni-match-reference: no pair matched in %s\n", path.c_str());
    return 1;
  }
  const double n = static_cast<double>(et.size());
  std::printf(
      "%s: gap %d, submap %d%s: %zu pairs matched (%d rejected by the mapper's checks)\n"
      "  translation error RMS %.4f m, median %.4f m; heading RMS %.4f rad, median %.4f rad\n"
      "  mean error (bias) x %.4f m, y %.4f m, heading %.4f rad; heading error per radian "
      "turned %.4f\n",
      path.c_str(), gap, submap, icp ? ", ICP polish" : (cubic ? ", bicubic polish" : ""),
      et.size(), rejected, Rms(et), Median(et), Rms(er), Median(er), bx / n, by / n, bt / n,
      tt > 0 ? te / tt : 0.0);
  return 0;
}
