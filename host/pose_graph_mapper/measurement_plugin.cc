#include "omni/pose_graph_mapper/measurement_plugin.h"
#include "omni/pose_graph_mapper/lie.h"

#include <cmath>

#include <Eigen/Dense>

namespace omni::pgm {

std::vector<Eigen::Vector2d> ScanToPoints(const LaserScan2& scan, ScanConversionStats* stats,
                                          const Pose2* sweep) {
  ScanConversionStats local;
  const double last_beam = scan.ranges_m.size() > 1 ? scan.ranges_m.size() - 1.0 : 1.0;
  std::vector<Eigen::Vector2d> out;
  out.reserve(scan.ranges_m.size());
  for (size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const float r = scan.ranges_m[i];
    if (!std::isfinite(r)) {
      ++local.not_finite;
      continue;
    }
    // (A zero or negative range is no return whatever min_range says, NaN included.)
    if (!(r > 0.f) || r < scan.min_range_m || (scan.max_range_m > 0 && r >= scan.max_range_m)) {
      ++local.out_of_range;
      continue;
    }
    const double a =
        static_cast<double>(scan.angle_min_rad) + static_cast<double>(i) * scan.angle_increment_rad;
    const Eigen::Vector2d p = scan.laser_in_base.Transform({r * std::cos(a), r * std::sin(a)});
    out.push_back(
        sweep ? Interpolate(Pose2(), *sweep, static_cast<double>(i) / last_beam).Transform(p) : p);
    ++local.used;
  }
  if (stats) {
    stats->used += local.used;
    stats->not_finite += local.not_finite;
    stats->out_of_range += local.out_of_range;
  }
  return out;
}

Eigen::Matrix3d RelativePoseFactor::Information() const {
  // A tiny floor keeps a degenerate covariance invertible (as Trajectory::ToPoseGraph does).
  return RelativeInformation(delta, covariance, 1e-12);
}

io::Edge2 RelativePoseFactor::ToEdge(int from_id, int to_id) const {
  io::Edge2 e;
  e.from = from_id;
  e.to = to_id;
  e.measurement = delta;
  e.information = Information();
  return e;
}

}  // namespace omni::pgm
