#include "omni/pose_graph_mapper/batch_optimizer.h"

#include <ceres/ceres.h>

#include <chrono>
#include <memory>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "omni/pose_graph_mapper/chi2.h"
#include "omni/pose_graph_mapper/cost_functions.h"
#include "omni/pose_graph_mapper/manifolds.h"
#include "omni/pose_graph_mapper/pose_graph_slam.h"

namespace omni::pgm {
namespace {

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

ceres::LossFunction* MakeLoss(const BatchOptions& o) {
  if (o.loss == "huber") return new ceres::HuberLoss(o.loss_scale);
  if (o.loss == "cauchy") return new ceres::CauchyLoss(o.loss_scale);
  return nullptr;
}

}  // namespace

Result<BatchOptions> BatchOptions::Load(ConfigReader& r) {
  BatchOptions o;
  std::string init = InitializationName(o.initialization);
  r.Get("initialization", &init, Optional(), OneOf({"none", "spanning-tree", "chordal"}));
  if (auto p = ParseInitialization(init); p.ok()) o.initialization = *p;
  r.Get("max_iterations", &o.max_iterations, Optional(), InRange(1, 100000));
  r.Get("function_tolerance", &o.function_tolerance, Optional(), InRange(0.0, 1.0));
  r.Get("gradient_tolerance", &o.gradient_tolerance, Optional(), InRange(0.0, 1.0));
  r.Get("parameter_tolerance", &o.parameter_tolerance, Optional(), InRange(0.0, 1.0));
  r.Get("initial_trust_region_radius", &o.initial_trust_region_radius, Optional(),
        Positive<double>());
  r.Get("sparse_library", &o.sparse_library, Optional(), OneOf({"suitesparse", "eigen"}));
  r.Get("loss", &o.loss, Optional(), OneOf({"none", "huber", "cauchy"}));
  r.Get("loss_scale", &o.loss_scale, Optional(), Positive<double>());
  return o;
}

Result<BatchOptions> LoadBatchOptionsFile(const std::string& path) {
  auto r = ConfigReader::FromFile(path);
  if (!r.ok()) return r.error();
  ConfigReader batch = r->Section("batch");
  auto o = BatchOptions::Load(batch);
  // The online mapper's `slam` and `node` sections share the file: their keys are checked, not
  // ignored.
  ConfigReader slam = r->Section("slam");
  (void)PoseGraphSlamOptions::Load(slam);
  ConfigReader node = r->Section("node");
  (void)PoseGraphNodeOptions::Load(node);
  if (Status s = r->Finish(); !s.ok()) return s.error();
  return o;
}

Status BatchOptions::Validate() const {
  if (max_iterations < 1) return MakeError(ErrorCode::kOutOfRange, "max_iterations must be >= 1");
  if (loss != "none" && loss != "huber" && loss != "cauchy")
    return MakeError(ErrorCode::kOutOfRange,
                     "loss '" + loss + "' must be one of: none huber cauchy");
  if (sparse_library != "suitesparse" && sparse_library != "eigen")
    return MakeError(ErrorCode::kOutOfRange,
                     "sparse_library '" + sparse_library + "' must be suitesparse or eigen");
  if (!(loss_scale > 0)) return MakeError(ErrorCode::kOutOfRange, "loss_scale must be > 0");
  if (num_threads < 1) return MakeError(ErrorCode::kOutOfRange, "num_threads must be >= 1");
  if (!(initial_trust_region_radius > 0))
    return MakeError(ErrorCode::kOutOfRange, "initial_trust_region_radius must be > 0");
  if (!(function_tolerance >= 0) || !(gradient_tolerance >= 0) || !(parameter_tolerance >= 0))
    return MakeError(ErrorCode::kOutOfRange, "tolerances must be >= 0");
  return Status::Ok();
}

Result<BatchResult> OptimizeGraph(io::PoseGraph* g, const BatchOptions& o,
                                  const std::vector<VertexPrior2>* priors) {
  if (Status s = o.Validate(); !s.ok()) return s.error();
  const bool is3d = g->is_3d();
  if ((is3d ? g->vertices3.size() : g->vertices2.size()) == 0)
    return MakeError(ErrorCode::kInvalidArgument, "the graph has no vertices");
  BatchResult res;
  auto chi2 = ComputeChi2(*g);
  if (!chi2.ok()) return chi2.error();
  res.chi2_input = *chi2;
  res.root_id = ChooseRoot(*g);

  const auto t_init = std::chrono::steady_clock::now();
  Initialization init = o.initialization;
  if (g->vertices_implicit && init == Initialization::kNone) init = Initialization::kSpanningTree;
  // Every FIX vertex stays where the file puts it: the initialisation places the graph from the
  // root (the first of them), so the others get their poses back before the solve holds them.
  const std::unordered_set<int> fixed_ids(g->fixed.begin(), g->fixed.end());
  std::unordered_map<int, Pose2> fixed2;
  std::unordered_map<int, Eigen::Isometry3d> fixed3;
  for (const auto& v : g->vertices2)
    if (fixed_ids.count(v.id)) fixed2[v.id] = v.pose;
  for (const auto& v : g->vertices3)
    if (fixed_ids.count(v.id)) fixed3[v.id] = v.pose;
  if (Status s = Initialize(g, init, res.root_id); !s.ok()) return s.error();
  for (auto& v : g->vertices2)
    if (const auto it = fixed2.find(v.id); it != fixed2.end()) v.pose = it->second;
  for (auto& v : g->vertices3)
    if (const auto it = fixed3.find(v.id); it != fixed3.end()) v.pose = it->second;
  res.init_s = SecondsSince(t_init);
  chi2 = ComputeChi2(*g);
  if (!chi2.ok()) return chi2.error();
  res.chi2_initialized = *chi2;

  const auto t_solve = std::chrono::steady_clock::now();
  ceres::Problem::Options popt;
  popt.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(popt);
  SE2Manifold se2;
  SE3Manifold se3;
  std::unordered_map<int, double*> block;
  std::vector<double> params;
  const int dim = is3d ? 7 : 3;
  const size_t n = is3d ? g->vertices3.size() : g->vertices2.size();
  params.resize(n * dim);
  for (size_t i = 0; i < n; ++i) {
    double* p = &params[i * dim];
    if (is3d) {
      const auto& v = g->vertices3[i];
      const Eigen::Quaterniond q(v.pose.linear());
      const Eigen::Vector3d t = v.pose.translation();
      p[0] = t.x(), p[1] = t.y(), p[2] = t.z();
      p[3] = q.x(), p[4] = q.y(), p[5] = q.z(), p[6] = q.w();
      block[v.id] = p;
    } else {
      const auto& v = g->vertices2[i];
      p[0] = v.pose.x, p[1] = v.pose.y, p[2] = v.pose.theta;
      block[v.id] = p;
    }
  }
  if (is3d) {
    for (const auto& e : g->edges3) {
      if (e.from == e.to) continue;
      problem.AddResidualBlock(RelativePose3Cost::Create(e.measurement, e.information), MakeLoss(o),
                               block.at(e.from), block.at(e.to));
    }
  } else {
    for (size_t i = 0; i < g->edges2.size(); ++i) {
      const auto& e = g->edges2[i];
      if (e.from == e.to) continue;
      problem.AddResidualBlock(RelativePose2Cost::Create(e.measurement, e.information),
                               i < o.first_plain_edge2 ? MakeLoss(o) : nullptr, block.at(e.from),
                               block.at(e.to));
    }
    if (priors)
      for (const auto& pr : *priors) {
        auto it = block.find(pr.id);
        if (it == block.end())
          return MakeError(ErrorCode::kInvalidArgument,
                           "prior on vertex " + std::to_string(pr.id) + " which does not exist");
        problem.AddResidualBlock(PosePrior2Cost::Create(pr.z, pr.information), MakeLoss(o),
                                 it->second);
      }
  }
  for (auto& [id, p] : block) {
    if (!problem.HasParameterBlock(p)) continue;  // a vertex without edges stays as it is
    problem.SetManifold(p, is3d ? static_cast<ceres::Manifold*>(&se3) : &se2);
  }
  if (problem.HasParameterBlock(block.at(res.root_id)))
    problem.SetParameterBlockConstant(block.at(res.root_id));
  for (int id : g->fixed) {
    const auto it = block.find(id);
    if (it != block.end() && problem.HasParameterBlock(it->second))
      problem.SetParameterBlockConstant(it->second);
  }

  ceres::Solver::Options so;
  so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  so.sparse_linear_algebra_library_type =
      o.sparse_library == "eigen" ? ceres::EIGEN_SPARSE : ceres::SUITE_SPARSE;
  so.max_num_iterations = o.max_iterations;
  if (o.max_time_s > 0) so.max_solver_time_in_seconds = o.max_time_s;
  so.function_tolerance = o.function_tolerance;
  so.gradient_tolerance = o.gradient_tolerance;
  so.parameter_tolerance = o.parameter_tolerance;
  so.num_threads = o.num_threads;
  so.initial_trust_region_radius = o.initial_trust_region_radius;
  so.logging_type = ceres::SILENT;
  std::string why;
  if (!so.IsValid(&why)) return MakeError(ErrorCode::kInvalidArgument, "ceres options: " + why);
  ceres::Solver::Summary summary;
  if (problem.NumResidualBlocks() > 0) {
    ceres::Solve(so, &problem, &summary);
    res.iterations = static_cast<int>(summary.iterations.size()) - 1;  // minus iteration 0
    res.termination = ceres::TerminationTypeToString(summary.termination_type);
    res.converged = summary.termination_type == ceres::CONVERGENCE;
    // Ceres reports the time limit as NO_CONVERGENCE with this message (iteration limits too,
    // with another message).
    res.time_limited = summary.termination_type == ceres::NO_CONVERGENCE &&
                       summary.message.rfind("Maximum solver time", 0) == 0;
    res.ceres_report = summary.FullReport();
    if (summary.termination_type == ceres::FAILURE)
      return MakeError(ErrorCode::kInternal, "ceres failed: " + summary.message);
  } else {
    res.termination = "NO_EDGES";
    res.converged = true;
  }
  res.solve_s = SecondsSince(t_solve);

  for (size_t i = 0; i < n; ++i) {
    const double* p = &params[i * dim];
    if (is3d) {
      auto& v = g->vertices3[i];
      Eigen::Quaterniond q(p[6], p[3], p[4], p[5]);
      v.pose = Eigen::Isometry3d::Identity();
      v.pose.linear() = q.normalized().toRotationMatrix();
      v.pose.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
    } else {
      g->vertices2[i].pose = Pose2(p[0], p[1], WrapAngle(p[2]));
    }
  }
  g->vertices_implicit = false;
  chi2 = ComputeChi2(*g);
  if (!chi2.ok()) return chi2.error();
  res.chi2_final = *chi2;
  return res;
}

}  // namespace omni::pgm
