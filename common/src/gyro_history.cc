#include "omni/common/gyro_history.h"

#include <algorithm>
#include <cmath>

namespace omni {

GyroRateHistory::Added GyroRateHistory::Add(int64_t utime, double rate) {
  if (!std::isfinite(rate)) return Added::kRefused;
  bool taken = false;  // the last sample handed over (this one) was appended
  const StampOrder::Verdict v = held_.Add(
      utime, rate,
      [this](int64_t run_first) {  // the newest samples are ahead of the new time line
        while (!samples_.empty() && samples_.back().utime >= run_first) samples_.pop_back();
      },
      [this, &taken](int64_t t, double r) { taken = Push(t, r); });
  switch (v) {
    case StampOrder::Verdict::kOld:
      return Added::kRefused;
    case StampOrder::Verdict::kRebase:
      return Added::kRebased;
    case StampOrder::Verdict::kInOrder:
      break;
  }
  return taken ? Added::kInOrder : Added::kRefused;
}

bool GyroRateHistory::Push(int64_t utime, double rate) {
  double integral = 0.0;
  int64_t gaps = 0;
  if (!samples_.empty()) {
    const Sample& last = samples_.back();
    if (utime == last.utime) return false;
    integral =
        last.integral + 0.5 * (last.rate + rate) * 1e-6 * static_cast<double>(utime - last.utime);
    // Judged with itself among the recent steps (the first step cannot be told from the rate).
    const int64_t step = utime - last.utime;
    spacing_[spacing_next_] = step;
    spacing_next_ = (spacing_next_ + 1) % spacing_.size();
    spacing_n_ = std::min(spacing_n_ + 1, spacing_.size());
    gaps = last.gaps + (step > GapUs() ? 1 : 0);
  }
  samples_.push_back({utime, rate, integral, gaps});
  while (samples_.size() > capacity_) samples_.pop_front();
  return true;
}

int64_t GyroRateHistory::GapUs() const {
  if (spacing_n_ == 0) return kMaxGapUs;
  std::array<int64_t, 9> s = spacing_;
  const auto mid = s.begin() + static_cast<std::ptrdiff_t>(spacing_n_ / 2);
  std::nth_element(s.begin(), mid, s.begin() + static_cast<std::ptrdiff_t>(spacing_n_));
  return std::max(kMaxGapUs, 3 * *mid);
}

double GyroRateHistory::IntegralAt(int64_t t) const {
  const auto it = std::lower_bound(samples_.begin(), samples_.end(), t,
                                   [](const Sample& s, int64_t v) { return s.utime < v; });
  if (it->utime == t || it == samples_.begin()) return it->integral;
  const Sample& a = *(it - 1);
  const Sample& b = *it;
  const double dt = 1e-6 * static_cast<double>(t - a.utime);
  const double span = 1e-6 * static_cast<double>(b.utime - a.utime);
  const double rate_t = a.rate + (b.rate - a.rate) * dt / span;
  return a.integral + 0.5 * (a.rate + rate_t) * dt;
}

std::optional<double> GyroRateHistory::Between(int64_t t0, int64_t t1) const {
  if (samples_.empty() || t1 < t0 || t0 < samples_.front().utime || t1 > samples_.back().utime)
    return std::nullopt;
  // The samples around the interval: the last at or before t0, the first at or after t1.
  const auto before = [](int64_t v, const Sample& s) { return v < s.utime; };
  const auto after = [](const Sample& s, int64_t v) { return s.utime < v; };
  const auto lo = std::upper_bound(samples_.begin(), samples_.end(), t0, before) - 1;
  const auto hi = std::lower_bound(samples_.begin(), samples_.end(), t1, after);
  if (hi->gaps != lo->gaps) return std::nullopt;
  return IntegralAt(t1) - IntegralAt(t0);
}

}  // namespace omni
