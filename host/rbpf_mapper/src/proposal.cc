#include "omni/rbpf_mapper/proposal.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Cholesky>

namespace omni::rbpf {

GaussianProposal FitGaussianProposal(const Pose2& center, const ProposalGridOptions& o,
                                     const std::function<double(const Pose2&)>& log_target) {
  const int n = std::max(0, o.steps);
  std::vector<Eigen::Vector3d> offsets;
  std::vector<double> logs;
  const size_t side = static_cast<size_t>(2 * n + 1);
  offsets.reserve(side * side * side);
  logs.reserve(side * side * side);
  double mx = -std::numeric_limits<double>::infinity();
  for (int ix = -n; ix <= n; ++ix)
    for (int iy = -n; iy <= n; ++iy)
      for (int it = -n; it <= n; ++it) {
        const Eigen::Vector3d d(ix * o.step_xy_m, iy * o.step_xy_m, it * o.step_theta_rad);
        const double l =
            log_target(Pose2(center.x + d.x(), center.y + d.y(), WrapAngle(center.theta + d.z())));
        offsets.push_back(d);
        logs.push_back(l);
        if (l > mx) mx = l;
      }
  GaussianProposal g;
  g.points = static_cast<int>(offsets.size());
  const double log_volume = std::log(std::max(o.step_xy_m, 1e-12) * std::max(o.step_xy_m, 1e-12) *
                                     std::max(o.step_theta_rad, 1e-12));
  if (!std::isfinite(mx)) {
    // Nothing has any probability: stay at the centre, with no information in the weight.
    g.mean = center;
    g.log_normalizer = mx;
    return g;
  }
  double sum = 0;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (size_t k = 0; k < offsets.size(); ++k) {
    const double w = std::exp(logs[k] - mx);
    logs[k] = w;
    sum += w;
    mean += w * offsets[k];
  }
  mean /= sum;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t k = 0; k < offsets.size(); ++k) {
    const Eigen::Vector3d e = offsets[k] - mean;
    cov += logs[k] * e * e.transpose();
  }
  g.cov = cov / sum;
  g.mean = Pose2(center.x + mean.x(), center.y + mean.y(), WrapAngle(center.theta + mean.z()));
  g.log_normalizer = mx + std::log(sum) + log_volume;
  return g;
}

Pose2 DrawPose(const GaussianProposal& g, std::mt19937_64& rng) {
  std::normal_distribution<double> n01(0.0, 1.0);
  const Eigen::Vector3d z(n01(rng), n01(rng), n01(rng));
  // Cholesky factor; a tiny jitter keeps a degenerate (single-point) fit drawable.
  Eigen::Matrix3d c = g.cov;
  c.diagonal().array() += 1e-14;
  const Eigen::LLT<Eigen::Matrix3d> llt(c);
  const Eigen::Vector3d d =
      llt.info() == Eigen::Success ? Eigen::Vector3d(llt.matrixL() * z) : Eigen::Vector3d::Zero();
  return Pose2(g.mean.x + d.x(), g.mean.y + d.y(), WrapAngle(g.mean.theta + d.z()));
}

}  // namespace omni::rbpf
