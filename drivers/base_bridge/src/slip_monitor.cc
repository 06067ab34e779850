#include "omni/base_bridge/slip_monitor.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>

namespace omni::base_bridge {
namespace {
constexpr size_t kKeep = 4096;  // samples of each source kept (40 s at 100 Hz)
}

SlipMonitor::SlipMonitor(const SlipOptions& options)
    : o_(options), bias_(options.bias_learning, options.gyro_bias_rad_s), gyro_(kKeep) {
  Restart();
}

void SlipMonitor::Restart() {
  gyro_.Reset();
  odom_.clear();
  bias_.Reset();
  last_judged_end_ = std::numeric_limits<int64_t>::min() / 2;
  slipping_ = false;
}

bool SlipMonitor::AddGyro(int64_t t, double rate) {
  ++c_.gyro_in;
  switch (gyro_.Add(t, rate)) {
    case GyroRateHistory::Added::kRefused:  // non-finite, older, or the same time
      ++c_.gyro_rejected;
      return false;
    case GyroRateHistory::Added::kRebased:  // the clock went back, or one was from the future
      ++c_.time_rebases;
      last_judged_end_ = std::numeric_limits<int64_t>::min() / 2;
      slipping_ = false;
      break;
    case GyroRateHistory::Added::kInOrder:
      break;
  }
  Judge();
  return true;
}

void SlipMonitor::AddOdometry(int64_t t, const Pose2& p) {
  if (!odom_.empty() && t == odom_.back().first) {
    ++c_.odom_duplicates;  // the same time again (a coarse clock): nothing new
    return;
  }
  if (!odom_.empty() && t < odom_.back().first) {
    // The bridge's own clock went back: start over (the windows need one time line); the
    // gyro's samples on the old clock go too, the IMU driver's clock being the same.
    ++c_.time_rebases;
    Restart();
  }
  const double yaw =
      odom_.empty() ? p.theta : odom_.back().second + WrapAngle(p.theta - odom_.back().second);
  odom_.emplace_back(t, yaw);
  while (odom_.size() > kKeep) odom_.pop_front();
  // A gyro that fell silent judges nothing: the last verdict does not stand for it.
  const int64_t window = static_cast<int64_t>(o_.window_s * 1e6);
  if (gyro_.empty() || t - gyro_.newest_utime() > 2 * window) slipping_ = false;
  if (!gyro_.empty())  // no IMU (yet): nothing to learn the bias from
    bias_.AddOdometry(t, p, [this](int64_t a, int64_t b) { return gyro_.Between(a, b); });
  Judge();
}

bool SlipMonitor::OdomYaw(int64_t t, double* yaw) const {
  if (odom_.empty() || t < odom_.front().first || t > odom_.back().first) return false;
  const auto it =
      std::lower_bound(odom_.begin(), odom_.end(), t,
                       [](const std::pair<int64_t, double>& s, int64_t v) { return s.first < v; });
  if (it->first == t || it == odom_.begin()) {
    *yaw = it->second;
    return true;
  }
  const auto& a = *(it - 1);
  const double f = static_cast<double>(t - a.first) / static_cast<double>(it->first - a.first);
  *yaw = a.second + f * (it->second - a.second);
  return true;
}

void SlipMonitor::Judge() {
  if (!o_.enabled || gyro_.empty() || odom_.empty()) return;
  const int64_t window = static_cast<int64_t>(o_.window_s * 1e6);
  const int64_t step = std::max<int64_t>(1, window / 2);  // windows overlap by half
  const int64_t end = std::min(gyro_.newest_utime(), odom_.back().first);
  if (end - last_judged_end_ < step) return;
  const std::optional<double> g = gyro_.Between(end - window, end);
  double e0 = 0, e1 = 0;
  if (!g || !OdomYaw(end - window, &e0) || !OdomYaw(end, &e1)) return;
  last_judged_end_ = end;
  last_gyro_ = *g - bias_.bias() * o_.window_s;
  last_enc_ = e1 - e0;
  ++c_.windows;
  const bool slip = std::abs(last_enc_ - last_gyro_) >
                    o_.threshold_rad + o_.threshold_fraction * std::abs(last_gyro_);
  if (slip) {
    ++c_.slip_windows;
    if (!slipping_) ++c_.slip_events;
  }
  slipping_ = slip;
}

std::string SlipMonitor::Problem() const {
  if (!slipping_) return "";
  char buf[160];
  std::snprintf(buf, sizeof(buf),
                "wheels slipping: the encoders turned %.3f rad, the gyro %.3f rad in %.2f s",
                last_enc_, last_gyro_, o_.window_s);
  return buf;
}

}  // namespace omni::base_bridge
