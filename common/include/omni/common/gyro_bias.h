// A gyro's bias learned while the base stands still. A MEMS gyro's zero-rate output changes from
// power-up to power-up and with temperature, so a bias from a config file is only where the
// estimate starts. While the wheel odometry says the base stands still, every `chunk_s` of the
// still stretch is one sample of the bias: the gyro's mean rate minus the odometry's over it.
// Used by both mappers that fuse the gyro (the pose graph's gyro source, the RBPF's motion
// model); they own the gyro's samples and hand in their raw integral.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <optional>
#include <utility>

#include "omni/common/config.h"
#include "omni/common/geometry.h"

namespace omni {

struct GyroBiasOptions {
  bool estimate = true;
  double chunk_s = 1.0;         // one bias sample per this much standing still
  double memory_s = 300.0;      // of still time: a running mean up to this, then fading
  double max_abs_rad_s = 0.03;  // a sample beyond this is refused (turned without its wheels)
  double still_xy_m = 0.002;    // still: the odometry stays within this distance ...
  double still_rad = 0.002;     // ... and this heading of where it stopped
  double edge_s = 0.2;          // left out at both ends of a still stretch (stopping, starting)
};

// Reads the keys of a `bias_learning:` section (estimate, chunk_s, memory_s, max_rad_s,
// still_xy_m, still_rad, edge_s; each optional) into `o`.
void ReadGyroBiasOptions(ConfigReader section, GyroBiasOptions* o);

class StillGyroBias {
 public:
  explicit StillGyroBias(GyroBiasOptions options = {}, double initial_bias_rad_s = 0.0)
      : o_(options), bias_(initial_bias_rad_s) {}

  // The gyro's heading change over [t0, t1] as measured (bias not removed), nullopt while its
  // samples do not cover the interval yet.
  using RawYaw = std::function<std::optional<double>(int64_t t0_us, int64_t t1_us)>;
  // An odometry pose at `utime`, in time order. Follows the still stretches and takes a bias
  // sample from every whole chunk of one that ends edge_s before `utime`; a chunk the gyro does
  // not cover yet is tried again with the next pose, and skipped (uncovered()) once it is
  // kMaxGyroWaitS old. Returns true when the bias changed.
  bool AddOdometry(int64_t utime, const Pose2& pose, const RawYaw& gyro);
  // Forgets the open still stretch (the caller's clock stepped, or samples were dropped).
  void Reset() { stretch_.clear(); }

  // One sample: over `span_s` the gyro turned by `gyro_yaw_rad` (as measured) and the odometry
  // by `odometry_yaw_rad`. The estimate is the samples' running mean until memory_s of them,
  // then an exponential average with that time constant; the first replaces the initial bias.
  // False (counted as refused) for a sample beyond max_abs_rad_s.
  bool Learn(double span_s, double gyro_yaw_rad, double odometry_yaw_rad);

  // A chunk the gyro has not covered this long after its end is skipped (counted).
  static constexpr double kMaxGyroWaitS = 5.0;

  double bias() const { return bias_; }
  int64_t samples() const { return samples_; }
  int64_t refused() const { return refused_; }
  int64_t uncovered() const { return uncovered_; }       // chunks skipped: no gyro samples for them
  size_t held_poses() const { return stretch_.size(); }  // of the open still stretch
  const GyroBiasOptions& options() const { return o_; }

 private:
  double OdometryYawAt(int64_t utime) const;  // within stretch_, interpolated

  GyroBiasOptions o_;
  double bias_;
  double learned_s_ = 0;  // still time behind the estimate
  int64_t samples_ = 0, refused_ = 0, uncovered_ = 0;
  // The open still stretch: its poses (time, heading) from where it began, the first one its
  // anchor; learn_from_ is where the next chunk starts.
  std::deque<std::pair<int64_t, double>> stretch_;
  Pose2 anchor_;
  int64_t learn_from_ = 0;
};

}  // namespace omni
