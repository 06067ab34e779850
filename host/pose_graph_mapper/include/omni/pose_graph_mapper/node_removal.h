// Removing a pose from a 2D pose graph of relative factors (the online mapper's long shifts:
// docs/posegraph.md, "Removing retired poses").
//
// The node's factors are linearised at the current estimates, the node is marginalised out of
// them (Schur complement), and the dense factor this leaves on its neighbours is replaced by a
// tree of relative-pose factors: a maximum spanning tree over the neighbour pairs, each pair
// weighted by how well the marginal fixes its relative pose (-log det of that pose's
// covariance), each tree edge with the marginal's information about that relative pose. This is
// the pairwise-marginal tree of Carlevaris-Bianco, Kaess and Eustice's generic node removal (IEEE
// T-RO 2014) with a simpler pair weight. The tree's measurements are chosen so that, at the
// current estimates, it pulls on the neighbours exactly as the removed factors did: a graph at
// its optimum stays there (to first order). For a node between two neighbours only (a chain),
// the result is the exact composition of the two factors.
#pragma once

#include <map>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omni/common/geometry.h"
#include "omni/common/result.h"

namespace omni::pgm {

struct RelativeFactor2 {
  int from = 0, to = 0;
  Pose2 z;  // the pose of `to` in `from`'s frame; error as EdgeError2 (chi2.h)
  Eigen::Matrix3d information = Eigen::Matrix3d::Identity();
};

// `factors` are the factors touching `node` (each has `node` at one end); `estimates` holds the
// current pose of `node` and every neighbour. Returns the replacement factors (neighbours - 1 of
// them, each from the older of its two nodes by `order`: a smaller order value is older), or an
// error when the linearised factors do not fix the neighbours relative to each other (a
// singular marginal).
Result<std::vector<RelativeFactor2>> MarginalizeNode(int node,
                                                     const std::vector<RelativeFactor2>& factors,
                                                     const std::map<int, Pose2>& estimates,
                                                     const std::map<int, int64_t>& order);

// The weight a robust loss ("none", "huber", "cauchy", as BatchOptions::loss) gives a factor
// whose whitened squared error is s2: rho'(s2), the weight of iteratively reweighted least
// squares (Ceres' curvature correction rho'' is left out). A factor is marginalised with its
// information times this weight, as the global solve last saw it.
double LossWeight(const std::string& loss, double scale, double s2);

// Two factors between the same two nodes as one (their information summed), linearised at the
// nodes' estimates `from` and `to`: keeps the graph from collecting parallel edges.
RelativeFactor2 MergeRelativeFactors(const RelativeFactor2& f1, const RelativeFactor2& f2,
                                     const Pose2& from, const Pose2& to);

}  // namespace omni::pgm
