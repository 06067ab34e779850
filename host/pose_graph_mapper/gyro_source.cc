#include "omni/pose_graph_mapper/gyro_source.h"

#include <algorithm>
#include <cmath>

namespace omni::pgm {

std::optional<GyroYawSource::Yaw> GyroYawSource::Between(int64_t t0, int64_t t1) const {
  const std::optional<double> raw = RawBetween(t0, t1);
  if (!raw) return std::nullopt;
  Yaw y;
  y.delta_rad = *raw - bias_ * 1e-6 * static_cast<double>(t1 - t0);
  y.variance = noise_.angle_var_per_s * 1e-6 * static_cast<double>(t1 - t0) +
               noise_.angle_var_per_rad * std::abs(y.delta_rad);
  return y;
}

std::optional<RelativeMotion> OdometryGyroSource::Between(int64_t t0, int64_t t1) const {
  const auto steps = odometry_->Steps(t0, t1);
  if (!steps) return std::nullopt;
  const auto& pts = *steps;
  RelativeMotion m;
  for (size_t k = 0; k + 1 < pts.size(); ++k) {
    Pose2 step = odometry_->CalibratedStep(pts[k].second.Between(pts[k + 1].second));
    const double dt = 1e-6 * static_cast<double>(pts[k + 1].first - pts[k].first);
    Eigen::Matrix3d q = StepCovariance(odometry_->noise(), step, dt);
    const auto yaw = gyro_->Between(pts[k].first, pts[k + 1].first);
    if (yaw && q(2, 2) + yaw->variance > 0.0) {
      // Weighted mean of the two heading changes (taken on the shortest arc between them), and
      // the variance of that mean.
      const double wo = 1.0 / std::max(q(2, 2), 1e-300), wg = 1.0 / std::max(yaw->variance, 1e-300);
      step.theta = WrapAngle(step.theta + wg / (wo + wg) * WrapAngle(yaw->delta_rad - step.theta));
      q(2, 2) = 1.0 / (wo + wg);
      fused_.fetch_add(1, std::memory_order_relaxed);
    } else if (pts[k + 1].first > pts[k].first) {
      missing_.fetch_add(1, std::memory_order_relaxed);
    }
    AppendStep(&m, step, q);
  }
  return m;
}

}  // namespace omni::pgm
