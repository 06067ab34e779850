#include "omni/bus/convert.h"

#include <cmath>
#include <limits>

#include "omni/common/time.h"

namespace omni::bus {

omni::laser_scan_t ToLaserScan(const io::CarmenLaser& l, int64_t seq) {
  omni::laser_scan_t s;
  s.utime = SecondsToUtime(l.timestamp_s);
  s.seq = seq;
  s.frame = "laser";
  const Pose2 mount = l.robot_pose.Between(l.laser_pose);
  s.sensor_x_m = mount.x;
  s.sensor_y_m = mount.y;
  s.sensor_yaw_rad = mount.theta;
  s.angle_min_rad = l.angle_min_rad;
  s.angle_increment_rad = l.angle_increment_rad;
  s.scan_time_s = 0.f;
  s.range_min_m = 0.f;
  s.range_max_m = l.max_range_m;
  s.num_ranges = static_cast<int32_t>(l.ranges_m.size());
  s.ranges_m.resize(l.ranges_m.size());
  for (size_t i = 0; i < l.ranges_m.size(); ++i) {
    const float r = l.ranges_m[i];
    s.ranges_m[i] = (std::isfinite(r) && r > 0.f && r < l.max_range_m)
                        ? r
                        : std::numeric_limits<float>::quiet_NaN();
  }
  s.num_intensities = 0;
  return s;
}

omni::odometry_t ToOdometry(const io::CarmenOdom& o, int64_t seq) {
  omni::odometry_t m{};
  m.utime = SecondsToUtime(o.timestamp_s);
  m.seq = seq;
  m.frame = "odom";
  m.child_frame = "base";
  m.x_m = o.pose.x;
  m.y_m = o.pose.y;
  m.yaw_rad = WrapAngle(o.pose.theta);
  m.vx_m_s = o.tv_m_s;
  m.vy_m_s = 0;
  m.omega_rad_s = o.rv_rad_s;
  for (int i = 0; i < 9; ++i) {
    m.pose_covariance[i] = 0;
    m.twist_covariance[i] = 0;
  }
  m.pose_covariance[0] = -1;  // CARMEN logs carry no covariance
  m.twist_covariance[0] = -1;
  return m;
}

omni::occupancy_grid_t ToGridMessage(const io::GridMap& map, int64_t utime,
                                     const std::string& source) {
  omni::occupancy_grid_t g;
  g.utime = utime;
  g.frame = "map";
  g.source = source;
  g.resolution_m = static_cast<float>(map.resolution_m);
  g.origin_x_m = map.origin_x_m;
  g.origin_y_m = map.origin_y_m;
  g.origin_yaw_rad = 0;
  g.width = map.width;
  g.height = map.height;
  g.num_cells = static_cast<int32_t>(map.cells.size());
  g.cells = map.cells;
  return g;
}

Result<io::GridMap> FromGridMessage(const omni::occupancy_grid_t& g) {
  if (!(g.resolution_m > 0) || !std::isfinite(g.resolution_m) || g.width < 0 || g.height < 0 ||
      static_cast<int64_t>(g.width) * g.height != g.num_cells)
    return MakeError(ErrorCode::kInvalidArgument,
                     "occupancy grid from '" + g.source + "': inconsistent size or resolution");
  // A map origin beyond 1000 km is no robot's map: refused like a non-finite one.
  if (!std::isfinite(g.origin_x_m) || !std::isfinite(g.origin_y_m) ||
      !std::isfinite(g.origin_yaw_rad) || std::abs(g.origin_x_m) > 1e6 ||
      std::abs(g.origin_y_m) > 1e6)
    return MakeError(ErrorCode::kInvalidArgument,
                     "occupancy grid from '" + g.source + "': non-finite or absurd origin");
  io::GridMap m;
  m.resolution_m = g.resolution_m;
  m.origin_x_m = g.origin_x_m;
  m.origin_y_m = g.origin_y_m;
  m.width = g.width;
  m.height = g.height;
  m.cells = g.cells;
  // A grid turned in its frame (origin_yaw_rad) is resampled onto the frame's axes.
  return io::AxisAligned(m, g.origin_yaw_rad);
}

}  // namespace omni::bus
