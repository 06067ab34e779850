// SE(2)/SE(3) helpers on Eigen: angle wrapping, composition, interpolation in time.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "omni/common/stamp_order.h"

namespace omni {

// Wraps an angle to (-pi, pi].
template <typename T>
inline T WrapAngle(T a) {
  const T two_pi = T(2.0 * M_PI);
  a = std::fmod(a + T(M_PI), two_pi);
  if (a <= T(0)) a += two_pi;
  return a - T(M_PI);
}

// A planar pose: position in metres and heading in radians (CCW), of a child frame in a parent.
struct Pose2 {
  double x = 0, y = 0, theta = 0;

  Pose2() = default;
  Pose2(double x_m, double y_m, double theta_rad) : x(x_m), y(y_m), theta(theta_rad) {}

  // this * other: `other` expressed in this pose's frame, mapped to the parent frame.
  Pose2 operator*(const Pose2& o) const {
    const double c = std::cos(theta), s = std::sin(theta);
    return {x + c * o.x - s * o.y, y + s * o.x + c * o.y, WrapAngle(theta + o.theta)};
  }
  Pose2 Inverse() const {
    const double c = std::cos(theta), s = std::sin(theta);
    return {-c * x - s * y, s * x - c * y, WrapAngle(-theta)};
  }
  // The pose of `o` seen from this pose: this^-1 * o.
  Pose2 Between(const Pose2& o) const { return Inverse() * o; }
  Eigen::Vector2d Transform(const Eigen::Vector2d& p) const {
    const double c = std::cos(theta), s = std::sin(theta);
    return {x + c * p.x() - s * p.y(), y + s * p.x() + c * p.y()};
  }
  Eigen::Vector2d translation() const { return {x, y}; }
  Eigen::Isometry3d ToIsometry3() const {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = Eigen::AngleAxisd(theta, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    t.translation() = Eigen::Vector3d(x, y, 0);
    return t;
  }
};

// Linear interpolation of position and shortest-arc interpolation of heading; f in [0, 1].
inline Pose2 Interpolate(const Pose2& a, const Pose2& b, double f) {
  return {a.x + f * (b.x - a.x), a.y + f * (b.y - a.y),
          WrapAngle(a.theta + f * WrapAngle(b.theta - a.theta))};
}

// Linear interpolation of translation and slerp of rotation; f in [0, 1].
inline Eigen::Isometry3d Interpolate(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b,
                                     double f) {
  const Eigen::Quaterniond qa(a.linear()), qb(b.linear());
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  out.linear() = qa.slerp(f, qb).toRotationMatrix();
  out.translation() = a.translation() + f * (b.translation() - a.translation());
  return out;
}

// A time-ordered buffer of stamped poses with interpolation ("pose at time t").
// Out-of-order inserts are rejected (and can be counted by the caller).
template <typename PoseT>
class StampedBuffer {
 public:
  explicit StampedBuffer(size_t capacity = 10000) : capacity_(capacity) {}

  // Returns false when utime is older than the newest entry (out of order). Rejected entries
  // that run in order among themselves are held; when a run reaches StampOrder's length, the
  // newest entries were stamped in the future (or the source's clock went back): they are
  // dropped and the run is taken in their place (`rebases()` counts it, `dropped_on_rebase()`
  // the entries dropped).
  bool Insert(int64_t utime, const PoseT& pose) {
    const auto drop_from = [this](int64_t from) {
      for (; !items_.empty() && items_.back().first >= from; ++dropped_on_rebase_)
        items_.pop_back();
    };
    const auto append = [this](int64_t t, const PoseT& p) { Append(t, p); };
    return stream_.Add(utime, pose, drop_from, append) != StampOrder::Verdict::kOld;
  }

  // Interpolated pose at `utime`; nullopt when outside [oldest, newest] by more than `slack_us`
  // (within the slack the nearest end is returned). Two neighbouring samples more than
  // `max_span_us` apart bound a gap (the source was down, or the later one was stamped in the
  // future): inside it the same rule as at the ends applies instead of interpolation.
  std::optional<PoseT> At(int64_t utime, int64_t slack_us = 0,
                          int64_t max_span_us = std::numeric_limits<int64_t>::max()) const {
    if (items_.empty()) return std::nullopt;
    if (utime <= items_.front().first) {
      if (items_.front().first - utime > slack_us) return std::nullopt;
      return items_.front().second;
    }
    if (utime >= items_.back().first) {
      if (utime - items_.back().first > slack_us) return std::nullopt;
      return items_.back().second;
    }
    size_t lo = 0, hi = items_.size() - 1;
    while (hi - lo > 1) {
      const size_t mid = (lo + hi) / 2;
      if (items_[mid].first <= utime)
        lo = mid;
      else
        hi = mid;
    }
    const auto& a = items_[lo];
    const auto& b = items_[hi];
    if (b.first - a.first > max_span_us) {
      if (utime - a.first <= slack_us) return a.second;
      if (b.first - utime <= slack_us) return b.second;
      return std::nullopt;
    }
    const double f = static_cast<double>(utime - a.first) / static_cast<double>(b.first - a.first);
    return Interpolate(a.second, b.second, f);
  }

  // The entries stamped strictly between `t0` and `t1`, oldest first (none when t1 <= t0).
  std::vector<PoseT> Inside(int64_t t0, int64_t t1) const {
    std::vector<PoseT> out;
    if (t1 <= t0) return out;
    auto it = std::upper_bound(items_.begin(), items_.end(), t0,
                               [](int64_t t, const auto& item) { return t < item.first; });
    for (; it != items_.end() && it->first < t1; ++it) out.push_back(it->second);
    return out;
  }

  bool empty() const { return items_.empty(); }
  size_t size() const { return items_.size(); }
  int64_t newest_utime() const { return items_.empty() ? 0 : items_.back().first; }
  int64_t oldest_utime() const { return items_.empty() ? 0 : items_.front().first; }
  int64_t rebases() const { return stream_.order().rebases(); }
  // Drops the entries stamped at or after `utime` (the caller re-bases the stream itself).
  void DropFrom(int64_t utime) {
    while (!items_.empty() && items_.back().first >= utime) items_.pop_back();
    stream_.Reset();
    if (!items_.empty()) stream_.Seed(items_.back().first);
  }
  int64_t dropped_on_rebase() const { return dropped_on_rebase_; }

 private:
  void Append(int64_t utime, const PoseT& pose) {
    if (!items_.empty() && utime == items_.back().first) {
      items_.back().second = pose;
      return;
    }
    items_.emplace_back(utime, pose);
    while (items_.size() > capacity_) items_.pop_front();
  }

  size_t capacity_;
  std::deque<std::pair<int64_t, PoseT>> items_;
  HeldRun<PoseT> stream_;
  int64_t dropped_on_rebase_ = 0;
};

}  // namespace omni
