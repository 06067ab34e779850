#include "omni/pose_graph_mapper/window_optimizer.h"

#include <ceres/ceres.h>

#include <algorithm>
#include <memory>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "omni/pose_graph_mapper/cost_functions.h"
#include "omni/pose_graph_mapper/manifolds.h"

namespace omni::pgm {
namespace {

// 1/2 |S d + r0|^2 over k pose blocks, d = x - x0 with angles wrapped. dr/dx_i = S(:, 3i..3i+2).
class MarginalPriorCost final : public ceres::CostFunction {
 public:
  MarginalPriorCost(Eigen::MatrixXd s, Eigen::VectorXd x0, Eigen::VectorXd r0)
      : s_(std::move(s)), x0_(std::move(x0)), r0_(std::move(r0)) {
    set_num_residuals(static_cast<int>(r0_.size()));
    for (int i = 0; i < r0_.size() / 3; ++i) mutable_parameter_block_sizes()->push_back(3);
  }
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const int n = static_cast<int>(r0_.size());
    Eigen::VectorXd d(n);
    for (int i = 0; i < n / 3; ++i) {
      d[3 * i] = parameters[i][0] - x0_[3 * i];
      d[3 * i + 1] = parameters[i][1] - x0_[3 * i + 1];
      d[3 * i + 2] = WrapAngle(parameters[i][2] - x0_[3 * i + 2]);
    }
    Eigen::Map<Eigen::VectorXd> r(residuals, n);
    r = s_ * d + r0_;
    if (jacobians == nullptr) return true;
    for (int i = 0; i < n / 3; ++i) {
      if (jacobians[i] == nullptr) continue;
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>> j(jacobians[i], n, 3);
      j = s_.middleCols(3 * i, 3);
    }
    return true;
  }

 private:
  Eigen::MatrixXd s_;
  Eigen::VectorXd x0_, r0_;
};

}  // namespace

Status WindowOptions::Validate() const {
  if (window_size < 2) return MakeError(ErrorCode::kOutOfRange, "window_size must be >= 2");
  if (max_iterations < 1) return MakeError(ErrorCode::kOutOfRange, "max_iterations must be >= 1");
  if (num_threads < 1) return MakeError(ErrorCode::kOutOfRange, "num_threads must be >= 1");
  return Status::Ok();
}

Status SlidingWindowOptimizer::AddPose(int id, const Pose2& p) {
  if (x_.count(id) || marginalized_.count(id))
    return MakeError(ErrorCode::kInvalidArgument, "pose " + std::to_string(id) + " exists");
  window_.push_back(id);
  x_[id] = {p.x, p.y, p.theta};
  return Status::Ok();
}

Status SlidingWindowOptimizer::AddRelative(int from, int to, const Pose2& z,
                                           const Eigen::Matrix3d& info) {
  for (int id : {from, to})
    if (!x_.count(id))
      return MakeError(ErrorCode::kInvalidArgument,
                       "pose " + std::to_string(id) +
                           (marginalized_.count(id) ? " has left the window" : " does not exist"));
  factors_.push_back({from, to, z, info});
  return Status::Ok();
}

Status SlidingWindowOptimizer::AddAbsolute(int id, const Pose2& z, const Eigen::Matrix3d& info) {
  if (!x_.count(id))
    return MakeError(ErrorCode::kInvalidArgument,
                     "pose " + std::to_string(id) + " is not in the window");
  factors_.push_back({id, -1, z, info});
  return Status::Ok();
}

bool SlidingWindowOptimizer::RemoveRelative(int from, int to, const Pose2& z) {
  for (auto it = factors_.begin(); it != factors_.end(); ++it)
    if (it->a == from && it->b == to && it->z.x == z.x && it->z.y == z.y &&
        it->z.theta == z.theta) {
      factors_.erase(it);
      return true;
    }
  return false;
}

std::optional<Pose2> SlidingWindowOptimizer::Estimate(int id) const {
  if (auto it = x_.find(id); it != x_.end())
    return Pose2(it->second[0], it->second[1], WrapAngle(it->second[2]));
  if (auto it = marginalized_.find(id); it != marginalized_.end()) return it->second;
  return std::nullopt;
}

namespace {

void Accumulate(const Eigen::VectorXd& r, const std::vector<int>& blocks,
                const std::vector<Eigen::MatrixXd>& jac, Eigen::MatrixXd* h, Eigen::VectorXd* g) {
  for (size_t i = 0; i < blocks.size(); ++i) {
    g->segment(3 * blocks[i], 3) += jac[i].transpose() * r;
    for (size_t j = 0; j < blocks.size(); ++j)
      h->block(3 * blocks[i], 3 * blocks[j], 3, 3) += jac[i].transpose() * jac[j];
  }
}

}  // namespace

template <typename Index>
void SlidingWindowOptimizer::Linearize(const Factor& f, Index&& index, Eigen::MatrixXd* h,
                                       Eigen::VectorXd* g) const {
  Eigen::Vector3d r;
  Eigen::Matrix<double, 3, 3, Eigen::RowMajor> ja, jb;
  double* jacs[2] = {ja.data(), jb.data()};
  if (f.b >= 0) {
    RelativePose2Cost cost(f.z, f.information);
    const double* params[2] = {x_.at(f.a).data(), x_.at(f.b).data()};
    cost.Evaluate(params, r.data(), jacs);
    Accumulate(r, {index(f.a), index(f.b)}, {Eigen::MatrixXd(ja), Eigen::MatrixXd(jb)}, h, g);
  } else {
    PosePrior2Cost cost(f.z, f.information);
    const double* params[1] = {x_.at(f.a).data()};
    cost.Evaluate(params, r.data(), jacs);
    Accumulate(r, {index(f.a)}, {Eigen::MatrixXd(ja)}, h, g);
  }
}

template <typename Index>
void SlidingWindowOptimizer::LinearizePrior(Index&& index, Eigen::MatrixXd* h,
                                            Eigen::VectorXd* g) const {
  if (prior_ids_.empty()) return;
  const int pn = static_cast<int>(prior_r0_.size());
  Eigen::VectorXd d(pn);
  std::vector<int> blocks;
  std::vector<Eigen::MatrixXd> jac;
  for (size_t i = 0; i < prior_ids_.size(); ++i) {
    const auto& x = x_.at(prior_ids_[i]);
    d[3 * i] = x[0] - prior_x0_[3 * i];
    d[3 * i + 1] = x[1] - prior_x0_[3 * i + 1];
    d[3 * i + 2] = WrapAngle(x[2] - prior_x0_[3 * i + 2]);
    blocks.push_back(index(prior_ids_[i]));
    jac.push_back(prior_s_.middleCols(3 * i, 3));
  }
  Accumulate(prior_s_ * d + prior_r0_, blocks, jac, h, g);
}

std::optional<Eigen::Matrix3d> SlidingWindowOptimizer::Covariance(int id) const {
  if (!x_.count(id)) return std::nullopt;
  std::unordered_map<int, int> block;
  for (int w : window_) block.emplace(w, static_cast<int>(block.size()));
  const int n = 3 * static_cast<int>(block.size());
  Eigen::MatrixXd h = Eigen::MatrixXd::Zero(n, n);
  Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
  auto index = [&](int pose) { return block.at(pose); };
  for (const auto& f : factors_) Linearize(f, index, &h, &g);
  LinearizePrior(index, &h, &g);
  const Eigen::LLT<Eigen::MatrixXd> llt(0.5 * (h + h.transpose()));
  if (llt.info() != Eigen::Success) return std::nullopt;
  Eigen::MatrixXd e = Eigen::MatrixXd::Zero(n, 3);
  e.middleRows(3 * block.at(id), 3).setIdentity();
  const Eigen::Matrix3d cov = llt.solve(e).middleRows(3 * block.at(id), 3);
  if (!cov.allFinite()) return std::nullopt;
  return 0.5 * (cov + cov.transpose());
}

Status SlidingWindowOptimizer::MarginalizeOldest() {
  const int m = window_.front();
  // Variables: m first, then every other pose of the factors touching m and of the prior.
  std::vector<int> vars{m};
  auto index = [&](int id) {
    auto it = std::find(vars.begin(), vars.end(), id);
    if (it != vars.end()) return static_cast<int>(it - vars.begin());
    vars.push_back(id);
    return static_cast<int>(vars.size()) - 1;
  };
  std::vector<size_t> touching;
  for (size_t k = 0; k < factors_.size(); ++k)
    if (factors_[k].a == m || factors_[k].b == m) {
      touching.push_back(k);
      index(factors_[k].a);
      if (factors_[k].b >= 0) index(factors_[k].b);
    }
  for (int id : prior_ids_) index(id);
  const int n = 3 * static_cast<int>(vars.size());
  Eigen::MatrixXd h = Eigen::MatrixXd::Zero(n, n);
  Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
  for (size_t k : touching) Linearize(factors_[k], index, &h, &g);
  LinearizePrior(index, &h, &g);
  // Schur complement onto the other variables.
  const int nk = n - 3;
  if (nk > 0) {
    const Eigen::Matrix3d hmm = h.topLeftCorner(3, 3);
    Eigen::LDLT<Eigen::Matrix3d> hmm_ldlt(hmm);
    const Eigen::MatrixXd hkm = h.bottomLeftCorner(nk, 3);
    const Eigen::MatrixXd hp = h.bottomRightCorner(nk, nk) - hkm * hmm_ldlt.solve(hkm.transpose());
    const Eigen::VectorXd gp = g.tail(nk) - hkm * hmm_ldlt.solve(g.head(3));
    Eigen::LLT<Eigen::MatrixXd> llt(0.5 * (hp + hp.transpose()) +
                                    1e-12 * Eigen::MatrixXd::Identity(nk, nk));
    if (llt.info() != Eigen::Success)
      return MakeError(ErrorCode::kInternal, "marginal prior is not positive definite");
    // Only now: a failed marginalisation leaves the old prior and its ids consistent.
    prior_ids_.assign(vars.begin() + 1, vars.end());
    prior_s_ = llt.matrixU();
    prior_r0_ = llt.matrixL().solve(gp);
    prior_x0_.resize(nk);
    for (size_t i = 0; i < prior_ids_.size(); ++i) {
      const auto& x = x_.at(prior_ids_[i]);
      prior_x0_.segment(3 * i, 3) << x[0], x[1], x[2];
    }
  } else {
    prior_ids_.clear();
    prior_s_.resize(0, 0);
    prior_r0_.resize(0);
    prior_x0_.resize(0);
  }
  // Drop m and its factors.
  std::vector<Factor> kept;
  kept.reserve(factors_.size());
  for (const auto& f : factors_)
    if (f.a != m && f.b != m) kept.push_back(f);
  factors_.swap(kept);
  const auto& xm = x_.at(m);
  marginalized_[m] = Pose2(xm[0], xm[1], WrapAngle(xm[2]));
  x_.erase(m);
  window_.pop_front();
  return Status::Ok();
}

Result<WindowUpdate> SlidingWindowOptimizer::Update() {
  if (Status s = options_.Validate(); !s.ok()) return s.error();
  WindowUpdate u;
  while (static_cast<int>(window_.size()) > options_.window_size) {
    if (Status s = MarginalizeOldest(); !s.ok()) return s.error();
    ++u.marginalized;
  }
  if (window_.empty()) return u;
  ceres::Problem::Options popt;
  popt.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(popt);
  SE2Manifold se2;
  bool anchored = !prior_ids_.empty();
  for (int id : window_) problem.AddParameterBlock(x_.at(id).data(), 3, &se2);
  for (const auto& f : factors_) {
    if (f.b >= 0) {
      problem.AddResidualBlock(RelativePose2Cost::Create(f.z, f.information), nullptr,
                               x_.at(f.a).data(), x_.at(f.b).data());
    } else {
      problem.AddResidualBlock(PosePrior2Cost::Create(f.z, f.information), nullptr,
                               x_.at(f.a).data());
      anchored = true;
    }
  }
  if (!prior_ids_.empty()) {
    std::vector<double*> blocks;
    for (int id : prior_ids_) blocks.push_back(x_.at(id).data());
    problem.AddResidualBlock(new MarginalPriorCost(prior_s_, prior_x0_, prior_r0_), nullptr,
                             blocks);
  }
  if (!anchored) problem.SetParameterBlockConstant(x_.at(window_.front()).data());
  if (problem.NumResidualBlocks() == 0) return u;
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  so.max_num_iterations = options_.max_iterations;
  so.function_tolerance = options_.function_tolerance;
  so.gradient_tolerance = options_.gradient_tolerance;
  so.parameter_tolerance = options_.parameter_tolerance;
  so.num_threads = options_.num_threads;
  so.initial_trust_region_radius = 1e8;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  if (summary.termination_type == ceres::FAILURE)
    return MakeError(ErrorCode::kInternal, "ceres failed: " + summary.message);
  u.iterations = static_cast<int>(summary.iterations.size()) - 1;
  u.cost = summary.final_cost;
  return u;
}

}  // namespace omni::pgm
