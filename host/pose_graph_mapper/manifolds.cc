#include "omni/pose_graph_mapper/manifolds.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "omni/pose_graph_mapper/lie.h"

namespace omni::pgm {

using RowMajor33 = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;

bool SE2Manifold::Plus(const double* x, const double* delta, double* out) const {
  const Pose2 p = Pose2(x[0], x[1], x[2]) * ExpSE2(Eigen::Vector3d(delta[0], delta[1], delta[2]));
  out[0] = p.x;
  out[1] = p.y;
  // Keep theta continuous with the input (no wrap): the cost functions wrap their own errors.
  out[2] = x[2] + WrapAngle(delta[2]);
  return true;
}

bool SE2Manifold::PlusJacobian(const double* x, double* jacobian) const {
  const double c = std::cos(x[2]), s = std::sin(x[2]);
  Eigen::Map<RowMajor33> j(jacobian);
  j << c, -s, 0, s, c, 0, 0, 0, 1;
  return true;
}

bool SE2Manifold::Minus(const double* y, const double* x, double* out) const {
  const Pose2 rel = Pose2(x[0], x[1], x[2]).Between(Pose2(y[0], y[1], y[2]));
  const Eigen::Vector3d d = LogSE2(rel);
  out[0] = d.x();
  out[1] = d.y();
  out[2] = d.z();
  return true;
}

bool SE2Manifold::MinusJacobian(const double* x, double* jacobian) const {
  const double c = std::cos(x[2]), s = std::sin(x[2]);
  Eigen::Map<RowMajor33> j(jacobian);
  j << c, s, 0, -s, c, 0, 0, 0, 1;
  return true;
}

namespace {
Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}
}  // namespace

bool SE3Manifold::Plus(const double* x, const double* delta, double* out) const {
  const Eigen::Map<const Eigen::Vector3d> t(x), v(delta), w(delta + 3);
  const Eigen::Quaterniond q = Eigen::Map<const Eigen::Quaterniond>(x + 3).normalized();
  Eigen::Map<Eigen::Vector3d> t_out(out);
  t_out = t + q * SE3V(w, v);
  Eigen::Map<Eigen::Quaterniond> q_out(out + 3);
  q_out = (q * ExpSO3(w)).normalized();
  return true;
}

bool SE3Manifold::PlusJacobian(const double* x, double* jacobian) const {
  // At delta = 0: d t / d v = R; d t / d w = 0 (V(w) v is second order);
  // d(q * [1, w/2]) / dw = 1/2 [[qw I + [qv]x], [-qv^T]] in (x, y, z, w) order.
  const Eigen::Quaterniond q = Eigen::Map<const Eigen::Quaterniond>(x + 3).normalized();
  const Eigen::Map<const Eigen::Quaterniond> q_raw(x + 3);
  Eigen::Map<Eigen::Matrix<double, 7, 6, Eigen::RowMajor>> j(jacobian);
  j.setZero();
  j.block<3, 3>(0, 0) = q.toRotationMatrix();
  j.block<3, 3>(3, 3) = 0.5 * (q_raw.w() * Eigen::Matrix3d::Identity() + Skew(q_raw.vec()));
  j.block<1, 3>(6, 3) = -0.5 * q_raw.vec().transpose();
  return true;
}

bool SE3Manifold::Minus(const double* y, const double* x, double* out) const {
  const Eigen::Map<const Eigen::Vector3d> tx(x), ty(y);
  const Eigen::Quaterniond qx = Eigen::Map<const Eigen::Quaterniond>(x + 3).normalized();
  const Eigen::Map<const Eigen::Quaterniond> qy(y + 3);
  const Eigen::Vector3d w = LogSO3(qx.conjugate() * qy);
  Eigen::Map<Eigen::Vector3d> v_out(out), w_out(out + 3);
  v_out = SE3VInverse(w, qx.conjugate() * (ty - tx));
  w_out = w;
  return true;
}

bool SE3Manifold::MinusJacobian(const double* x, double* jacobian) const {
  // At y = x: d v / d t_y = R^T (the translation of x^-1 y is zero there, so v does not move
  // with q_y to first order); Log(q_x^* q_y) ~ 2 vec(q_x^* q_y): d/dq_y = 2 [qw I - [qv]x, -qv].
  const Eigen::Quaterniond q = Eigen::Map<const Eigen::Quaterniond>(x + 3).normalized();
  const Eigen::Map<const Eigen::Quaterniond> q_raw(x + 3);
  Eigen::Map<Eigen::Matrix<double, 6, 7, Eigen::RowMajor>> j(jacobian);
  j.setZero();
  j.block<3, 3>(0, 0) = q.toRotationMatrix().transpose();
  j.block<3, 3>(3, 3) = 2.0 * (q_raw.w() * Eigen::Matrix3d::Identity() - Skew(q_raw.vec()));
  j.block<3, 1>(3, 6) = -2.0 * q_raw.vec();
  return true;
}

}  // namespace omni::pgm
