// Time as passed into algorithms: a Clock interface so replays and tests control time.
#pragma once

#include <chrono>
#include <cstdint>
#include <limits>

namespace omni {

// Microseconds since the Unix epoch, the unit of every `utime` on the bus.
using Utime = int64_t;

inline double UtimeToSeconds(Utime t) { return static_cast<double>(t) * 1e-6; }
// Rounded to the microsecond. A NaN or a time beyond what an int64 of microseconds holds
// (+-292,000 years) saturates to INT64_MIN / INT64_MAX instead of the undefined conversion;
// readers refuse such stamps (the CARMEN reader already at +-73,000 years).
inline Utime SecondsToUtime(double s) {
  if (!(s > -9.2e12 && s < 9.2e12)) {
    return s > 0 ? std::numeric_limits<Utime>::max() : std::numeric_limits<Utime>::min();
  }
  return static_cast<Utime>(s * 1e6 + (s >= 0 ? 0.5 : -0.5));
}

class Clock {
 public:
  virtual ~Clock() = default;
  virtual Utime NowUtime() const = 0;
};

// Wall clock (system_clock), for processes talking to real devices.
class SystemClock final : public Clock {
 public:
  Utime NowUtime() const override {
    return std::chrono::duration_cast<std::chrono::microseconds>(
               std::chrono::system_clock::now().time_since_epoch())
        .count();
  }
};

// Whether a periodic action on a wall clock is due: never done (`last` 0), `period_us` passed,
// or the clock is now before `last` — set back by NTP or by hand — in which case waiting for it
// to come back to `last` would silence the action for as long as the step (heartbeats, grids,
// the base's commands), so the action runs and the caller's `last = now` re-bases it.
inline bool PeriodDue(Utime now, Utime last, int64_t period_us) {
  return last == 0 || now < last || now - last >= period_us;
}

// Monotonic clock in microseconds, for measuring durations.
inline int64_t MonotonicMicros() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// A clock that moves only when told: tests and log replay.
class ManualClock final : public Clock {
 public:
  explicit ManualClock(Utime start = 0) : now_(start) {}
  Utime NowUtime() const override { return now_; }
  void Set(Utime t) { now_ = t; }
  void Advance(Utime dt) { now_ += dt; }

 private:
  Utime now_;
};

}  // namespace omni
