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

}  // namespace omni::pgm
