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

}  // namespace omni::pgm
