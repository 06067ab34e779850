#include "omni/io/g2o.h"

#include <fstream>
#include <iomanip>
#include <set>
#include <sstream>
#include <unordered_set>

#include <Eigen/Cholesky>

namespace omni::io {
namespace {

template <int N>
bool PositiveDefinite(const Eigen::Matrix<double, N, N>& m) {
  if (!m.allFinite()) return false;
  Eigen::LLT<Eigen::Matrix<double, N, N>> llt(0.5 * (m + m.transpose()));
  return llt.info() == Eigen::Success;
}

template <int N>
Eigen::Matrix<double, N, N> UpperTriangular(const double* v) {
  Eigen::Matrix<double, N, N> m;
  int k = 0;
  for (int r = 0; r < N; ++r)
    for (int c = r; c < N; ++c) {
      m(r, c) = v[k];
      m(c, r) = v[k];
      ++k;
    }
  return m;
}

Eigen::Matrix3d RollPitchYaw(double roll, double pitch, double yaw) {
  return (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

}  // namespace

Result<PoseGraph> ReadPoseGraph(const std::string& path) {
  std::ifstream in(path);
  if (!in) return MakeError(ErrorCode::kNotFound, "cannot open pose graph '" + path + "'");
  return ParsePoseGraph(in, path);
}

Result<PoseGraph> ParsePoseGraph(std::istream& in, const std::string& name) {
  PoseGraph g;
  std::string line;
  int64_t lineno = 0;
  std::unordered_set<int> ids2, ids3;
  while (std::getline(in, line)) {
    ++lineno;
    std::istringstream ss(line);
    std::string tag;
    if (!(ss >> tag) || tag[0] == '#') continue;
    const std::string where = name + ":" + std::to_string(lineno) + ": ";
    auto bad = [&](const std::string& why) {
      return MakeError(ErrorCode::kParse, where + tag + ": " + why);
    };
    auto read = [&](double* v, int n) {
      for (int i = 0; i < n; ++i)
        if (!(ss >> v[i]) || !std::isfinite(v[i])) return false;
      return true;
    };
    if (tag == "VERTEX_SE2" || tag == "VERTEX2") {
      Vertex2 v;
      double p[3];
      if (!(ss >> v.id) || !read(p, 3)) return bad("expected id x y theta");
      if (!ids2.insert(v.id).second)
        return bad("vertex id " + std::to_string(v.id) + " defined twice");
      v.pose = Pose2(p[0], p[1], p[2]);
      g.vertices2.push_back(v);
    } else if (tag == "EDGE_SE2" || tag == "EDGE2") {
      Edge2 e;
      e.line = lineno;
      double p[9];
      if (!(ss >> e.from >> e.to) || !read(p, 9))
        return bad("expected from to dx dy dtheta and 6 information values");
      e.measurement = Pose2(p[0], p[1], p[2]);
      if (tag == "EDGE_SE2") {
        e.information = UpperTriangular<3>(p + 3);  // i11 i12 i13 i22 i23 i33
      } else {
        // TORO order: xx xy yy tt xt yt
        Eigen::Matrix3d m;
        m << p[3], p[4], p[7], p[4], p[5], p[8], p[7], p[8], p[6];
        e.information = m;
      }
      if (!PositiveDefinite<3>(e.information))
        return bad("information matrix is not positive definite");
      g.edges2.push_back(e);
    } else if (tag == "VERTEX_SE3:QUAT") {
      Vertex3 v;
      double p[7];
      if (!(ss >> v.id) || !read(p, 7)) return bad("expected id x y z qx qy qz qw");
      if (!ids3.insert(v.id).second)
        return bad("vertex id " + std::to_string(v.id) + " defined twice");
      Eigen::Quaterniond q(p[6], p[3], p[4], p[5]);
      if (q.norm() < 1e-9) return bad("zero quaternion");
      v.pose.linear() = q.normalized().toRotationMatrix();
      v.pose.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
      g.vertices3.push_back(v);
    } else if (tag == "VERTEX3") {
      Vertex3 v;
      double p[6];
      if (!(ss >> v.id) || !read(p, 6)) return bad("expected id x y z roll pitch yaw");
      if (!ids3.insert(v.id).second)
        return bad("vertex id " + std::to_string(v.id) + " defined twice");
      v.pose.linear() = RollPitchYaw(p[3], p[4], p[5]);
      v.pose.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
      g.vertices3.push_back(v);
    } else if (tag == "EDGE_SE3:QUAT" || tag == "EDGE3") {
      Edge3 e;
      e.line = lineno;
      const bool quat = tag == "EDGE_SE3:QUAT";
      const int np = quat ? 7 : 6;
      double p[7];
      double info[21];
      if (!(ss >> e.from >> e.to) || !read(p, np) || !read(info, 21))
        return bad("expected from to, the relative pose and 21 information values");
      if (quat) {
        Eigen::Quaterniond q(p[6], p[3], p[4], p[5]);
        if (q.norm() < 1e-9) return bad("zero quaternion");
        e.measurement.linear() = q.normalized().toRotationMatrix();
      } else {
        e.measurement.linear() = RollPitchYaw(p[3], p[4], p[5]);
      }
      e.measurement.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
      e.information = UpperTriangular<6>(info);
      if (!PositiveDefinite<6>(e.information))
        return bad("information matrix is not positive definite");
      g.edges3.push_back(e);
    } else if (tag == "FIX") {
      int id;
      while (ss >> id) g.fixed.push_back(id);
    } else {
      return MakeError(ErrorCode::kParse, where + "unknown tag '" + tag + "'");
    }
  }
  if (!g.vertices2.empty() && !g.vertices3.empty())
    return MakeError(ErrorCode::kParse, name + ": mixes 2D and 3D vertices");
  if (g.vertices2.empty() && g.vertices3.empty() && (!g.edges2.empty() || !g.edges3.empty())) {
    if (!g.edges2.empty() && !g.edges3.empty())
      return MakeError(ErrorCode::kParse, name + ": mixes 2D and 3D edges");
    g.vertices_implicit = true;
    std::set<int> ids;
    for (const auto& e : g.edges2) ids.insert({e.from, e.to});
    for (const auto& e : g.edges3) ids.insert({e.from, e.to});
    for (int id : ids) {
      if (!g.edges2.empty()) {
        g.vertices2.push_back(Vertex2{id, Pose2()});
        ids2.insert(id);
      } else {
        g.vertices3.push_back(Vertex3{id, Eigen::Isometry3d::Identity()});
        ids3.insert(id);
      }
    }
  }
  for (const auto& e : g.edges2) {
    if (!ids2.count(e.from) || !ids2.count(e.to))
      return MakeError(ErrorCode::kParse, name + ":" + std::to_string(e.line) + ": edge " +
                                              std::to_string(e.from) + " -> " +
                                              std::to_string(e.to) +
                                              " refers to a vertex that does not exist");
  }
  for (const auto& e : g.edges3) {
    if (!ids3.count(e.from) || !ids3.count(e.to))
      return MakeError(ErrorCode::kParse, name + ":" + std::to_string(e.line) + ": edge " +
                                              std::to_string(e.from) + " -> " +
                                              std::to_string(e.to) +
                                              " refers to a vertex that does not exist");
  }
  return g;
}

Status WriteG2o(const std::string& path, const PoseGraph& g) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp);
    if (!out) return MakeError(ErrorCode::kIo, "cannot write '" + tmp + "'");
    out << std::setprecision(12);
    for (const auto& v : g.vertices2)
      out << "VERTEX_SE2 " << v.id << ' ' << v.pose.x << ' ' << v.pose.y << ' ' << v.pose.theta
          << '\n';
    for (const auto& e : g.edges2) {
      out << "EDGE_SE2 " << e.from << ' ' << e.to << ' ' << e.measurement.x << ' '
          << e.measurement.y << ' ' << e.measurement.theta;
      for (int r = 0; r < 3; ++r)
        for (int c = r; c < 3; ++c) out << ' ' << e.information(r, c);
      out << '\n';
    }
    for (const auto& v : g.vertices3) {
      const Eigen::Quaterniond q(v.pose.linear());
      const Eigen::Vector3d t = v.pose.translation();
      out << "VERTEX_SE3:QUAT " << v.id << ' ' << t.x() << ' ' << t.y() << ' ' << t.z() << ' '
          << q.x() << ' ' << q.y() << ' ' << q.z() << ' ' << q.w() << '\n';
    }
    for (const auto& e : g.edges3) {
      const Eigen::Quaterniond q(e.measurement.linear());
      const Eigen::Vector3d t = e.measurement.translation();
      out << "EDGE_SE3:QUAT " << e.from << ' ' << e.to << ' ' << t.x() << ' ' << t.y() << ' '
          << t.z() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << ' ' << q.w();
      for (int r = 0; r < 6; ++r)
        for (int c = r; c < 6; ++c) out << ' ' << e.information(r, c);
      out << '\n';
    }
    if (!g.fixed.empty()) {
      out << "FIX";
      for (int id : g.fixed) out << ' ' << id;
      out << '\n';
    }
    if (!out) return MakeError(ErrorCode::kIo, "write to '" + tmp + "' failed");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    return MakeError(ErrorCode::kIo, "cannot rename '" + tmp + "' to '" + path + "'");
  return Status::Ok();
}

}  // namespace omni::io
