// Batch optimisation of a whole 2D (SE2) or 3D (SE3:QUAT) pose graph with Ceres:
// initialisation (see initialization.h), then Levenberg-Marquardt with sparse Cholesky
// (SuiteSparse), the root vertex held constant as the gauge. chi^2 before/after are computed
// by chi2.h's evaluator, not by Ceres, so they compare with any other system's output.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omni/common/config.h"
#include "omni/common/geometry.h"
#include "omni/common/result.h"
#include "omni/io/g2o.h"
#include "omni/pose_graph_mapper/initialization.h"

namespace omni::pgm {

struct BatchOptions {
  Initialization initialization = Initialization::kChordal;
  int max_iterations = 100;
  // Wall-clock limit of the Ceres solve in seconds (checked between iterations, so one
  // iteration may run past it); 0: none.
  double max_time_s = 0;
  // Ceres' convergence tests: relative cost decrease, and max |gradient| (tangent space).
  double function_tolerance = 1e-10;
  double gradient_tolerance = 1e-12;
  double parameter_tolerance = 1e-10;
  std::string sparse_library = "suitesparse";  // sparse Cholesky: suitesparse | eigen
  std::string loss = "none";  // none | huber | cauchy (on the whitened residual norm)
  double loss_scale = 1.0;
  // 2D edges from this index on take no loss: factors already weighted by it when they were made
  // (PoseGraphSlam's marginalised ones, node_removal.h). Not read from the config.
  size_t first_plain_edge2 = SIZE_MAX;
  int num_threads = 1;  // the caller decides (main passes the number of cores)
  // Levenberg-Marquardt's first trust region; large = start close to Gauss-Newton, which
  // suits the good starting points of the linear initialisations.
  double initial_trust_region_radius = 1e8;

  // Reads the `batch` section's keys from `r` (ConfigReader::Finish is the caller's).
  static Result<BatchOptions> Load(ConfigReader& r);
  Status Validate() const;
};

// Reads config/pose_graph_mapper.yaml's `batch` section; unknown keys anywhere in the file are
// errors naming file, line and key.
Result<BatchOptions> LoadBatchOptionsFile(const std::string& path);

struct BatchResult {
  double chi2_input = 0;        // the graph as given
  double chi2_initialized = 0;  // after the initialisation
  double chi2_final = 0;
  int iterations = 0;  // Ceres iterations (successful + unsuccessful)
  double init_s = 0, solve_s = 0;
  std::string termination;  // Ceres' termination type and message
  bool converged = false;
  bool time_limited = false;  // stopped by max_time_s before converging
  int root_id = 0;
  std::string ceres_report;  // Ceres' FullReport (per-stage times), for --verbose
};

// Absolute (GPS-like) factor on a 2D vertex: the vertex's pose in the graph's frame with an
// information matrix over (x_m, y_m, theta_rad) (PosePrior2Cost). g2o files have no such edge,
// so these are passed beside the graph.
struct VertexPrior2 {
  int id = 0;
  Pose2 z;
  Eigen::Matrix3d information = Eigen::Matrix3d::Identity();
};

// Optimises `graph` in place (vertex poses), with the absolute factors `priors` (2D only, may
// be null; they get the same loss as the edges and do not enter the reported chi^2). Errors:
// invalid options, a graph without vertices or edges, an edge or prior to a missing vertex, a
// disconnected graph with an initialisation that needs a spanning tree.
Result<BatchResult> OptimizeGraph(io::PoseGraph* graph, const BatchOptions& options,
                                  const std::vector<VertexPrior2>* priors = nullptr);

}  // namespace omni::pgm
