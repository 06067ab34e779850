// Continuous pose sources (OmniMapper's "pose plugins"): sources that can say how the robot moved
// between ANY two times, so that the mapper links every pair of consecutive poses with one
// factor however fast the source's own data arrives.
//
// A factor for [t0, t1] is the relative pose of the robot at t1 in its frame at t0 with a
// covariance over (x_m, y_m, theta_rad) in that frame. The covariance is propagated step by step
// over the source's samples inside the interval (each step's noise is linear in its length,
// rotation and duration), so for a split time t at a sample
//   Sigma(t0, t1) = A Sigma(t0, t) A^T + B Sigma(t, t1) B^T      (A, B: Jacobians of composition)
// holds exactly: replacing one factor by two (pose splicing) neither adds nor loses information.
// Inside a sample interval the split point is interpolated and the identity holds to first order.
#pragma once

#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "omni/common/geometry.h"
#include "omni/common/odometry_calibration.h"

namespace omni::pgm {

struct RelativeMotion {
  Pose2 delta;  // pose at t1 in the frame of the pose at t0
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
};

class ContinuousPoseSource {
 public:
  virtual ~ContinuousPoseSource() = default;
  virtual std::string name() const = 0;
  // Motion over [t0_us, t1_us] (t0 <= t1); nullopt when the source cannot cover the interval
  // (no data yet for t1, or data already dropped for t0).
  virtual std::optional<RelativeMotion> Between(int64_t t0_us, int64_t t1_us) const = 0;
};

// Per-step noise: standard deviations grow with the square root of the step's translation,
// rotation and duration (variances linear in them), so splitting a step splits its variance.
struct OdometryNoise {
  double xy_var_per_m = 1e-3;       // m^2 of position variance per metre travelled
  double xy_var_per_rad = 1e-4;     // m^2 per radian turned
  double theta_var_per_m = 1e-4;    // rad^2 per metre travelled
  double theta_var_per_rad = 1e-3;  // rad^2 per radian turned
  double xy_var_per_s = 1e-6;       // m^2 per second, even when standing still
  double theta_var_per_s = 1e-6;    // rad^2 per second
};

// Composition Jacobians of D = P (+) Q (SE(2)), in the frame of P's origin.
void ComposeJacobians(const Pose2& p, const Pose2& q, Eigen::Matrix3d* a, Eigen::Matrix3d* b);
// Covariance of P (+) Q from P's (over its coordinates) and Q's (in P's frame), independent:
// A cov_p A^T + B cov_q B^T.
Eigen::Matrix3d ComposeCovariance(const Pose2& p, const Eigen::Matrix3d& cov_p, const Pose2& q,
                                  const Eigen::Matrix3d& cov_q);

// Covariance of one odometry step (in its start frame) lasting `dt_s` seconds.
Eigen::Matrix3d StepCovariance(const OdometryNoise& noise, const Pose2& step, double dt_s);
// m <- m (+) step, the step with covariance `q`: Sigma <- A Sigma A^T + B q B^T.
void AppendStep(RelativeMotion* m, const Pose2& step, const Eigen::Matrix3d& q);

// Wheel odometry: a time-ordered buffer of odometry poses (in the odometry frame), interpolated.
// Every step between two samples passes through the calibration (odometry_calibration.h; the
// identity unless set) before it is composed, so a new calibration applies to every factor
// asked for afterwards, including intervals whose samples arrived before it.
class OdometrySource final : public ContinuousPoseSource {
 public:
  explicit OdometrySource(OdometryNoise noise = {}, size_t capacity = 100000)
      : base_noise_(noise), noise_(noise), capacity_(capacity) {}
  std::string name() const override { return "odometry"; }
  // False (to be counted by the caller) when utime is older than the newest sample. A pose equal
  // to the two before it (a base standing still) moves the newest sample's time instead of
  // adding one: interpolation and Between() give exactly the same, and a parked robot does not
  // run the buffer out.
  bool AddSample(int64_t utime, const Pose2& odom_pose);
  // Samples held, how many at most, and how many are stamped after `utime`.
  size_t size() const { return samples_.size(); }
  size_t capacity() const { return capacity_; }
  size_t SamplesAfter(int64_t utime) const;
  std::optional<RelativeMotion> Between(int64_t t0_us, int64_t t1_us) const override;
  // The odometry poses at t0, at every sample strictly inside (t0, t1) and at t1 (interpolated
  // at the ends): the steps Between() composes. nullopt when [t0, t1] is not covered.
  std::optional<std::vector<std::pair<int64_t, Pose2>>> Steps(int64_t t0_us, int64_t t1_us) const;
  // The noise model in use: the configured one times noise_scale() (every term).
  const OdometryNoise& noise() const { return noise_; }
  double noise_scale() const { return noise_scale_; }
  void SetNoiseScale(double scale);
  void SetCalibration(const OdometryCalibration& c) { calibration_ = c; }
  const OdometryCalibration& calibration() const { return calibration_; }
  // One raw step between two of Steps()' poses, calibrated.
  Pose2 CalibratedStep(const Pose2& raw) const {
    return calibration_.IsIdentity() ? raw : calibration_.Correct(raw);
  }
  int64_t newest_utime() const { return samples_.empty() ? 0 : samples_.back().first; }
  int64_t oldest_utime() const { return samples_.empty() ? 0 : samples_.front().first; }
  bool empty() const { return samples_.empty(); }
  Pose2 newest_pose() const { return samples_.empty() ? Pose2() : samples_.back().second; }
  // Drops the samples stamped at or after `utime` (they were stamped in the future); how many.
  int64_t DropFrom(int64_t utime) {
    int64_t n = 0;
    for (; !samples_.empty() && samples_.back().first >= utime; ++n) samples_.pop_back();
    return n;
  }

 private:
  Pose2 At(size_t upper, int64_t utime) const;  // interpolated in [upper-1, upper]

  OdometryNoise base_noise_, noise_;
  double noise_scale_ = 1.0;
  OdometryCalibration calibration_;
  size_t capacity_;
  std::deque<std::pair<int64_t, Pose2>> samples_;
};

// No motion information at all: zero motion with variance growing linearly with time, so the
// graph stays connected when no other continuous source is running.
class NullMotionSource final : public ContinuousPoseSource {
 public:
  NullMotionSource(double xy_var_per_s, double theta_var_per_s)
      : xy_var_per_s_(xy_var_per_s), theta_var_per_s_(theta_var_per_s) {}
  std::string name() const override { return "null_motion"; }
  std::optional<RelativeMotion> Between(int64_t t0_us, int64_t t1_us) const override;

 private:
  double xy_var_per_s_, theta_var_per_s_;
};

}  // namespace omni::pgm
