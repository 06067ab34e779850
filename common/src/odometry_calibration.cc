#include "omni/common/odometry_calibration.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Cholesky>

namespace omni {

Pose2 OdometryCalibration::Correct(const Pose2& raw) const {
  const double x = raw.x / (1.0 + x_scale);
  const double y = raw.y - y_per_x * x;
  const double theta = (raw.theta - theta_per_x * x) / (1.0 + theta_scale);
  return Pose2(x, y, theta);
}

Pose2 OdometryCalibration::Distort(const Pose2& t) const {
  return Pose2((1.0 + x_scale) * t.x, t.y + y_per_x * t.x,
               (1.0 + theta_scale) * t.theta + theta_per_x * t.x);
}

void ReadOdometryCalibratorOptions(ConfigReader& oc, OdometryCalibratorOptions* o,
                                   bool graph_keys) {
  OdometryCalibratorOptions& cal = *o;
  oc.Get("enabled", &cal.enabled, Optional());
  oc.Get("min_pairs", &cal.min_pairs, Optional(), InRange(1, 1000000));
  oc.Get("min_forward_m", &cal.min_forward_m, Optional(), NonNegative<double>());
  oc.Get("update_every_pairs", &cal.update_every_pairs, Optional(), InRange(1, 1000000));
  oc.Get("max_abs_scale", &cal.max_abs_scale, Optional(), InRange(0.0, 0.5));
  oc.Get("max_abs_y_per_x", &cal.max_abs_y_per_x, Optional(), InRange(0.0, 0.5));
  oc.Get("max_abs_theta_per_x", &cal.max_abs_theta_per_x, Optional(), InRange(0.0, 1.0));
  oc.Get("gate_xy_m", &cal.gate_xy_m, Optional(), Positive<double>());
  oc.Get("gate_theta_rad", &cal.gate_theta_rad, Optional(), Positive<double>());
  oc.Get("max_pairs", &cal.max_pairs, Optional(), InRange(1, 10000000));
  if (!graph_keys) return;
  oc.Get("relink_on_global", &cal.relink_on_global, Optional());
  oc.Get("adapt_noise", &cal.adapt_noise, Optional());
  oc.Get("min_noise_scale", &cal.min_noise_scale, Optional(), Positive<double>());
  oc.Get("max_noise_scale", &cal.max_noise_scale, Optional(), Positive<double>());
  if (!(cal.min_noise_scale <= cal.max_noise_scale))
    oc.AddError("max_noise_scale", "must be >= min_noise_scale");
}

std::vector<std::pair<std::string, std::function<int64_t()>>> OdometryCalibrationCounters(
    const OdometryCalibrator& oc) {
  const OdometryCalibrator* p = &oc;
  auto ppm = [p](double OdometryCalibration::*field) {
    return [p, field] { return static_cast<int64_t>(std::lround(p->calibration().*field * 1e6)); };
  };
  return {{"odom_cal_pairs_used", [p] { return p->pairs_used(); }},
          {"odom_cal_pairs_gated", [p] { return p->pairs_gated(); }},
          {"odom_cal_updates", [p] { return p->updates(); }},
          {"odom_cal_x_scale_ppm", ppm(&OdometryCalibration::x_scale)},
          {"odom_cal_y_per_x_ppm", ppm(&OdometryCalibration::y_per_x)},
          {"odom_cal_theta_scale_ppm", ppm(&OdometryCalibration::theta_scale)},
          {"odom_cal_theta_per_x_ppm", ppm(&OdometryCalibration::theta_per_x)}};
}

bool OdometryCalibrator::AddPair(const Pose2& raw, const Pose2& matched,
                                 const Eigen::Matrix3d& model_covariance) {
  const bool finite = std::isfinite(raw.x) && std::isfinite(raw.y) && std::isfinite(raw.theta) &&
                      std::isfinite(matched.x) && std::isfinite(matched.y) &&
                      std::isfinite(matched.theta) && model_covariance.allFinite();
  Eigen::LDLT<Eigen::Matrix3d> ldlt(model_covariance);
  if (!finite || ldlt.info() != Eigen::Success || !(ldlt.vectorD().array() > 0).all()) {
    ++gated_;
    return false;
  }
  // Residual against the current fit (the identity before the first estimate).
  const Pose2 predicted = cal_.Distort(matched);
  if (std::hypot(raw.x - predicted.x, raw.y - predicted.y) > o_.gate_xy_m ||
      std::abs(WrapAngle(raw.theta - predicted.theta)) > o_.gate_theta_rad) {
    ++gated_;
    return false;
  }
  pairs_.push_back({raw, matched, ldlt.solve(Eigen::Matrix3d::Identity())});
  while (static_cast<int>(pairs_.size()) > o_.max_pairs) pairs_.pop_front();
  ++used_;
  ++since_update_;
  if (used_ >= o_.min_pairs && (!active_ || since_update_ >= o_.update_every_pairs)) Solve();
  return true;
}

void OdometryCalibrator::Solve() {
  // Three regressions: x and y residuals on forward motion; heading residual on heading change
  // and forward motion.
  double sxx = 0, sx_ex = 0, sx_ey = 0, stt = 0, stx = 0, st_et = 0, sx_et = 0, forward = 0;
  for (const Pair& p : pairs_) {
    const double x = p.matched.x, th = p.matched.theta;
    const double ex = p.raw.x - x, ey = p.raw.y - p.matched.y, et = WrapAngle(p.raw.theta - th);
    sxx += x * x;
    sx_ex += x * ex;
    sx_ey += x * ey;
    stt += th * th;
    stx += th * x;
    st_et += th * et;
    sx_et += x * et;
    forward += std::abs(x);
  }
  if (forward < o_.min_forward_m || sxx <= 0.0) return;
  since_update_ = 0;
  OdometryCalibration c;
  c.x_scale = std::clamp(sx_ex / sxx, -o_.max_abs_scale, o_.max_abs_scale);
  c.y_per_x = std::clamp(sx_ey / sxx, -o_.max_abs_y_per_x, o_.max_abs_y_per_x);
  // [stt stx; stx sxx] [theta_scale; theta_per_x] = [st_et; sx_et]; without enough turning
  // the scale is not observable and only the drift is fitted.
  const double det = stt * sxx - stx * stx;
  double r = 0.0, k = sx_et / sxx;
  if (stt > 0.0 && det > 1e-6 * stt * sxx) {
    r = (st_et * sxx - stx * sx_et) / det;
    k = (stt * sx_et - stx * st_et) / det;
  }
  c.theta_scale = std::clamp(r, -o_.max_abs_scale, o_.max_abs_scale);
  c.theta_per_x = std::clamp(k, -o_.max_abs_theta_per_x, o_.max_abs_theta_per_x);
  cal_ = c;
  // The noise scale: each pair's calibrated odometry residual, in its own frame, whitened by
  // the configured model.
  std::vector<double> chi2;
  chi2.reserve(pairs_.size());
  for (const Pair& p : pairs_) {
    const Pose2 e = p.matched.Between(cal_.Correct(p.raw));
    const Eigen::Vector3d v(e.x, e.y, e.theta);
    chi2.push_back(v.dot(p.information * v));
  }
  auto mid = chi2.begin() + static_cast<std::ptrdiff_t>(chi2.size() / 2);
  std::nth_element(chi2.begin(), mid, chi2.end());
  constexpr double kChi2Median3 = 2.366;  // median of chi-square, 3 degrees of freedom
  suggested_noise_scale_ = *mid / kChi2Median3;
  if (o_.adapt_noise)
    noise_scale_ = std::clamp(suggested_noise_scale_, o_.min_noise_scale, o_.max_noise_scale);
  active_ = true;
  ++updates_;
}

}  // namespace omni
