#include "omni/pose_graph_mapper/continuous_source.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace omni::pgm {

void ComposeJacobians(const Pose2& p, const Pose2& q, Eigen::Matrix3d* a, Eigen::Matrix3d* b) {
  const double c = std::cos(p.theta), s = std::sin(p.theta);
  const double rx = c * q.x - s * q.y, ry = s * q.x + c * q.y;  // R_p q_t
  *a << 1, 0, -ry, 0, 1, rx, 0, 0, 1;
  *b << c, -s, 0, s, c, 0, 0, 0, 1;
}

Eigen::Matrix3d StepCovariance(const OdometryNoise& noise, const Pose2& step, double dt) {
  const double dist = std::hypot(step.x, step.y), rot = std::abs(step.theta);
  Eigen::Matrix3d q = Eigen::Matrix3d::Zero();
  q(0, 0) = q(1, 1) =
      noise.xy_var_per_m * dist + noise.xy_var_per_rad * rot + noise.xy_var_per_s * dt;
  q(2, 2) =
      noise.theta_var_per_m * dist + noise.theta_var_per_rad * rot + noise.theta_var_per_s * dt;
  return q;
}

Eigen::Matrix3d ComposeCovariance(const Pose2& p, const Eigen::Matrix3d& cov_p, const Pose2& q,
                                  const Eigen::Matrix3d& cov_q) {
  Eigen::Matrix3d a, b;
  ComposeJacobians(p, q, &a, &b);
  return a * cov_p * a.transpose() + b * cov_q * b.transpose();
}

void AppendStep(RelativeMotion* m, const Pose2& step, const Eigen::Matrix3d& q) {
  m->covariance = ComposeCovariance(m->delta, m->covariance, step, q);
  m->delta = m->delta * step;
}

void OdometrySource::SetNoiseScale(double scale) {
  noise_scale_ = scale;
  const OdometryNoise& b = base_noise_;
  noise_ = {b.xy_var_per_m * scale,      b.xy_var_per_rad * scale, b.theta_var_per_m * scale,
            b.theta_var_per_rad * scale, b.xy_var_per_s * scale,   b.theta_var_per_s * scale};
}

namespace {
bool Same(const Pose2& a, const Pose2& b) { return a.x == b.x && a.y == b.y && a.theta == b.theta; }
}  // namespace

bool OdometrySource::AddSample(int64_t utime, const Pose2& pose) {
  if (!samples_.empty() && utime < samples_.back().first) return false;
  if (!samples_.empty() && utime == samples_.back().first) {
    samples_.back().second = pose;
    return true;
  }
  const size_t n = samples_.size();
  if (n >= 2 && Same(samples_[n - 1].second, pose) && Same(samples_[n - 2].second, pose)) {
    // Standing still: the middle sample says nothing the two around it do not. Its step's
    // covariance is linear in the time (and isotropic in x, y), so one longer step equals two.
    samples_.back().first = utime;
    return true;
  }
  samples_.emplace_back(utime, pose);
  while (samples_.size() > capacity_) samples_.pop_front();
  return true;
}

size_t OdometrySource::SamplesAfter(int64_t utime) const {
  const auto it =
      std::upper_bound(samples_.begin(), samples_.end(), utime,
                       [](int64_t v, const std::pair<int64_t, Pose2>& s) { return v < s.first; });
  return static_cast<size_t>(samples_.end() - it);
}

Pose2 OdometrySource::At(size_t upper, int64_t utime) const {
  const auto& [tb, pb] = samples_[upper];
  if (upper == 0 || utime >= tb) return pb;
  const auto& [ta, pa] = samples_[upper - 1];
  const double f = static_cast<double>(utime - ta) / static_cast<double>(tb - ta);
  return Interpolate(pa, pb, f);
}

std::optional<std::vector<std::pair<int64_t, Pose2>>> OdometrySource::Steps(int64_t t0,
                                                                            int64_t t1) const {
  if (samples_.empty() || t1 < t0 || t0 < samples_.front().first || t1 > samples_.back().first)
    return std::nullopt;
  auto upper = [&](int64_t t) {
    // First sample with time >= t.
    return static_cast<size_t>(std::lower_bound(samples_.begin(), samples_.end(), t,
                                                [](const std::pair<int64_t, Pose2>& s, int64_t v) {
                                                  return s.first < v;
                                                }) -
                               samples_.begin());
  };
  const size_t i0 = upper(t0), i1 = upper(t1);
  std::vector<std::pair<int64_t, Pose2>> pts;
  pts.emplace_back(t0, At(i0, t0));
  for (size_t i = i0; i < i1; ++i)
    if (samples_[i].first > t0) pts.push_back(samples_[i]);
  if (t1 > pts.back().first) pts.emplace_back(t1, At(i1, t1));
  return pts;
}

std::optional<RelativeMotion> OdometrySource::Between(int64_t t0, int64_t t1) const {
  const auto steps = Steps(t0, t1);
  if (!steps) return std::nullopt;
  const auto& pts = *steps;
  RelativeMotion m;
  for (size_t k = 0; k + 1 < pts.size(); ++k) {
    const Pose2 step = CalibratedStep(pts[k].second.Between(pts[k + 1].second));
    const double dt = 1e-6 * static_cast<double>(pts[k + 1].first - pts[k].first);
    AppendStep(&m, step, StepCovariance(noise_, step, dt));
  }
  return m;
}

std::optional<RelativeMotion> NullMotionSource::Between(int64_t t0, int64_t t1) const {
  if (t1 < t0) return std::nullopt;
  const double dt = 1e-6 * static_cast<double>(t1 - t0);
  RelativeMotion m;
  m.covariance.diagonal() << xy_var_per_s_ * dt, xy_var_per_s_ * dt, theta_var_per_s_ * dt;
  return m;
}

}  // namespace omni::pgm
