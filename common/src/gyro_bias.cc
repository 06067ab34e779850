#include "omni/common/gyro_bias.h"

#include <algorithm>
#include <cmath>

namespace omni {

void ReadGyroBiasOptions(ConfigReader r, GyroBiasOptions* o) {
  r.Get("estimate", &o->estimate, Optional());
  r.Get("chunk_s", &o->chunk_s, Optional(), InRange(0.05, 3600.0));
  r.Get("memory_s", &o->memory_s, Optional(), Positive<double>());
  r.Get("max_rad_s", &o->max_abs_rad_s, Optional(), Positive<double>());
  r.Get("still_xy_m", &o->still_xy_m, Optional(), Positive<double>());
  r.Get("still_rad", &o->still_rad, Optional(), Positive<double>());
  r.Get("edge_s", &o->edge_s, Optional(), InRange(0.0, 60.0));
}

bool StillGyroBias::Learn(double span_s, double gyro_yaw, double odometry_yaw) {
  const double sample = (gyro_yaw - odometry_yaw) / span_s;
  if (!(span_s > 0) || !std::isfinite(sample) || std::abs(sample) > o_.max_abs_rad_s) {
    ++refused_;
    return false;
  }
  learned_s_ += span_s;
  const double w =
      samples_ == 0 ? 1.0 : std::max(span_s / learned_s_, span_s / std::max(o_.memory_s, span_s));
  bias_ += w * (sample - bias_);
  ++samples_;
  return true;
}

double StillGyroBias::OdometryYawAt(int64_t t) const {
  const auto it =
      std::lower_bound(stretch_.begin(), stretch_.end(), t,
                       [](const std::pair<int64_t, double>& s, int64_t v) { return s.first < v; });
  if (it == stretch_.begin()) return it->second;
  if (it == stretch_.end()) return stretch_.back().second;
  const auto& a = *(it - 1);
  const auto& b = *it;
  const double f = static_cast<double>(t - a.first) / static_cast<double>(b.first - a.first);
  return a.second + f * (b.second - a.second);  // unwrapped (AddOdometry)
}

bool StillGyroBias::AddOdometry(int64_t t, const Pose2& p, const RawYaw& gyro) {
  if (!o_.estimate) return false;
  const int64_t edge = static_cast<int64_t>(o_.edge_s * 1e6);
  if (stretch_.empty() || t <= stretch_.back().first ||
      std::hypot(p.x - anchor_.x, p.y - anchor_.y) > o_.still_xy_m ||
      std::abs(WrapAngle(p.theta - anchor_.theta)) > o_.still_rad) {
    // Moving (or the first pose, or time not moving on): a still stretch can only begin here.
    stretch_.clear();
    stretch_.emplace_back(t, p.theta);
    anchor_ = p;
    learn_from_ = t + edge;
    return false;
  }
  // Headings relative to the anchor, unwrapped, so interpolation never crosses +-pi.
  stretch_.emplace_back(t, anchor_.theta + WrapAngle(p.theta - anchor_.theta));
  bool changed = false;
  const int64_t chunk = std::max<int64_t>(1, static_cast<int64_t>(o_.chunk_s * 1e6));
  while (t - edge - learn_from_ >= chunk) {
    const int64_t a = learn_from_, b = a + chunk;
    const std::optional<double> g = gyro(a, b);
    if (!g) {
      // The gyro's samples come later than the odometry's: next time. A chunk still not
      // covered kMaxGyroWaitS after its end never will be (no gyro, or one that started after
      // it, or whose history no longer reaches back to it): skipped, so the stop's later
      // chunks are learned and the stretch's poses do not pile up.
      if (t - edge - b <= static_cast<int64_t>(kMaxGyroWaitS * 1e6)) break;
      ++uncovered_;
      learn_from_ = b;
      continue;
    }
    changed |= Learn(1e-6 * static_cast<double>(chunk), *g, OdometryYawAt(b) - OdometryYawAt(a));
    learn_from_ = b;
  }
  // Poses older than the next chunk's start are no longer needed (keep one before it).
  while (stretch_.size() > 2 && stretch_[1].first <= learn_from_) stretch_.pop_front();
  return changed;
}

}  // namespace omni
