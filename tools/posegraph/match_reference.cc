// omni-match-reference: how far the pose-graph keyframe matcher's answer is from a corrected
// log's own relative poses, when the submap is placed at the *corrected* poses (so no mapping
// error enters it). On the Radish logs this measures the corrected poses' scan-to-scan noise as
// much as the matcher's (docs/posegraph.md, "Freiburg 079: what the 0.05 m goal measures").
//
// usage: omni-match-reference LOG [--gap N] [--submap K] [--icp]
//   LOG: CARMEN log whose laser poses are corrected (../shared/datasets/carmen-corrected)
//   --gap N: scans between the pair (1: consecutive; 6: about a keyframe step), default 6
//   --submap K: the previous K scans (N apart) form the submap, default 3 (as the mapper)
//   --icp: point-to-line ICP polish after the correlative search
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "omni/io/carmen.h"
#include "omni/pose_graph_mapper/pose_graph_slam.h"
#include "omni/pose_graph_mapper/scan_plugins.h"

namespace {

int Usage() {
  std::fprintf(stderr,
               "usage: omni-match-reference LOG [--gap N] [--submap K] [--icp]\n"
               "  The keyframe matcher against submaps at a corrected log's poses: its error\n"
               "  relative to the log's own relative poses (RMS, median, mean).\n");
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
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") return Usage();
  const std::string path = argv[1];
  int gap = 6, submap = 3;
  bool icp = false;
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--gap" && i + 1 < argc) {
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
  auto log = io::ReadCarmenLog(path);
  if (!log.ok()) {
    std::fprintf(stderr, "omni-match-reference: %s\n", log.error().message.c_str());
    return 1;
  }
  // Every laser scan as a keyframe at its corrected pose, end points in the base frame.
  const KeyframeMatchOptions mapper = PoseGraphSlamOptions().match;
  std::vector<Keyframe> scans;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    const io::CarmenLaser& l = r.laser;
    Keyframe k;
    k.estimate = l.laser_pose;
    for (size_t i = 0; i < l.ranges_m.size(); ++i) {
      const double d = l.ranges_m[i];
      if (!(d > 0.05) || d >= l.max_range_m || d > mapper.max_range_m) continue;
      const double a = l.angle_min_rad + static_cast<double>(i) * l.angle_increment_rad;
      k.points.emplace_back(d * std::cos(a), d * std::sin(a));
    }
    scans.push_back(std::move(k));
  }
  std::vector<double> et, er;
  double bx = 0, by = 0, bt = 0;
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
  }
  if (et.empty()) {
    std::fprintf(stderr, "omni-match-reference: no pair matched in %s\n", path.c_str());
    return 1;
  }
  const double n = static_cast<double>(et.size());
  std::printf(
      "%s: gap %d, submap %d%s: %zu pairs matched (%d rejected by the mapper's checks)\n"
      "  translation error RMS %.4f m, median %.4f m; heading RMS %.4f rad, median %.4f rad\n"
      "  mean error (bias) x %.4f m, y %.4f m, heading %.4f rad\n",
      path.c_str(), gap, submap, icp ? ", ICP polish" : "", et.size(), rejected, Rms(et),
      Median(et), Rms(er), Median(er), bx / n, by / n, bt / n);
  return 0;
}
