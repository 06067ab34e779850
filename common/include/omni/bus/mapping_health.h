// Whether a mapper maps what it is given: over each window, scans came in but most were
// dropped for want of odometry (the base bridge stopped, WHEEL_ODOM on another channel), or most
// could not be used (too few valid beams: a covered lidar, range limits that leave out every
// return; or an impossible geometry), make the process DEGRADED in its heartbeat, so
// `omni status` and the supervisor see it; counters alone showed it while the state still said
// "mapping".
#pragma once

#include <cstdint>
#include <string>

#include "omni/bus/heartbeat.h"
#include "omni/common/time.h"
#include "omni/heartbeat_t.hpp"

namespace omni {

class MappingHealth {
 public:
  explicit MappingHealth(int64_t window_us = 5000000) : window_us_(window_us) {}

  // The cumulative counters as they stand at `now_us`. At the end of each window the verdict
  // is taken from what the window added: degraded when scans came and at least half of them
  // had no odometry, or at least half could not be used; a window with no scan keeps the last
  // verdict.
  void Update(Utime now_us, int64_t scans_in, int64_t scans_without_odometry,
              int64_t scans_unusable = 0) {
    if (!started_) {
      started_ = true;
      window_start_us_ = now_us;
      in0_ = scans_in;
      dropped0_ = scans_without_odometry;
      unusable0_ = scans_unusable;
      return;
    }
    if (!PeriodDue(now_us, window_start_us_, window_us_)) return;
    const int64_t in = scans_in - in0_, dropped = scans_without_odometry - dropped0_,
                  unusable = scans_unusable - unusable0_;
    if (in > 0) {
      const std::string of = std::to_string(in) + " scans in the last " +
                             std::to_string(window_us_ / 1000000) + " s: nothing mapped";
      degraded_ = true;
      if (2 * dropped >= in) {
        text_ = "no odometry for " + std::to_string(dropped) + " of " + of +
                " (is the base bridge publishing odometry?)";
      } else if (2 * unusable >= in) {
        text_ = "too few valid beams or a bad geometry in " + std::to_string(unusable) + " of " +
                of + " (lidar covered? range limits or the driver's config?)";
      } else {
        degraded_ = false;
      }
    }
    window_start_us_ = now_us;
    in0_ = scans_in;
    dropped0_ = scans_without_odometry;
    unusable0_ = scans_unusable;
  }
  // Update, then put the verdict in `heartbeat`'s state: DEGRADED with the reason, and OK with
  // `ok_text` when it has just cleared (otherwise the state is the caller's).
  void Report(Utime now_us, int64_t scans_in, int64_t scans_without_odometry,
              int64_t scans_unusable, bus::Heartbeat* heartbeat, const std::string& ok_text) {
    const bool was = degraded_;
    Update(now_us, scans_in, scans_without_odometry, scans_unusable);
    if (degraded_)
      heartbeat->SetState(omni::heartbeat_t::STATE_DEGRADED, text_);
    else if (was)
      heartbeat->SetState(omni::heartbeat_t::STATE_OK, ok_text);
  }
  bool degraded() const { return degraded_; }
  const std::string& text() const { return text_; }

 private:
  int64_t window_us_;
  bool started_ = false;
  Utime window_start_us_ = 0;
  int64_t in0_ = 0, dropped0_ = 0, unusable0_ = 0;
  bool degraded_ = false;
  std::string text_;
};

}  // namespace omni
