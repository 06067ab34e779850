#include "omni/firmware/speed_estimator.h"

#include "omni/firmware/quadrature.h"

namespace omni::firmware {

void SpeedEstimator::Reset(int32_t position) {
  for (int32_t& p : pos_) p = position;
  head_ = 0;
  filled_ = 1;
  since_change_ = kHistory;
  speed_ = 0.f;
}

float SpeedEstimator::Update(int32_t position) {
  const bool changed = position != pos_[head_];
  head_ = (head_ + 1) & (kHistory - 1);
  pos_[head_] = position;
  if (filled_ < kHistory) ++filled_;
  since_change_ = changed ? 0 : (since_change_ < kHistory ? since_change_ + 1 : kHistory);
  if (since_change_ >= kHistory - 1) {
    speed_ = 0.f;  // below one count per history: standing still as far as we can tell
    return speed_;
  }
  static constexpr int kWindows[] = {4, 8, 16, 32, kHistory - 1};
  float speed = 0.f;
  for (int window : kWindows) {
    const int w = window < filled_ - 1 ? window : filled_ - 1;
    // A change at age a: the count moved between samples a+1 and a.
    int newest = -1, oldest = -1;
    for (int a = 0; a < w; ++a) {
      if (At(a) != At(a + 1)) {
        if (newest < 0) newest = a;
        oldest = a;
      }
    }
    const bool last_window = (w == kHistory - 1) || (w == filled_ - 1);
    if (newest >= 0 && oldest > newest) {
      const int32_t counts = CountsBetween(At(oldest), At(newest));
      if (counts >= kMinCounts || counts <= -kMinCounts || last_window) {
        speed = static_cast<float>(counts) / static_cast<float>(oldest - newest);
        break;
      }
    } else if (last_window) {
      // One change only: bounded by one change over the time since it.
      if (newest >= 0) {
        speed = static_cast<float>(CountsBetween(At(newest + 1), At(newest))) /
                static_cast<float>(since_change_ + 1);
      }
      break;
    }
  }
  // No count for `since_change_` periods: the speed is below one count per that time.
  if (since_change_ > 0) {
    const float bound = 1.f / static_cast<float>(since_change_);
    if (speed > bound) speed = bound;
    if (speed < -bound) speed = -bound;
  }
  speed_ = speed;
  return speed_;
}

}  // namespace omni::firmware
