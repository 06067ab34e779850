// A gyro's yaw-rate samples as measured, with their running integral: the heading change between
// any two times they cover (the rate taken as linear between samples, so a ramp integrates
// exactly). Time order is kept as for the other streams (stamp_order.h): an older sample is
// held, not taken; when a run of them shows the clock went back (or the newest sample was
// stamped in the future) the history is re-based: the samples stamped at or after the run's
// first are dropped and the held run is taken, so no sample of the new time line is lost.
// The pose graph's gyro source and the base bridge's slip check keep their samples in one.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>

#include "omni/common/stamp_order.h"

namespace omni {

class GyroRateHistory {
 public:
  // Two samples further apart than this, or than three times the stream's recent spacing (the
  // median of its last nine steps) if that is longer, bound a gap (the IMU or its driver was
  // away): the rate inside it was not measured, and a straight line between its ends may miss a
  // whole turn. 0.5 s: five periods of the factory 10 Hz output; a 1 Hz IMU's steps are no gaps.
  static constexpr int64_t kMaxGapUs = 500000;

  explicit GyroRateHistory(size_t capacity) : capacity_(capacity < 2 ? 2 : capacity) {}

  enum class Added {
    kInOrder,  // taken
    kRebased,  // taken with the held run; the samples stamped at or after the run's first
               // (ahead of the new time line) were dropped
    kRefused,  // non-finite, the same time as the newest, or older (held: taken if a run of
               // them re-bases the history, else dropped when the run breaks)
  };
  // The oldest samples are dropped beyond `capacity`.
  Added Add(int64_t utime, double rate_rad_s);
  // The heading change over [t0, t1] (rad, as measured: no bias removed), nullopt when the
  // samples do not cover the interval or a gap (kMaxGapUs) lies inside it.
  std::optional<double> Between(int64_t t0_us, int64_t t1_us) const;
  // Forgets every sample and the stream's order (the caller moved to another time line).
  void Reset() {
    samples_.clear();
    held_.Reset();
    spacing_n_ = spacing_next_ = 0;
  }
  int64_t rebases() const { return held_.order().rebases(); }
  bool empty() const { return samples_.empty(); }
  size_t size() const { return samples_.size(); }
  int64_t newest_utime() const { return samples_.empty() ? INT64_MIN : samples_.back().utime; }

 private:
  struct Sample {
    int64_t utime;
    double rate;      // rad/s
    double integral;  // rad, from the oldest sample ever kept to this one
    int64_t gaps;     // gaps (kMaxGapUs) between the oldest sample ever kept and this one
  };
  double IntegralAt(int64_t utime) const;  // utime within the kept samples
  bool Push(int64_t utime, double rate);   // appends unless the same time as the newest

  int64_t GapUs() const;  // the gap rule's bound now (kMaxGapUs)

  size_t capacity_;
  std::deque<Sample> samples_;
  std::array<int64_t, 9> spacing_{};  // the last steps between samples, a ring
  size_t spacing_n_ = 0, spacing_next_ = 0;
  HeldRun<double> held_;
};

}  // namespace omni
