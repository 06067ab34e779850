// Ceres manifolds for pose parameter blocks.
//
// SE2Manifold: ambient (x_m, y_m, theta_rad), tangent (v_x, v_y, omega);
//   Plus(x, d)  = x * Exp(d)           (right perturbation on the Lie group SE(2))
//   Minus(y, x) = Log(x^-1 * y)
//   d Plus / d d at d = 0   = [[R(theta), 0], [0, 1]]
//   d Minus / d y at y = x  = [[R(theta)^T, 0], [0, 1]]
//
// SE3Manifold: ambient (tx, ty, tz, qx, qy, qz, qw), tangent (dt, dw);
//   Plus(x, d)  = (t + dt, q * Exp(dw))   (R^3 x SO(3), rotation perturbed on the right)
//   Minus(y, x) = (t_y - t_x, Log(q_x^* q_y))
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
