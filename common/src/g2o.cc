#include "omni/io/g2o.h"

#include <charconv>
#include <fstream>
#include <set>
#include <string_view>
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

// Whitespace-separated fields of one line, parsed with std::from_chars (locale-free and several
// times faster than an istringstream per line; a 3D graph of 6000 edges is 170 000 numbers).
// A field must be a number as a whole: "3.5" is not an id, "1.2abc" not a value.
class Fields {
 public:
  explicit Fields(std::string_view line) : rest_(line) {}
  bool Next(std::string_view* out) {
    size_t i = 0;
    while (i < rest_.size() && IsSpace(rest_[i])) ++i;
    size_t j = i;
    while (j < rest_.size() && !IsSpace(rest_[j])) ++j;
    *out = rest_.substr(i, j - i);
    rest_.remove_prefix(j);
    return !out->empty();
  }
  template <class T>
  bool Number(T* v) {
    std::string_view f;
    if (!Next(&f)) return false;
    const char* end = f.data() + f.size();
    const auto [ptr, ec] = std::from_chars(f.data(), end, *v);
    return ec == std::errc() && ptr == end;
  }

 private:
  static bool IsSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; }
  std::string_view rest_;
};

// `v` as printf("%.12g") would write it (what the writer always used), appended to `out`.
void AppendNumber(std::string* out, double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v, std::chars_format::general, 12);
  out->push_back(' ');
  out->append(buf, r.ptr);
}
void AppendNumber(std::string* out, int v) {
  char buf[16];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  out->push_back(' ');
  out->append(buf, r.ptr);
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
  std::vector<int64_t> fix_lines;  // the line of each FIX id
  while (std::getline(in, line)) {
    ++lineno;
    Fields ss(line);
    std::string_view tag;
    if (!ss.Next(&tag) || tag[0] == '#') continue;
    auto bad = [&](const std::string& why) {
      return MakeError(ErrorCode::kParse,
                       name + ":" + std::to_string(lineno) + ": " + std::string(tag) + ": " + why);
    };
    auto read = [&](double* v, int n) {
      for (int i = 0; i < n; ++i)
        if (!ss.Number(&v[i]) || !std::isfinite(v[i])) return false;
      return true;
    };
    if (tag == "VERTEX_SE2" || tag == "VERTEX2") {
      Vertex2 v;
      double p[3];
      if (!ss.Number(&v.id) || !read(p, 3)) return bad("expected id x y theta");
      if (!ids2.insert(v.id).second)
        return bad("vertex id " + std::to_string(v.id) + " defined twice");
      v.pose = Pose2(p[0], p[1], p[2]);
      g.vertices2.push_back(v);
    } else if (tag == "EDGE_SE2" || tag == "EDGE2") {
      Edge2 e;
      e.line = lineno;
      double p[9];
      if (!ss.Number(&e.from) || !ss.Number(&e.to) || !read(p, 9))
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
      if (!ss.Number(&v.id) || !read(p, 7)) return bad("expected id x y z qx qy qz qw");
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
      if (!ss.Number(&v.id) || !read(p, 6)) return bad("expected id x y z roll pitch yaw");
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
      if (!ss.Number(&e.from) || !ss.Number(&e.to) || !read(p, np) || !read(info, 21))
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
      if (!quat) {
        // TORO's information is over (x, y, z, roll, pitch, yaw) errors; ours (and g2o's
        // EDGE_SE3:QUAT) over the translation and the error quaternion's vector part, which is
        // half the rotation for small errors: J^T Omega J with J = diag(1, 1, 1, 2, 2, 2).
        e.information.bottomRightCorner<3, 3>() *= 4.0;
        e.information.topRightCorner<3, 3>() *= 2.0;
        e.information.bottomLeftCorner<3, 3>() *= 2.0;
      }
      if (!PositiveDefinite<6>(e.information))
        return bad("information matrix is not positive definite");
      g.edges3.push_back(e);
    } else if (tag == "FIX") {
      std::string_view f;
      while (ss.Next(&f)) {
        int id = 0;
        const auto [ptr, ec] = std::from_chars(f.data(), f.data() + f.size(), id);
        if (ec != std::errc() || ptr != f.data() + f.size())
          return bad("'" + std::string(f) + "' is not a vertex id");
        g.fixed.push_back(id);
        fix_lines.push_back(lineno);
      }
    } else {
      return MakeError(ErrorCode::kParse, name + ":" + std::to_string(lineno) + ": unknown tag '" +
                                              std::string(tag) + "'");
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
  for (size_t i = 0; i < g.fixed.size(); ++i) {
    if (!ids2.count(g.fixed[i]) && !ids3.count(g.fixed[i]))
      return MakeError(ErrorCode::kParse, name + ":" + std::to_string(fix_lines[i]) +
                                              ": FIX: vertex " + std::to_string(g.fixed[i]) +
                                              " does not exist");
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
    std::ofstream out(tmp, std::ios::binary);
    if (!out) return MakeError(ErrorCode::kIo, "cannot write '" + tmp + "'");
    std::string text;
    text.reserve(64 * (g.vertices2.size() + g.vertices3.size()) + 160 * g.edges2.size() +
                 400 * g.edges3.size());
    for (const auto& v : g.vertices2) {
      text += "VERTEX_SE2";
      AppendNumber(&text, v.id);
      for (double x : {v.pose.x, v.pose.y, v.pose.theta}) AppendNumber(&text, x);
      text += '\n';
    }
    for (const auto& e : g.edges2) {
      text += "EDGE_SE2";
      AppendNumber(&text, e.from);
      AppendNumber(&text, e.to);
      for (double x : {e.measurement.x, e.measurement.y, e.measurement.theta})
        AppendNumber(&text, x);
      for (int r = 0; r < 3; ++r)
        for (int c = r; c < 3; ++c) AppendNumber(&text, e.information(r, c));
      text += '\n';
    }
    for (const auto& v : g.vertices3) {
      const Eigen::Quaterniond q(v.pose.linear());
      const Eigen::Vector3d t = v.pose.translation();
      text += "VERTEX_SE3:QUAT";
      AppendNumber(&text, v.id);
      for (double x : {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()}) AppendNumber(&text, x);
      text += '\n';
    }
    for (const auto& e : g.edges3) {
      const Eigen::Quaterniond q(e.measurement.linear());
      const Eigen::Vector3d t = e.measurement.translation();
      text += "EDGE_SE3:QUAT";
      AppendNumber(&text, e.from);
      AppendNumber(&text, e.to);
      for (double x : {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()}) AppendNumber(&text, x);
      for (int r = 0; r < 6; ++r)
        for (int c = r; c < 6; ++c) AppendNumber(&text, e.information(r, c));
      text += '\n';
    }
    if (!g.fixed.empty()) {
      text += "FIX";
      for (int id : g.fixed) AppendNumber(&text, id);
      text += '\n';
    }
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
    if (!out) return MakeError(ErrorCode::kIo, "write to '" + tmp + "' failed");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    return MakeError(ErrorCode::kIo, "cannot rename '" + tmp + "' to '" + path + "'");
  return Status::Ok();
}

}  // namespace omni::io
