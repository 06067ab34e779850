// The improved proposal of Grisetti, Stachniss, Burgard (IEEE T-RO 2007, sec. IV): around the
// scan-match optimum x*, the target p(z | m, x) p(x | x', u) is evaluated at K points x_k, a
// Gaussian is fitted to it (weighted mean and covariance of the x_k), the particle's new pose is
// drawn from that Gaussian, and its weight is multiplied by the normaliser
// eta = sum_k p(z | m, x_k) p(x_k | x', u) (times the volume each point stands for, so that eta
// approximates the integral and is comparable with the weight of a particle whose match failed
// and was drawn from the motion model alone).
#pragma once

#include <functional>
#include <random>

#include <Eigen/Core>

#include "omni/common/geometry.h"

namespace omni::rbpf {

// The K points: a (2 steps + 1)^3 grid centred on the optimum.
struct ProposalGridOptions {
  int steps = 1;                  // points per side on each axis
  double step_xy_m = 0.01;        // spacing in x and y
  double step_theta_rad = 0.005;  // spacing in heading
};

struct GaussianProposal {
  Pose2 mean;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();  // x, y, theta
  double log_normalizer = 0;  // log(sum_k exp(log_target(x_k)) * step_xy^2 * step_theta)
  int points = 0;
};

// Evaluates `log_target` on the grid around `center` and fits the Gaussian. The heading offsets
// are taken relative to `center` (no wrap-around inside the grid).
GaussianProposal FitGaussianProposal(const Pose2& center, const ProposalGridOptions& options,
                                     const std::function<double(const Pose2&)>& log_target);

// One pose drawn from the Gaussian (heading wrapped).
Pose2 DrawPose(const GaussianProposal& g, std::mt19937_64& rng);

}  // namespace omni::rbpf
