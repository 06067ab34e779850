#include "omni/pose_graph_mapper/lie.h"

#include <cmath>

namespace omni::pgm {
namespace {

// A = sin(w)/w and B = (1 - cos(w))/w, with their Taylor series near 0; V(w) = [[A, -B], [B, A]].
void SE2VCoefficients(double w, double* a, double* b) {
  if (std::abs(w) < 1e-6) {
    *a = 1.0 - w * w / 6.0;
    *b = 0.5 * w - w * w * w / 24.0;
  } else {
    *a = std::sin(w) / w;
    *b = (1.0 - std::cos(w)) / w;
  }
}

}  // namespace

Pose2 ExpSE2(const Eigen::Vector3d& d) {
  double a, b;
  SE2VCoefficients(d.z(), &a, &b);
  return Pose2(a * d.x() - b * d.y(), b * d.x() + a * d.y(), WrapAngle(d.z()));
}

Eigen::Vector3d LogSE2(const Pose2& p) {
  const double w = WrapAngle(p.theta);
  double a, b;
  SE2VCoefficients(w, &a, &b);
  const double det = a * a + b * b;  // > 0 for |w| < 2 pi
  return {(a * p.x + b * p.y) / det, (-b * p.x + a * p.y) / det, w};
}

Eigen::Quaterniond ExpSO3(const Eigen::Vector3d& r) {
  const double angle = r.norm();
  if (angle < 1e-10) {
    Eigen::Quaterniond q(1.0, 0.5 * r.x(), 0.5 * r.y(), 0.5 * r.z());
    return q.normalized();
  }
  const Eigen::Vector3d axis = r / angle;
  const double s = std::sin(0.5 * angle);
  return Eigen::Quaterniond(std::cos(0.5 * angle), s * axis.x(), s * axis.y(), s * axis.z());
}

Eigen::Vector3d LogSO3(const Eigen::Quaterniond& q_in) {
  Eigen::Quaterniond q = q_in.normalized();
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  const double n = q.vec().norm();
  if (n < 1e-10) return 2.0 * q.vec() / q.w();
  const double angle = 2.0 * std::atan2(n, q.w());
  return angle * q.vec() / n;
}

// Below this squared angle the coefficients come from their Taylor series (the closed forms
// lose digits to cancellation there); the series' first omitted terms are < 1e-12.
constexpr double kSeriesBelow = 1e-4;

Eigen::Vector3d SE3V(const Eigen::Vector3d& w, const Eigen::Vector3d& v) {
  const double a2 = w.squaredNorm();
  double b, c;  // (1 - cos a)/a^2 and (a - sin a)/a^3
  if (a2 < kSeriesBelow) {
    b = 0.5 - a2 / 24.0 + a2 * a2 / 720.0;
    c = 1.0 / 6.0 - a2 / 120.0 + a2 * a2 / 5040.0;
  } else {
    const double a = std::sqrt(a2), s = std::sin(0.5 * a);
    b = 2.0 * s * s / a2;
    c = (a - std::sin(a)) / (a2 * a);
  }
  const Eigen::Vector3d wv = w.cross(v);
  return v + b * wv + c * w.cross(wv);
}

Eigen::Vector3d SE3VInverse(const Eigen::Vector3d& w, const Eigen::Vector3d& u) {
  // V^-1 = I - [w]x / 2 + d [w]x^2 with d = (1 - (a/2) cot(a/2)) / a^2.
  const double a2 = w.squaredNorm();
  double d;
  if (a2 < kSeriesBelow) {
    d = 1.0 / 12.0 + a2 / 720.0 + a2 * a2 / 30240.0;
  } else {
    const double h = 0.5 * std::sqrt(a2);
    d = (1.0 - h * std::cos(h) / std::sin(h)) / a2;
  }
  const Eigen::Vector3d wu = w.cross(u);
  return u - 0.5 * wu + d * w.cross(wu);
}

Eigen::Matrix3d RelativeInformation(const Pose2& z, const Eigen::Matrix3d& covariance,
                                    double floor) {
  const double c = std::cos(z.theta), s = std::sin(z.theta);
  Eigen::Matrix3d t = Eigen::Matrix3d::Identity();
  t.topLeftCorner<2, 2>() << c, s, -s, c;  // R_z^T
  const Eigen::Matrix3d info = (covariance + floor * Eigen::Matrix3d::Identity()).inverse();
  const Eigen::Matrix3d out = t * info * t.transpose();
  return 0.5 * (out + out.transpose());
}

}  // namespace omni::pgm
