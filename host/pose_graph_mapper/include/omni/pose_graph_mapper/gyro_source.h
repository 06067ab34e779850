// The IMU as a continuous pose source: the gyro's yaw rate, integrated, gives the heading change
// between any two times. A gyro alone says nothing about translation, so it is used fused with
// the wheel odometry: OdometryGyroSource walks the odometry's own steps (as OdometrySource does)
// and replaces each step's heading change by the variance-weighted mean of the odometry's and the
// gyro's over the same step. The translation of every step is the odometry's, turned by the fused
// heading, so the drift of a wheel-odometry heading (slipping omni wheels, scale errors) stops
// bending the path. Each step's fused variance is that of the weighted mean, so factors still
// split step by step as continuous_source.h describes (exactly at odometry sample times).
#pragma once

#include <atomic>
#include <cstdint>
#include <optional>
#include <string>

#include "omni/common/gyro_history.h"
#include "omni/pose_graph_mapper/continuous_source.h"

namespace omni::pgm {

// Heading noise of the integrated gyro: variances linear in the step's duration (angle random
// walk and bias uncertainty) and rotation (scale-factor error).
struct GyroNoise {
  double angle_var_per_s = 1e-5;    // rad^2 per second of integration
  double angle_var_per_rad = 1e-4;  // rad^2 per radian turned
};

class GyroYawSource {
 public:
  // `bias_rad_s` is subtracted from every sample (set_bias changes it, for every interval
  // read afterwards: the samples are kept as measured); `capacity` samples are kept (oldest
  // dropped).
  explicit GyroYawSource(GyroNoise noise = {}, double bias_rad_s = 0.0, size_t capacity = 200000)
      : noise_(noise), bias_(bias_rad_s), history_(capacity) {}
  // False (to be counted by the caller) for a non-finite rate or a time older than the newest
  // sample; a repeated time replaces nothing and is also refused. A run of older samples in
  // order re-bases the stream (the newest was stamped in the future; stamp_order.h).
  bool AddSample(int64_t utime, double yaw_rate_rad_s) {
    return history_.Add(utime, yaw_rate_rad_s) != GyroRateHistory::Added::kRefused;
  }
  int64_t rebases() const { return history_.rebases(); }
  // Forgets every sample and the stream's order (the caller moved to another time line).
  void Reset() { history_.Reset(); }
  struct Yaw {
    double delta_rad = 0;
    double variance = 0;
  };
  // Heading change over [t0, t1] (the rate taken as linear between samples) with the current
  // bias removed, nullopt when the samples do not cover the interval.
  std::optional<Yaw> Between(int64_t t0_us, int64_t t1_us) const;
  // The heading change over [t0, t1] as measured (no bias removed), nullopt when not covered;
  // what a bias estimate (omni/common/gyro_bias.h) learns from.
  std::optional<double> RawBetween(int64_t t0_us, int64_t t1_us) const {
    return history_.Between(t0_us, t1_us);
  }
  double bias() const { return bias_; }
  void set_bias(double bias_rad_s) { bias_ = bias_rad_s; }
  bool empty() const { return history_.empty(); }
  size_t size() const { return history_.size(); }

 private:
  GyroNoise noise_;
  double bias_;
  GyroRateHistory history_;  // the samples as measured (bias not removed)
};

// Wheel odometry with the gyro's heading fused in, step by step (see the top of this file).
// Steps the gyro does not cover use the odometry alone and are counted (gyro_missing_steps()).
class OdometryGyroSource final : public ContinuousPoseSource {
 public:
  // Both must outlive this source.
  OdometryGyroSource(const OdometrySource* odometry, const GyroYawSource* gyro)
      : odometry_(odometry), gyro_(gyro) {}
  std::string name() const override { return "odometry+gyro"; }
  std::optional<RelativeMotion> Between(int64_t t0_us, int64_t t1_us) const override;
  uint64_t gyro_missing_steps() const { return missing_.load(std::memory_order_relaxed); }
  uint64_t gyro_fused_steps() const { return fused_.load(std::memory_order_relaxed); }

 private:
  const OdometrySource* odometry_;
  const GyroYawSource* gyro_;
  mutable std::atomic<uint64_t> missing_{0}, fused_{0};
};

}  // namespace omni::pgm
