// chi^2 of a pose graph: sum over edges of e^T Omega e, with g2o's edge errors
//   SE(2): e = t2v(Z^-1 A^-1 B) = (R_z^T (R_a^T (p_b - p_a) - p_z), wrap(th_b - th_a - th_z))
//   SE(3): D = Z^-1 A^-1 B, e = (t_D, vec(q_D)) with q_D's w >= 0
// This is the one evaluator the CLI and the benchmark use for every system's output file, so
// ours and the peer's results are scored the same way. It does not use Ceres.
#pragma once

#include <Eigen/Geometry>

#include "omni/common/geometry.h"
#include "omni/common/result.h"
#include "omni/io/g2o.h"

namespace omni::pgm {

Eigen::Vector3d EdgeError2(const Pose2& measurement, const Pose2& a, const Pose2& b);
Eigen::Matrix<double, 6, 1> EdgeError3(const Eigen::Isometry3d& measurement,
                                       const Eigen::Isometry3d& a, const Eigen::Isometry3d& b);

// Errors when an edge refers to a vertex the graph does not hold (naming the edge's line).
Result<double> ComputeChi2(const io::PoseGraph& graph);

}  // namespace omni::pgm
