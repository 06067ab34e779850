// Wheel speed from a counter sampled at a fixed rate, sane from standstill to full speed.
//
// Counts arrive quantised (1440 counts per wheel turn on the reference base), so a plain
// difference over one period is useless at low speed (0 or 1 count per ms) and a long window
// adds lag at high speed. The estimator keeps the last kHistory positions and picks the
// shortest window (4, 8, 16, 32 or kHistory-1 periods) that holds at least kMinCounts counts;
// inside it, speed = counts between the first and the last count change / the time between
// those changes (edge-to-edge timing, the "M/T" method with the period as time base).
// When no count arrived for longer than the last edge interval, the speed is bounded by one
// count over the time since the last change, so it decays to zero instead of holding; after
// kHistory periods without a change it is zero.
#pragma once

#include <cstdint>

namespace omni::firmware {

class SpeedEstimator {
 public:
  static constexpr int kHistory = 64;    // periods of history (64 ms at 1 kHz)
  static constexpr int kMinCounts = 12;  // counts a window needs to be trusted

  void Reset(int32_t position);
  // Feeds the position of this period; returns the speed in counts per period.
  float Update(int32_t position);
  float counts_per_period() const { return speed_; }
  // Periods since the position last changed (saturates at kHistory).
  int periods_since_change() const { return since_change_; }

 private:
  int32_t pos_[kHistory] = {};
  int head_ = 0;  // index of the newest sample
  int filled_ = 0;
  int since_change_ = kHistory;
  float speed_ = 0.f;
  int32_t At(int age) const { return pos_[(head_ - age) & (kHistory - 1)]; }
  static_assert((kHistory & (kHistory - 1)) == 0, "kHistory must be a power of two");
};

}  // namespace omni::firmware
