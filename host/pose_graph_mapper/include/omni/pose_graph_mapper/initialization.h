// Initial estimates for batch pose-graph optimisation.
//
// kNone:         the poses in the file (odometry-chained, usually).
// kSpanningTree: breadth-first spanning tree from the root over all edges (odometry and loop
//                closures, fewest hops first), composing edge measurements; MRPT's graph-slam
//                does the same. Needed for edge-only files such as CSAIL.g2o.
// kChordal:      a linear relaxation. 2D: orientations from a weighted linear least-squares over
//                all edges with the 2 pi ambiguities fixed by the spanning tree (Carlone's LAGO),
//                then positions by linear least squares given the orientations. 3D: chordal
//                relaxation of rotations (R_j = R_i R_ij as 9 linear equations per edge,
//                projected back onto SO(3)), then positions. Sparse Cholesky; no Ceres.
// The root keeps its pose; a graph whose vertices are not all reachable from the root is an
// error naming one unreachable vertex.
#pragma once

#include <string>

#include "omni/common/result.h"
#include "omni/io/g2o.h"

namespace omni::pgm {

enum class Initialization { kNone, kSpanningTree, kChordal };

const char* InitializationName(Initialization init);
Result<Initialization> ParseInitialization(const std::string& name);

// The gauge vertex: the first FIX id that is a vertex, else the smallest vertex id.
int ChooseRoot(const io::PoseGraph& graph);

Status InitializeSpanningTree(io::PoseGraph* graph, int root_id);
Status InitializeChordal(io::PoseGraph* graph, int root_id);
Status Initialize(io::PoseGraph* graph, Initialization init, int root_id);

}  // namespace omni::pgm
