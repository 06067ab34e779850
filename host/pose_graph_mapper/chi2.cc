#include "omni/pose_graph_mapper/chi2.h"

#include <string>
#include <unordered_map>

namespace omni::pgm {

Eigen::Vector3d EdgeError2(const Pose2& z, const Pose2& a, const Pose2& b) {
  const Pose2 ab = a.Between(b);
  const double c = std::cos(z.theta), s = std::sin(z.theta);
  const double dx = ab.x - z.x, dy = ab.y - z.y;
  return {c * dx + s * dy, -s * dx + c * dy, WrapAngle(b.theta - a.theta - z.theta)};
}

Eigen::Matrix<double, 6, 1> EdgeError3(const Eigen::Isometry3d& z, const Eigen::Isometry3d& a,
                                       const Eigen::Isometry3d& b) {
  const Eigen::Quaterniond qz(z.linear()), qa(a.linear()), qb(b.linear());
  const Eigen::Quaterniond qa_inv = qa.conjugate();
  const Eigen::Vector3d p_ab = qa_inv * (b.translation() - a.translation());
  const Eigen::Quaterniond qz_inv = qz.conjugate();
  Eigen::Quaterniond qd = (qz_inv * (qa_inv * qb)).normalized();
  if (qd.w() < 0) qd.coeffs() = -qd.coeffs();
  Eigen::Matrix<double, 6, 1> e;
  e.head<3>() = qz_inv * (p_ab - z.translation());
  e.tail<3>() = qd.vec();
  return e;
}

Result<double> ComputeChi2(const io::PoseGraph& g) {
  double chi2 = 0;
  auto missing = [](int64_t line, int from, int to) {
    return MakeError(ErrorCode::kInvalidArgument,
                     "line " + std::to_string(line) + ": edge " + std::to_string(from) + " -> " +
                         std::to_string(to) + " refers to a vertex that does not exist");
  };
  if (!g.edges2.empty()) {
    std::unordered_map<int, const Pose2*> v;
    for (const auto& x : g.vertices2) v[x.id] = &x.pose;
    for (const auto& e : g.edges2) {
      auto a = v.find(e.from), b = v.find(e.to);
      if (a == v.end() || b == v.end()) return missing(e.line, e.from, e.to);
      const Eigen::Vector3d err = EdgeError2(e.measurement, *a->second, *b->second);
      chi2 += err.dot(e.information * err);
    }
  }
  if (!g.edges3.empty()) {
    std::unordered_map<int, const Eigen::Isometry3d*> v;
    for (const auto& x : g.vertices3) v[x.id] = &x.pose;
    for (const auto& e : g.edges3) {
      auto a = v.find(e.from), b = v.find(e.to);
      if (a == v.end() || b == v.end()) return missing(e.line, e.from, e.to);
      const Eigen::Matrix<double, 6, 1> err = EdgeError3(e.measurement, *a->second, *b->second);
      chi2 += err.dot(e.information * err);
    }
  }
  return chi2;
}

}  // namespace omni::pgm
