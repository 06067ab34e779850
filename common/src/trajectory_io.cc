#include "omni/io/trajectory_io.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <sstream>

namespace omni::io {

double TrajectoryEntry::yaw() const {
  const Eigen::Matrix3d r = orientation.toRotationMatrix();
  return std::atan2(r(1, 0), r(0, 0));
}

TrajectoryEntry MakeEntry2D(int64_t index, double timestamp_s, const Pose2& pose) {
  TrajectoryEntry e;
  e.index = index;
  e.timestamp_s = timestamp_s;
  e.position = Eigen::Vector3d(pose.x, pose.y, 0);
  e.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(pose.theta, Eigen::Vector3d::UnitZ()));
  return e;
}

Result<Trajectory> ReadTrajectory(const std::string& path) {
  std::ifstream in(path);
  if (!in) return MakeError(ErrorCode::kNotFound, "cannot open trajectory '" + path + "'");
  Trajectory t;
  bool format_known = false;
  std::string line;
  int64_t lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    std::istringstream ss(line);
    std::vector<double> v;
    std::string tok;
    bool comment = false;
    while (ss >> tok) {
      if (v.empty() && tok[0] == '#') {
        comment = true;
        break;
      }
      char* end = nullptr;
      const double d = std::strtod(tok.c_str(), &end);
      if (end != tok.c_str() + tok.size() || !std::isfinite(d))
        return MakeError(ErrorCode::kParse, path + ":" + std::to_string(lineno) + ": '" + tok +
                                                "' is not a finite number");
      v.push_back(d);
    }
    if (comment || v.empty()) continue;
    Trajectory::Format f;
    if (v.size() == 5)
      f = Trajectory::Format::kIndexed2D;
    else if (v.size() == 8)
      f = Trajectory::Format::kTum;
    else
      return MakeError(ErrorCode::kParse, path + ":" + std::to_string(lineno) +
                                              ": expected 5 columns " +
                                              "(index timestamp x y theta) or 8 (TUM), got " +
                                              std::to_string(v.size()));
    if (!format_known) {
      t.format = f;
      format_known = true;
    } else if (f != t.format) {
      return MakeError(ErrorCode::kParse,
                       path + ":" + std::to_string(lineno) + ": mixes trajectory forms");
    }
    if (f == Trajectory::Format::kIndexed2D) {
      // A scan index: a whole number, not 0.9 read as 0 (or 1e300 cast to nothing defined).
      if (!(v[0] >= 0 && v[0] < 9.0e15 && v[0] == std::floor(v[0])))
        return MakeError(ErrorCode::kParse, path + ":" + std::to_string(lineno) + ": index " +
                                                std::to_string(v[0]) +
                                                " is not a whole number from 0 to 9e15");
      t.entries.push_back(MakeEntry2D(static_cast<int64_t>(v[0]), v[1], Pose2(v[2], v[3], v[4])));
    } else {
      TrajectoryEntry e;
      e.timestamp_s = v[0];
      e.position = Eigen::Vector3d(v[1], v[2], v[3]);
      Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
      if (q.norm() < 1e-9)
        return MakeError(ErrorCode::kParse,
                         path + ":" + std::to_string(lineno) + ": zero quaternion");
      e.orientation = q.normalized();
      t.entries.push_back(e);
    }
  }
  return t;
}

Status WriteTrajectory2D(const std::string& path, const std::vector<TrajectoryEntry>& entries,
                         const std::string& header_comment) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp);
    if (!out) return MakeError(ErrorCode::kIo, "cannot write '" + tmp + "'");
    out << "# " << (header_comment.empty() ? "index timestamp x y theta" : header_comment) << '\n';
    out << std::fixed;
    for (const auto& e : entries) {
      out << e.index << ' ' << std::setprecision(6) << e.timestamp_s << ' ' << e.position.x() << ' '
          << e.position.y() << ' ' << e.yaw() << '\n';
    }
    if (!out) return MakeError(ErrorCode::kIo, "write to '" + tmp + "' failed");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    return MakeError(ErrorCode::kIo, "cannot rename '" + tmp + "' to '" + path + "'");
  return Status::Ok();
}

}  // namespace omni::io
