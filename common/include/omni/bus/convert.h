// Conversions between file-format records / library types and bus messages.
#pragma once

#include "omni/io/carmen.h"
#include "omni/io/grid.h"
#include "omni/laser_scan_t.hpp"
#include "omni/occupancy_grid_t.hpp"
#include "omni/odometry_t.hpp"

namespace omni::bus {

// A CARMEN laser line as a scan: invalid readings (written as the maximum range) become NaN;
// the sensor pose in the base frame is the line's laser pose relative to its robot pose.
omni::laser_scan_t ToLaserScan(const io::CarmenLaser& laser, int64_t seq);
// A CARMEN ODOM line as odometry in the "odom" frame (velocities from tv/rv).
omni::odometry_t ToOdometry(const io::CarmenOdom& odom, int64_t seq);
omni::occupancy_grid_t ToGridMessage(const io::GridMap& map, int64_t utime,
                                     const std::string& source);
// Rejects messages whose sizes disagree, whose resolution is not positive and finite or whose
// origin is not finite; a grid turned in its frame (origin_yaw_rad) is resampled onto the
// frame's axes (io::AxisAligned).
Result<io::GridMap> FromGridMessage(const omni::occupancy_grid_t& msg);

// A laser_scan_t's sweep time as the mappers use it: the message's scan_time_s when it is a
// plausible revolution (finite, in (0, 1] s), else 0 (the scan is taken as one instant). A
// lidar slower than 1 Hz is not one of ours; a wild value must not overflow the time arithmetic.
inline float SweepTime(float scan_time_s) {
  return scan_time_s > 0.f && scan_time_s <= 1.f ? scan_time_s : 0.f;  // NaN compares false
}

}  // namespace omni::bus
