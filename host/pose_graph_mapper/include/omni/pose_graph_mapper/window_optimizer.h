// Sliding-window optimisation of a 2D pose graph with Ceres: the last N poses are optimised on
// every update; older poses are marginalised into a Gaussian prior on the window (not frozen).
//
// Marginalising pose m: every factor touching m (and the current prior) is linearised at the
// current estimates, in the ambient coordinates (x, y, theta); with H = J^T J and g = J^T r over
// m and its neighbours K, the Schur complement
//   H_p = H_KK - H_Km H_mm^-1 H_mK,   g_p = g_K - H_Km H_mm^-1 g_m
// becomes the new prior  1/2 |S d + r0|^2  with d = x_K - x0_K (angles wrapped), S = L^T,
// r0 = L^-1 g_p, H_p = L L^T. For a linear problem this is exact: the window's solution equals
// the full graph's.
#pragma once

#include <array>
#include <deque>
#include <map>
#include <optional>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "omni/common/geometry.h"
#include "omni/common/result.h"

namespace omni::pgm {

struct WindowOptions {
  int window_size = 50;  // poses optimised on every update (N)
  int max_iterations = 10;
  double function_tolerance = 1e-8;
  double gradient_tolerance = 1e-10;
  double parameter_tolerance = 1e-10;
  int num_threads = 1;
  Status Validate() const;
};

struct WindowUpdate {
  int iterations = 0;
  int marginalized = 0;  // poses marginalised in this update
  double cost = 0;       // Ceres' final cost (1/2 sum of squared residuals, prior included)
};

class SlidingWindowOptimizer {
 public:
  explicit SlidingWindowOptimizer(const WindowOptions& options) : options_(options) {}

  // Poses are added in time order with an initial estimate; ids must be new.
  Status AddPose(int id, const Pose2& initial);
  // Relative factor (z = pose `to` in the frame of `from`); both poses must still be in the
  // window (older poses are marginalised: a loop closure to them needs a global optimisation).
  Status AddRelative(int from, int to, const Pose2& z, const Eigen::Matrix3d& information);
  // Absolute factor (GPS-like) on a window pose.
  Status AddAbsolute(int id, const Pose2& z, const Eigen::Matrix3d& information);
  // Removes the first relative factor from -> to whose measurement equals z exactly (pose
  // splicing replaces a continuous-source factor by two); false when there is none, e.g.
  // because it was folded into the marginal prior.
  bool RemoveRelative(int from, int to, const Pose2& z);
  // True while the pose is optimised (added and not marginalised).
  bool InWindow(int id) const { return x_.count(id) > 0; }

  // Marginalises poses beyond the window size (oldest first), then optimises the window.
  Result<WindowUpdate> Update();

  // Current estimate (window poses) or the estimate at marginalisation (older poses).
  std::optional<Pose2> Estimate(int id) const;
  // Marginal covariance over (x, y, theta) of a window pose: the inverse of the window's
  // information (its factors and the marginal prior, linearised at the current estimates),
  // block `id`. With the gauge held by an absolute factor (the mapper anchors its first pose),
  // this is the fixed-lag smoother's covariance in the map frame: the marginalised poses count
  // through the prior, so it equals the full graph's covariance on a linear problem. nullopt
  // for a pose outside the window or an information matrix that is not positive definite.
  std::optional<Eigen::Matrix3d> Covariance(int id) const;
  std::vector<int> WindowIds() const { return {window_.begin(), window_.end()}; }
  size_t prior_size() const { return prior_ids_.size(); }

 private:
  struct Factor {
    int a = 0, b = -1;  // b == -1: absolute factor on a
    Pose2 z;
    Eigen::Matrix3d information;
  };
  Status MarginalizeOldest();
  // Adds a factor's / the marginal prior's J^T J and J^T r to (h, g), at the current estimates;
  // `index` maps a pose id to its block.
  template <typename Index>
  void Linearize(const Factor& f, Index&& index, Eigen::MatrixXd* h, Eigen::VectorXd* g) const;
  template <typename Index>
  void LinearizePrior(Index&& index, Eigen::MatrixXd* h, Eigen::VectorXd* g) const;

  WindowOptions options_;
  std::deque<int> window_;
  std::unordered_map<int, std::array<double, 3>> x_;  // window estimates (x, y, theta)
  std::map<int, Pose2> marginalized_;
  std::vector<Factor> factors_;
  std::vector<int> prior_ids_;
  Eigen::VectorXd prior_x0_, prior_r0_;
  Eigen::MatrixXd prior_s_;
};

}  // namespace omni::pgm
