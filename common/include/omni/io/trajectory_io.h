// Trajectory files.
//  - indexed 2D form (the datasets' reference files and our mappers' output):
//      `index timestamp x y theta`   (index = 0-based scan index, timestamp in seconds)
//  - TUM form: `timestamp tx ty tz qx qy qz qw`
// Lines starting with '#' are comments. The form is detected from the column count.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "omni/common/geometry.h"
#include "omni/common/result.h"

namespace omni::io {

struct TrajectoryEntry {
  int64_t index = -1;  // scan index (indexed form), -1 for TUM
  double timestamp_s = 0;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  double yaw() const;
  Pose2 pose2() const { return Pose2(position.x(), position.y(), yaw()); }
};

struct Trajectory {
  enum class Format { kIndexed2D, kTum } format = Format::kIndexed2D;
  std::vector<TrajectoryEntry> entries;
};

Result<Trajectory> ReadTrajectory(const std::string& path);
TrajectoryEntry MakeEntry2D(int64_t index, double timestamp_s, const Pose2& pose);
// Writes the indexed 2D form (atomically: temp file + rename).
Status WriteTrajectory2D(const std::string& path, const std::vector<TrajectoryEntry>& entries,
                         const std::string& header_comment = "");

}  // namespace omni::io
