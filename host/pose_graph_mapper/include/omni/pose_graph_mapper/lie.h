// SE(2) and SE(3) exponential / logarithm maps used by the manifolds and the initialisation.
// Conventions: an SE(2) pose is (x_m, y_m, theta_rad); an SE(3) pose is stored as 7 doubles
// (tx, ty, tz, qx, qy, qz, qw), Eigen's quaternion memory order. Tangent vectors are
// (v_x, v_y, omega) for SE(2) and (v_x, v_y, v_z, w_x, w_y, w_z) for SE(3).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "omni/common/geometry.h"

namespace omni::pgm {

// Exp of an se(2) tangent vector (v, omega): translation V(omega) v, rotation omega.
Pose2 ExpSE2(const Eigen::Vector3d& tangent);
// Log of an SE(2) pose; the inverse of ExpSE2 for |theta| < pi.
Eigen::Vector3d LogSE2(const Pose2& pose);

// Unit quaternion of a rotation vector (angle = norm, axis = direction).
Eigen::Quaterniond ExpSO3(const Eigen::Vector3d& rotation_vector);
// Rotation vector of a unit quaternion (angle in [0, pi]).
Eigen::Vector3d LogSO3(const Eigen::Quaterniond& q);

// The translation part of SE(3)'s exponential: Exp(v, w) = (R = Exp(w), t = V(w) v) with
//   V(w) = I + (1 - cos a)/a^2 [w]x + (a - sin a)/a^3 [w]x^2,  a = |w|  (Taylor series near 0).
// SE3V returns V(w) v; SE3VInverse returns V(w)^-1 u (for |w| < 2 pi).
Eigen::Vector3d SE3V(const Eigen::Vector3d& w, const Eigen::Vector3d& v);
Eigen::Vector3d SE3VInverse(const Eigen::Vector3d& w, const Eigen::Vector3d& u);

// Information for RelativePose2Cost (cost_functions.h) from a covariance over the measurement's own
// coordinates (x, y, theta of b in a's frame: how the odometry sources and the scan matchers
// express it). The cost's error lives in b's frame, e = T (z_hat - z) with T = diag(R_z^T, 1)
// exactly, so Omega = (T Sigma T^T)^-1 = T Sigma^-1 T^T. `floor` is added to Sigma's diagonal first
// (keeps a standstill's zero covariance invertible).
Eigen::Matrix3d RelativeInformation(const Pose2& z, const Eigen::Matrix3d& covariance,
                                    double floor);

}  // namespace omni::pgm
