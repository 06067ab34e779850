// Ceres cost functions of the pose graph. Every residual is r = S e with S^T S = Omega (the
// upper Cholesky factor of the information matrix), so ||r||^2 = e^T Omega e, the chi^2 term
// of the edge exactly as g2o defines it (see chi2.h, which computes the same e without Ceres).
#pragma once

#include <ceres/autodiff_cost_function.h>
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "omni/common/geometry.h"

namespace omni::pgm {

// S with S^T S = information (upper Cholesky factor). `information` must be positive definite
// (io::ReadPoseGraph checks it).
Eigen::Matrix3d SqrtInformation3(const Eigen::Matrix3d& information);
Eigen::Matrix<double, 6, 6> SqrtInformation6(const Eigen::Matrix<double, 6, 6>& information);

// Relative SE(2) factor between pose blocks a and b = (x_m, y_m, theta_rad), measurement Z = the
// pose of b in the frame of a (g2o EDGE_SE2):
//   e = t2v(Z^-1 A^-1 B):  e_xy = R_z^T (R_a^T (p_b - p_a) - p_z),  e_th = wrap(th_b - th_a - th_z)
// Analytic Jacobians:
//   de_xy/dp_a = -R_z^T R_a^T,   de_xy/dp_b = R_z^T R_a^T,
//   de_xy/dth_a = R_z^T (dR_a^T/dth) (p_b - p_a),   de_th/dth_a = -1,   de_th/dth_b = 1.
class RelativePose2Cost final : public ceres::SizedCostFunction<3, 3, 3> {
 public:
  RelativePose2Cost(const Pose2& measurement, const Eigen::Matrix3d& information);
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;
  static ceres::CostFunction* Create(const Pose2& measurement, const Eigen::Matrix3d& information) {
    return new RelativePose2Cost(measurement, information);
  }

 private:
  Eigen::Matrix2d rz_t_;  // R_z^T
  Eigen::Vector2d pz_;
  double theta_z_;
  Eigen::Matrix3d sqrt_info_;
};

// Absolute SE(2) factor (a GPS-like source, or an anchor): e = t2v(Z^-1 X):
//   e_xy = R_z^T (p - p_z),  e_th = wrap(th - th_z);  de/dX = [[R_z^T, 0], [0, 1]].
class PosePrior2Cost final : public ceres::SizedCostFunction<3, 3> {
 public:
  PosePrior2Cost(const Pose2& measurement, const Eigen::Matrix3d& information);
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;
  static ceres::CostFunction* Create(const Pose2& measurement, const Eigen::Matrix3d& information) {
    return new PosePrior2Cost(measurement, information);
  }

 private:
  Eigen::Matrix2d rz_t_;
  Eigen::Vector2d pz_;
  double theta_z_;
  Eigen::Matrix3d sqrt_info_;
};

// Relative SE(3) factor between pose blocks a and b = (tx, ty, tz, qx, qy, qz, qw), measurement Z
// = the pose of b in the frame of a (g2o EDGE_SE3:QUAT):
//   D = Z^-1 A^-1 B,  e = (t_D, vec(q_D))  with q_D taken with w >= 0 (g2o's toVectorMQT).
// Analytic Jacobians with respect to all 7 ambient parameters, exact also for quaternions that
// are not of unit length (so Ceres' GradientChecker agrees with and without the manifold):
//   t_D = R_z^T (g(q_a, p_b - p_a) - p_z),  g(q, d) = q^* d q for unit q, evaluated for any q as
//         d - 2 w (u x d) + 2 u x (u x d)  with q = (u, w);
//   q_D = q_z^* (x) q_a^* (x) q_b  (Hamilton products, linear in q_a and in q_b).
// RelativePose3Functor below is the same residual by automatic differentiation (kept as the
// reference the tests compare against).
class RelativePose3Cost final : public ceres::SizedCostFunction<6, 7, 7> {
 public:
  RelativePose3Cost(const Eigen::Isometry3d& measurement,
                    const Eigen::Matrix<double, 6, 6>& information);
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;
  static ceres::CostFunction* Create(const Eigen::Isometry3d& measurement,
                                     const Eigen::Matrix<double, 6, 6>& information) {
    return new RelativePose3Cost(measurement, information);
  }

 private:
  Eigen::Vector3d p_z_;
  Eigen::Quaterniond q_z_inv_;               // q_z^*, q_z normalised
  Eigen::Matrix<double, 6, 3> s_rz_t_;       // S.leftCols<3>() R_z^T
  Eigen::Matrix<double, 6, 3> s_rot_;        // S.rightCols<3>()
  Eigen::Matrix<double, 3, 4> l_z_inv_top_;  // top 3 rows of the left-product matrix of q_z^*

 public:
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
};

struct RelativePose3Functor {
  RelativePose3Functor(const Eigen::Isometry3d& measurement,
                       const Eigen::Matrix<double, 6, 6>& information)
      : p_z(measurement.translation()),
        q_z(measurement.linear()),
        sqrt_info(SqrtInformation6(information)) {
    q_z.normalize();
  }

  template <typename T>
  bool operator()(const T* a, const T* b, T* residuals) const {
    using Vec3 = Eigen::Matrix<T, 3, 1>;
    const Eigen::Map<const Vec3> p_a(a), p_b(b);
    const Eigen::Map<const Eigen::Quaternion<T>> q_a(a + 3), q_b(b + 3);
    const Eigen::Quaternion<T> q_a_inv = q_a.conjugate();
    const Vec3 p_ab = q_a_inv * (p_b - p_a);
    const Eigen::Quaternion<T> q_ab = q_a_inv * q_b;
    const Eigen::Quaternion<T> q_z_inv = q_z.conjugate().template cast<T>();
    Eigen::Matrix<T, 6, 1> e;
    e.template head<3>() = q_z_inv * (p_ab - p_z.template cast<T>());
    const Eigen::Quaternion<T> q_d = q_z_inv * q_ab;
    if (q_d.w() < T(0))
      e.template tail<3>() = -q_d.vec();
    else
      e.template tail<3>() = q_d.vec();
    Eigen::Map<Eigen::Matrix<T, 6, 1>> r(residuals);
    r = sqrt_info.template cast<T>() * e;
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Isometry3d& measurement,
                                     const Eigen::Matrix<double, 6, 6>& information) {
    return new ceres::AutoDiffCostFunction<RelativePose3Functor, 6, 7, 7>(
        new RelativePose3Functor(measurement, information));
  }

  Eigen::Vector3d p_z;
  Eigen::Quaterniond q_z;
  Eigen::Matrix<double, 6, 6> sqrt_info;
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
};

}  // namespace omni::pgm
