// Motion model of an omnidirectional base: the odometry increment (dx forward, dy left, dtheta)
// in the frame of the previous pose gets independent Gaussian noise on each axis, with standard
// deviations growing with the motion. Lateral slip (dy noise) grows with both forward and
// sideways travel, since an omni base moves sideways as freely as forward.
//   sigma_x     = min_xy + a_xx |dx| + a_xy |dy| + a_xt |dtheta|
//   sigma_y     = min_xy + a_yx |dx| + a_yy |dy| + a_yt |dtheta|
//   sigma_theta = min_t  + a_tt |dtheta| + a_td sqrt(dx^2 + dy^2)
// Optional IMU fusion: when the gyro's integrated yaw over the same interval is given, the
// heading increment is the variance-weighted mean of odometry's and the gyro's.
#pragma once

#include <optional>
#include <random>

#include "omni/common/geometry.h"

namespace omni::rbpf {

struct MotionNoise {
  // Sized for odometry whose systematic error the calibration takes out (RbpfOptions::
  // odometry_calibration); twice these were measured worse with it and as good without it.
  double a_xx = 0.05, a_xy = 0.025, a_xt = 0.025;  // m/m, m/m, m/rad
  double a_yx = 0.025, a_yy = 0.05, a_yt = 0.025;
  double a_tt = 0.05, a_td = 0.025;  // rad/rad, rad/m
  double min_xy_m = 0.005, min_theta_rad = 0.002;
  double imu_yaw_sigma_per_rad = 0.02;  // gyro heading increment noise, rad per rad turned
  double imu_yaw_sigma_min_rad = 0.002;
};

struct MotionSigma {
  double x = 0, y = 0, theta = 0;
};

class OmniMotionModel {
 public:
  explicit OmniMotionModel(const MotionNoise& noise = {}) : n_(noise) {}

  // Standard deviations of the noise for an odometry increment (frame of the previous pose).
  MotionSigma Sigma(const Pose2& delta) const;
  // Fuses a gyro heading increment into the odometry increment (returns the fused increment
  // and writes its heading sigma).
  Pose2 FuseImuYaw(const Pose2& delta, double imu_dtheta_rad, double* theta_sigma) const;
  // Draws a new pose: from * (delta + noise). `imu_dtheta_rad`: optional gyro increment.
  Pose2 Sample(const Pose2& from, const Pose2& delta, std::mt19937_64& rng,
               std::optional<double> imu_dtheta_rad = std::nullopt) const;
  // Log density (per m^2 rad) of Sample(from, delta, ., imu_dtheta_rad) drawing `to`: the
  // motion prior p(to | from, odometry) of the improved proposal.
  double LogDensity(const Pose2& from, const Pose2& delta, const Pose2& to,
                    std::optional<double> imu_dtheta_rad = std::nullopt) const;
  const MotionNoise& noise() const { return n_; }

 private:
  MotionNoise n_;
};

}  // namespace omni::rbpf
