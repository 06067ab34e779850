#include "omni/rbpf_mapper/motion_model.h"

#include <algorithm>
#include <cmath>

namespace omni::rbpf {

MotionSigma OmniMotionModel::Sigma(const Pose2& d) const {
  const double ax = std::abs(d.x), ay = std::abs(d.y), at = std::abs(d.theta);
  MotionSigma s;
  s.x = n_.min_xy_m + n_.a_xx * ax + n_.a_xy * ay + n_.a_xt * at;
  s.y = n_.min_xy_m + n_.a_yx * ax + n_.a_yy * ay + n_.a_yt * at;
  s.theta = n_.min_theta_rad + n_.a_tt * at + n_.a_td * std::hypot(d.x, d.y);
  return s;
}

Pose2 OmniMotionModel::FuseImuYaw(const Pose2& delta, double imu_dtheta, double* sigma) const {
  const double so = Sigma(delta).theta;
  const double si = n_.imu_yaw_sigma_min_rad + n_.imu_yaw_sigma_per_rad * std::abs(imu_dtheta);
  const double wo = 1.0 / (so * so), wi = 1.0 / (si * si);
  Pose2 out = delta;
  out.theta = WrapAngle(delta.theta + wi / (wo + wi) * WrapAngle(imu_dtheta - delta.theta));
  if (sigma) *sigma = std::sqrt(1.0 / (wo + wi));
  return out;
}

Pose2 OmniMotionModel::Sample(const Pose2& from, const Pose2& delta, std::mt19937_64& rng,
                              std::optional<double> imu_dtheta) const {
  MotionSigma s = Sigma(delta);
  Pose2 d = delta;
  if (imu_dtheta) d = FuseImuYaw(delta, *imu_dtheta, &s.theta);
  std::normal_distribution<double> n01(0.0, 1.0);
  const double nx = n01(rng), ny = n01(rng), nt = n01(rng);
  Pose2 noisy(d.x + s.x * nx, d.y + s.y * ny, WrapAngle(d.theta + s.theta * nt));
  return from * noisy;
}

double OmniMotionModel::LogDensity(const Pose2& from, const Pose2& delta, const Pose2& to,
                                   std::optional<double> imu_dtheta) const {
  MotionSigma s = Sigma(delta);
  Pose2 d = delta;
  if (imu_dtheta) d = FuseImuYaw(delta, *imu_dtheta, &s.theta);
  // All-zero noise settings make the model exact; keep the density finite.
  s.x = std::max(s.x, 1e-9);
  s.y = std::max(s.y, 1e-9);
  s.theta = std::max(s.theta, 1e-9);
  // Sample adds the noise to the increment in `from`'s frame, so the increment `from` -> `to`
  // minus the (fused) odometry increment is that noise.
  const Pose2 got = from.Between(to);
  const double ex = (got.x - d.x) / s.x, ey = (got.y - d.y) / s.y;
  const double et = WrapAngle(got.theta - d.theta) / s.theta;
  constexpr double kLog2Pi = 1.8378770664093453;
  return -0.5 * (ex * ex + ey * ey + et * et) - std::log(s.x * s.y * s.theta) - 1.5 * kLog2Pi;
}

}  // namespace omni::rbpf
