// Reader for CARMEN logs (.clf, .log, optionally gzip-compressed): FLASER, RLASER,
// ROBOTLASER1 and ODOM lines. Other message types (PARAM, NEFF, SYNC, TRUEPOS, ...) are
// skipped and counted. Beam angles follow ../shared/datasets/README.md: beam i of an
// FLASER/RLASER line is at -90 deg + i * res, res = 1 deg for 180/181 beams, 0.5 deg for
// 360/361 beams, counter-clockwise, 0 = robot forward.
#pragma once

#include <cstdint>
#include <istream>
#include <map>
#include <string>
#include <vector>

#include "omni/common/geometry.h"
#include "omni/common/result.h"

namespace omni::io {

struct CarmenLaser {
  std::string tag;          // FLASER, RLASER or ROBOTLASER1
  int64_t line = 0;         // 1-based line in the file
  double timestamp_s = 0;   // ipc timestamp, seconds
  float angle_min_rad = 0;  // beam 0, CCW from the laser's forward axis
  float angle_increment_rad = 0;
  float max_range_m = 0;  // readings >= this are "no return" (CARMEN writes max range); for
                          // FLASER/RLASER the log's (CarmenLog::max_range_m), not the line's
  std::vector<float> ranges_m;
  Pose2 laser_pose;  // pose of the laser in the odometry frame (from the line)
  Pose2 robot_pose;  // odometry pose of the robot base (from the line)
};

struct CarmenOdom {
  int64_t line = 0;
  double timestamp_s = 0;
  Pose2 pose;           // odometry pose of the robot base
  double tv_m_s = 0;    // translational velocity
  double rv_rad_s = 0;  // rotational velocity
};

struct CarmenRecord {
  enum class Kind { kLaser, kOdom } kind = Kind::kLaser;
  CarmenLaser laser;
  CarmenOdom odom;
  double timestamp_s() const { return kind == Kind::kLaser ? laser.timestamp_s : odom.timestamp_s; }
};

struct CarmenLog {
  std::vector<CarmenRecord> records;  // in file order
  size_t num_lasers = 0;
  size_t num_odometry = 0;
  std::map<std::string, size_t> skipped;  // other message types, by tag
  // FLASER/RLASER: the sensor's range, which the lines do not carry: the largest reading most
  // lines share (a beam without a return is written as it), else the log's largest reading.
  std::map<std::string, float> max_range_m;
};

// Reads a (possibly gzip-compressed) CARMEN log. Any malformed FLASER/RLASER/ROBOTLASER1/ODOM
// line is an error naming the file and line.
Result<CarmenLog> ReadCarmenLog(const std::string& path);
Result<CarmenLog> ParseCarmenLog(std::istream& in, const std::string& name);

// Beam spacing of an FLASER/RLASER line with n beams (see the header comment).
float CarmenBeamIncrementRad(size_t n);

// Reads a whole file, transparently decompressing gzip. Errors name the file.
Result<std::string> ReadMaybeGzipFile(const std::string& path);

}  // namespace omni::io
