// Pose-graph files: g2o (VERTEX_SE2/EDGE_SE2, VERTEX_SE3:QUAT/EDGE_SE3:QUAT, FIX) and TORO
// (VERTEX2/EDGE2, VERTEX3/EDGE3; an EDGE3's information over x y z roll pitch yaw is converted
// to the EDGE_SE3:QUAT residual's). Unknown tags, edges to missing vertices, FIX ids that are
// not vertices and information matrices that are not positive definite are errors naming the
// file and line. A file with
// edges but no vertex lines at all is accepted with implicit vertices (see vertices_implicit).
#pragma once

#include <istream>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "omni/common/geometry.h"
#include "omni/common/result.h"

namespace omni::io {

struct Vertex2 {
  int id = 0;
  Pose2 pose;
};
struct Edge2 {
  int from = 0, to = 0;
  Pose2 measurement;                                          // pose of `to` in the frame of `from`
  Eigen::Matrix3d information = Eigen::Matrix3d::Identity();  // over (x, y, theta)
  int64_t line = 0;
};
struct Vertex3 {
  int id = 0;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
};
struct Edge3 {
  int from = 0, to = 0;
  Eigen::Isometry3d measurement = Eigen::Isometry3d::Identity();
  Eigen::Matrix<double, 6, 6> information =
      Eigen::Matrix<double, 6, 6>::Identity();  // (x y z rx ry rz)
  int64_t line = 0;
};

struct PoseGraph {
  std::vector<Vertex2> vertices2;
  std::vector<Edge2> edges2;
  std::vector<Vertex3> vertices3;
  std::vector<Edge3> edges3;
  std::vector<int> fixed;  // FIX ids (each an existing vertex): held where the file puts them
  // True for edge-only files (e.g. CSAIL.g2o in the datasets): the vertices were created from
  // the edge ids with identity poses, so the optimiser must initialise them (spanning tree).
  bool vertices_implicit = false;
  bool is_3d() const { return !vertices3.empty(); }
};

Result<PoseGraph> ReadPoseGraph(const std::string& path);
Result<PoseGraph> ParsePoseGraph(std::istream& in, const std::string& name);
// Writes g2o format (SE2 or SE3:QUAT, whichever the graph holds).
Status WriteG2o(const std::string& path, const PoseGraph& graph);

}  // namespace omni::io
