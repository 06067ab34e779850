// A restarted odometry source (the base bridge restarted by the supervisor, the firmware
// reset) starts its pose again at the origin and its sequence numbers again from the start.
// Handed on as it came, the restart's step is taken for motion whenever it is below the
// mappers' jump limits (max_odom_jump_m, 3 m: a robot 2 m from where the source started).
// OdometryRestartBridge lays the source's poses after a restart on from the last pose before
// it, as if the base stood still while the source was down (the firmware's watchdog stops the
// motors when commands stop).
#pragma once

#include <cstdint>
#include <optional>

#include "omni/common/geometry.h"
#include "omni/common/scan_checks.h"

namespace omni {

class OdometryRestartBridge {
 public:
  // A number at most this far below the newest is a late (reordered) sample, handed on for the
  // mappers' stamp checks; further below, the source restarted (its count began again).
  static constexpr int64_t kLateWindow = 20;

  // The pose to hand on for a sample numbered `seq` (< 0: unnumbered, never a restart). A pose
  // no odometry can have (NaN, absurd) is handed on as it came, for the mapper to refuse and
  // count, and leaves the bridge as it was: laid on from, it would spoil every pose after it.
  Pose2 Take(int64_t seq, const Pose2& raw) {
    if (!PlausibleOdometryPose(raw)) return raw;
    if (seq >= 0 && last_seq_ >= 0 && seq < last_seq_) {
      if (last_seq_ - seq <= kLateWindow) return correction_ * raw;  // late: the newest stays
      correction_ = (correction_ * last_raw_) * raw.Inverse();
      ++restarts_;
    }
    if (seq >= 0) last_seq_ = seq;
    last_raw_ = raw;
    return correction_ * raw;
  }
  int64_t restarts() const { return restarts_; }

 private:
  int64_t last_seq_ = -1;
  Pose2 last_raw_;
  Pose2 correction_;
  int64_t restarts_ = 0;
};

}  // namespace omni
