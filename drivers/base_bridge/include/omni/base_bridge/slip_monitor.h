// Wheel slip seen by the IMU's gyro. The encoders measure how far the wheels turned, not how far
// the base moved: a wheel that slips (a wet floor, a bump lifting it, a stalled roller) makes
// the wheel odometry's heading run away from the true one. The gyro measures the heading change
// directly, so over every window the two are compared: the encoders' yaw change (the bridge's
// odometry) against the gyro's integral with its bias taken out — the bias learned while the
// encoders say the base stands still (omni/common/gyro_bias.h). A window whose difference is
// beyond threshold_rad + threshold_fraction x the gyro's turn is a slipping one. Only slip that
// turns the base is seen this way; slip along a straight line leaves the heading alone.
// No bus or CAN in here: the node feeds it, time is passed in.
#pragma once

#include <cstdint>
#include <deque>
#include <string>
#include <utility>

#include "omni/common/geometry.h"
#include "omni/common/gyro_bias.h"
#include "omni/common/gyro_history.h"

namespace omni::base_bridge {

struct SlipOptions {
  bool enabled = true;              // judged only while gyro samples come (IMU on its channel)
  double window_s = 0.5;            // heading changes compared over this much time ...
  double threshold_rad = 0.02;      // ... and called slip beyond this ...
  double threshold_fraction = 0.1;  // ... plus this fraction of the gyro's turn
  double gyro_bias_rad_s = 0.0;     // where the bias estimate starts
  GyroBiasOptions bias_learning;
};

struct SlipCounters {
  int64_t gyro_in = 0;
  int64_t gyro_rejected = 0;    // non-finite, or not newer than the last sample
  int64_t windows = 0;          // windows judged (both sources covered them)
  int64_t slip_windows = 0;     // ... of which the headings disagreed
  int64_t slip_events = 0;      // runs of slipping windows
  int64_t time_rebases = 0;     // a clock that went back: the history is started over
  int64_t odom_duplicates = 0;  // odometry with the same time as the last: ignored
};

class SlipMonitor {
 public:
  explicit SlipMonitor(const SlipOptions& options);
  // The gyro's z rate (rad/s, about the base's up axis) at `utime`; false (counted) when
  // non-finite or not newer than the previous sample.
  bool AddGyro(int64_t utime, double rate_rad_s);
  // The bridge's odometry pose at `utime` (in time order; an older one restarts the history).
  void AddOdometry(int64_t utime, const Pose2& pose);

  bool slipping() const { return slipping_; }
  // "" unless slipping: what the last window saw.
  std::string Problem() const;
  const SlipCounters& counters() const { return c_; }
  double gyro_bias() const { return bias_.bias(); }
  int64_t bias_samples() const { return bias_.samples(); }
  int64_t bias_uncovered() const { return bias_.uncovered(); }

 private:
  void Judge();
  void Restart();  // forgets both histories and the verdict (a clock went back)
  bool OdomYaw(int64_t t, double* yaw) const;  // unwrapped heading, interpolated

  SlipOptions o_;
  StillGyroBias bias_;
  GyroRateHistory gyro_;                         // the samples as measured
  std::deque<std::pair<int64_t, double>> odom_;  // (utime, unwrapped heading)
  int64_t last_judged_end_ = 0;
  bool slipping_ = false;
  double last_enc_ = 0, last_gyro_ = 0;  // of the last judged window
  SlipCounters c_;
};

}  // namespace omni::base_bridge
