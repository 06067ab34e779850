// A laser_scan_t off the bus as odom_mapper's library takes it: shared by the process and the
// mapper_stream fuzz target, so the target feeds the library what the process would. (Header
// only: the library itself does not depend on the bus's message types.)
#pragma once

#include "omni/bus/convert.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odom_mapper/odom_mapper.h"

namespace omni::odom_mapper {

inline Scan ScanFromMessage(const omni::laser_scan_t& m) {
  Scan s;
  s.utime = m.utime;
  s.seq = m.seq;
  s.sensor_in_base = Pose2(m.sensor_x_m, m.sensor_y_m, m.sensor_yaw_rad);
  s.angle_min_rad = m.angle_min_rad;
  s.angle_increment_rad = m.angle_increment_rad;
  s.range_min_m = m.range_min_m;
  s.range_max_m = m.range_max_m;
  s.scan_time_s = bus::SweepTime(m.scan_time_s);
  s.ranges_m = m.ranges_m;
  return s;
}

}  // namespace omni::odom_mapper
