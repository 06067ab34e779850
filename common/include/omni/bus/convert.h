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
// Rejects messages whose sizes disagree or whose resolution is not positive.
Result<io::GridMap> FromGridMessage(const omni::occupancy_grid_t& msg);

}  // namespace omni::bus
