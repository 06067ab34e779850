// Ceres manifolds for pose parameter blocks.
//
// SE2Manifold: ambient (x_m, y_m, theta_rad), tangent (v_x, v_y, omega);
//   Plus(x, d)  = x * Exp(d)           (right perturbation on the Lie group SE(2))
//   Minus(y, x) = Log(x^-1 * y)
//   d Plus / d d at d = 0   = [[R(theta), 0], [0, 1]]
//   d Minus / d y at y = x  = [[R(theta)^T, 0], [0, 1]]
//
// SE3Manifold: ambient (tx, ty, tz, qx, qy, qz, qw), tangent (v, w) of se(3);
//   Plus(x, d)  = x * Exp(d) = (t + R V(w) v, q * Exp(w))   (right perturbation on SE(3))
//   Minus(y, x) = Log(x^-1 * y)
//   d Plus / d d at d = 0   = [[R, 0], [0, 1/2 Q(q)]]
// The group chart (rather than R^3 x SO(3), translation in the world frame) makes a rigid
// motion of a weakly connected part of a graph a linear step: a hinge between two parts costs
// Levenberg-Marquardt far fewer iterations (parking-garage.g2o: 19 -> 7).
#pragma once

#include <ceres/manifold.h>

namespace omni::pgm {

class SE2Manifold final : public ceres::Manifold {
 public:
  int AmbientSize() const override { return 3; }
  int TangentSize() const override { return 3; }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override;
  bool PlusJacobian(const double* x, double* jacobian) const override;
  bool Minus(const double* y, const double* x, double* y_minus_x) const override;
  bool MinusJacobian(const double* x, double* jacobian) const override;
};

class SE3Manifold final : public ceres::Manifold {
 public:
  int AmbientSize() const override { return 7; }
  int TangentSize() const override { return 6; }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override;
  bool PlusJacobian(const double* x, double* jacobian) const override;
  bool Minus(const double* y, const double* x, double* y_minus_x) const override;
  bool MinusJacobian(const double* x, double* jacobian) const override;
};

}  // namespace omni::pgm
