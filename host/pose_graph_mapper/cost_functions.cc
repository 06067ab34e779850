#include "omni/pose_graph_mapper/cost_functions.h"

#include <cmath>

#include <Eigen/Cholesky>

namespace omni::pgm {
namespace {
Eigen::Matrix2d Rot(double th) {
  const double c = std::cos(th), s = std::sin(th);
  Eigen::Matrix2d r;
  r << c, -s, s, c;
  return r;
}
}  // namespace

Eigen::Matrix3d SqrtInformation3(const Eigen::Matrix3d& information) {
  Eigen::LLT<Eigen::Matrix3d> llt(0.5 * (information + information.transpose()));
  return llt.matrixU();
}

Eigen::Matrix<double, 6, 6> SqrtInformation6(const Eigen::Matrix<double, 6, 6>& information) {
  Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(0.5 * (information + information.transpose()));
  return llt.matrixU();
}

RelativePose2Cost::RelativePose2Cost(const Pose2& z, const Eigen::Matrix3d& information)
    : rz_t_(Rot(z.theta).transpose()),
      pz_(z.x, z.y),
      theta_z_(z.theta),
      sqrt_info_(SqrtInformation3(information)) {}

bool RelativePose2Cost::Evaluate(double const* const* parameters, double* residuals,
                                 double** jacobians) const {
  const double* a = parameters[0];
  const double* b = parameters[1];
  const double c = std::cos(a[2]), s = std::sin(a[2]);
  Eigen::Matrix2d ra_t;
  ra_t << c, s, -s, c;
  const Eigen::Vector2d dp(b[0] - a[0], b[1] - a[1]);
  Eigen::Vector3d e;
  e.head<2>() = rz_t_ * (ra_t * dp - pz_);
  e.z() = WrapAngle(b[2] - a[2] - theta_z_);
  Eigen::Map<Eigen::Vector3d> r(residuals);
  r = sqrt_info_ * e;
  if (jacobians == nullptr) return true;
  const Eigen::Matrix2d m = rz_t_ * ra_t;
  if (jacobians[0] != nullptr) {
    Eigen::Matrix2d dra_t;  // d R_a^T / d theta_a
    dra_t << -s, c, -c, -s;
    Eigen::Matrix3d j = Eigen::Matrix3d::Zero();
    j.block<2, 2>(0, 0) = -m;
    j.block<2, 1>(0, 2) = rz_t_ * dra_t * dp;
    j(2, 2) = -1.0;
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> jac(jacobians[0]);
    jac = sqrt_info_ * j;
  }
  if (jacobians[1] != nullptr) {
    Eigen::Matrix3d j = Eigen::Matrix3d::Zero();
    j.block<2, 2>(0, 0) = m;
    j(2, 2) = 1.0;
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> jac(jacobians[1]);
    jac = sqrt_info_ * j;
  }
  return true;
}

PosePrior2Cost::PosePrior2Cost(const Pose2& z, const Eigen::Matrix3d& information)
    : rz_t_(Rot(z.theta).transpose()),
      pz_(z.x, z.y),
      theta_z_(z.theta),
      sqrt_info_(SqrtInformation3(information)) {}

bool PosePrior2Cost::Evaluate(double const* const* parameters, double* residuals,
                              double** jacobians) const {
  const double* x = parameters[0];
  Eigen::Vector3d e;
  e.head<2>() = rz_t_ * (Eigen::Vector2d(x[0], x[1]) - pz_);
  e.z() = WrapAngle(x[2] - theta_z_);
  Eigen::Map<Eigen::Vector3d> r(residuals);
  r = sqrt_info_ * e;
  if (jacobians != nullptr && jacobians[0] != nullptr) {
    Eigen::Matrix3d j = Eigen::Matrix3d::Zero();
    j.block<2, 2>(0, 0) = rz_t_;
    j(2, 2) = 1.0;
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> jac(jacobians[0]);
    jac = sqrt_info_ * j;
  }
  return true;
}

namespace {

Eigen::Matrix3d Skew3(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

// Top three rows (the vector part) of L(p), p (x) q = L(p) q, in (x, y, z, w) order.
Eigen::Matrix<double, 3, 4> LeftProductTop(const Eigen::Quaterniond& p) {
  Eigen::Matrix<double, 3, 4> m;
  m.leftCols<3>() = p.w() * Eigen::Matrix3d::Identity() + Skew3(p.vec());
  m.col(3) = p.vec();
  return m;
}

// R(q) with p (x) q = R(q) p, in (x, y, z, w) order.
Eigen::Matrix4d RightProduct(const Eigen::Quaterniond& q) {
  Eigen::Matrix4d m;
  m.topLeftCorner<3, 3>() = q.w() * Eigen::Matrix3d::Identity() - Skew3(q.vec());
  m.topRightCorner<3, 1>() = q.vec();
  m.bottomLeftCorner<1, 3>() = -q.vec().transpose();
  m(3, 3) = q.w();
  return m;
}

}  // namespace

RelativePose3Cost::RelativePose3Cost(const Eigen::Isometry3d& measurement,
                                     const Eigen::Matrix<double, 6, 6>& information)
    : p_z_(measurement.translation()) {
  const Eigen::Quaterniond q_z = Eigen::Quaterniond(measurement.linear()).normalized();
  q_z_inv_ = q_z.conjugate();
  const Eigen::Matrix<double, 6, 6> s = SqrtInformation6(information);
  s_rz_t_ = s.leftCols<3>() * q_z.toRotationMatrix().transpose();
  s_rot_ = s.rightCols<3>();
  l_z_inv_top_ = LeftProductTop(q_z_inv_);
}

bool RelativePose3Cost::Evaluate(double const* const* parameters, double* residuals,
                                 double** jacobians) const {
  const Eigen::Map<const Eigen::Vector3d> p_a(parameters[0]), p_b(parameters[1]);
  const Eigen::Map<const Eigen::Quaterniond> q_a(parameters[0] + 3), q_b(parameters[1] + 3);
  const Eigen::Vector3d d = p_b - p_a;
  const Eigen::Vector3d u = q_a.vec();
  const double w = q_a.w();
  // g = q_a^* d q_a written for any q_a (as Eigen's quaternion-vector product evaluates it).
  const Eigen::Vector3d uxd = u.cross(d);
  const Eigen::Vector3d g = d - 2.0 * w * uxd + 2.0 * u.cross(uxd);
  const Eigen::Quaterniond c = q_z_inv_ * q_a.conjugate();
  const Eigen::Quaterniond q_d = c * q_b;
  const double sign = q_d.w() < 0 ? -1.0 : 1.0;
  Eigen::Map<Eigen::Matrix<double, 6, 1>> r(residuals);
  r = s_rz_t_ * (g - p_z_) + sign * (s_rot_ * q_d.vec());
  if (jacobians == nullptr) return true;
  using Jac = Eigen::Map<Eigen::Matrix<double, 6, 7, Eigen::RowMajor>>;
  const Eigen::Matrix<double, 6, 3> s_rot_signed = sign * s_rot_;
  if (jacobians[0] != nullptr || jacobians[1] != nullptr) {
    // dg/dd = I - 2 w [u]x + 2 (u u^T - |u|^2 I).
    const Eigen::Matrix3d dg_dd = (1.0 - 2.0 * u.squaredNorm()) * Eigen::Matrix3d::Identity() -
                                  2.0 * w * Skew3(u) + 2.0 * u * u.transpose();
    const Eigen::Matrix<double, 6, 3> j_d = s_rz_t_ * dg_dd;
    if (jacobians[0] != nullptr) {
      Jac j(jacobians[0]);
      j.leftCols<3>() = -j_d;
      // dg/du = 2 w [d]x + 2 (u.d) I + 2 u d^T - 4 d u^T;  dg/dw = -2 u x d.
      Eigen::Matrix<double, 3, 4> dg_dq;
      dg_dq.leftCols<3>() = 2.0 * w * Skew3(d) + 2.0 * u.dot(d) * Eigen::Matrix3d::Identity() +
                            2.0 * u * d.transpose() - 4.0 * d * u.transpose();
      dg_dq.col(3) = -2.0 * uxd;
      // q_d = q_z^* (x) (q_a^* (x) q_b) = L(q_z^*) R(q_b) diag(-1, -1, -1, 1) q_a.
      Eigen::Matrix<double, 3, 4> dqd_dqa = l_z_inv_top_ * RightProduct(q_b);
      dqd_dqa.leftCols<3>() = -dqd_dqa.leftCols<3>();
      j.rightCols<4>() = s_rz_t_ * dg_dq + s_rot_signed * dqd_dqa;
    }
    if (jacobians[1] != nullptr) {
      Jac j(jacobians[1]);
      j.leftCols<3>() = j_d;
      j.rightCols<4>() = s_rot_signed * LeftProductTop(c);
    }
  }
  return true;
}

}  // namespace omni::pgm
