// Conversions between file-format records / library types and bus messages.
#pragma once

#include <string>
#include <vector>

#include "omni/io/carmen.h"
#include "omni/io/grid.h"
#include "omni/laser_scan_t.hpp"
#include "omni/occupancy_grid_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/trajectory_t.hpp"

namespace omni::bus {

// A CARMEN laser line as a scan: invalid readings (written as the maximum range) become NaN;
// the sensor pose in the base frame is the line's laser pose relative to its robot pose.
omni::laser_scan_t ToLaserScan(const io::CarmenLaser& laser, int64_t seq);
// A CARMEN ODOM line as odometry in the "odom" frame (velocities from tv/rv).
omni::odometry_t ToOdometry(const io::CarmenOdom& odom, int64_t seq);
// The grid as a message, its cells zlib-compressed (level 1) unless `raw`. An error, and no
// message, for a grid whose cells do not match its width x height or that holds more than
// io::kMaxGridCells cells, which no receiver would accept.
Result<omni::occupancy_grid_t> ToGridMessage(const io::GridMap& map, int64_t utime,
                                             const std::string& source, bool raw = false);
class Bus;
// Publishes `map` on `channel` as ToGridMessage's message in `frame`. A grid ToGridMessage refuses
// is not sent: it counts as a publish error in the bus counters (and so in the heartbeat) and is
// logged, the first time and every 100th. True when the message went out.
bool PublishGrid(Bus& bus, const std::string& channel, const io::GridMap& map, int64_t utime,
                 const std::string& source, const std::string& frame = "map");
// Rejects messages whose sizes disagree (also once inflated), whose encoding is unknown, whose
// zlib stream is corrupt, whose resolution is not positive and finite or whose origin is not
// finite, and grids over io::kMaxGridCells (2^28) cells, also once a grid turned in its frame
// (origin_yaw_rad) is resampled onto the frame's axes (io::AxisAligned).
Result<io::GridMap> FromGridMessage(const omni::occupancy_grid_t& msg);

// A whole trajectory as a message: `poses` in time order, each with `utime` (µs) and `pose`
// (a Pose2 in `frame`); the message's utime is the newest pose's. Empty `poses`: no poses, utime 0.
// A path of more than `max_poses` poses goes out as every k-th pose (k = ceil(n / max_poses)),
// the newest always included, so that hours of mapping do not make a message larger than a
// receive buffer (32 bytes a pose: 10 Hz scans grow a whole path by 1.15 MB an hour); receivers
// interpolate between poses. Of poses on one stamp only the last is sent.
inline constexpr size_t kMaxTrajectoryMessagePoses = 40000;  // 1.3 MB
template <class Stamped>
omni::trajectory_t ToTrajectoryMessage(const std::vector<Stamped>& poses, const std::string& frame,
                                       const std::string& source,
                                       size_t max_poses = kMaxTrajectoryMessagePoses) {
  omni::trajectory_t m;
  m.utime = poses.empty() ? 0 : poses.back().utime;
  m.frame = frame;
  m.source = source;
  const size_t n = poses.size();
  const size_t stride = max_poses == 0 || n <= max_poses ? 1 : (n + max_poses - 1) / max_poses;
  const size_t room = n / stride + 2;
  m.pose_utime.reserve(room);
  m.x_m.reserve(room);
  m.y_m.reserve(room);
  m.yaw_rad.reserve(room);
  for (size_t i = 0; i < n; ++i) {
    // Counted from the newest, so the newest pose is always one of those sent.
    if ((n - 1 - i) % stride != 0) continue;
    const auto& e = poses[i];
    if (!m.pose_utime.empty() && e.utime == m.pose_utime.back()) {  // the later one stays
      m.pose_utime.pop_back();
      m.x_m.pop_back();
      m.y_m.pop_back();
      m.yaw_rad.pop_back();
    }
    m.pose_utime.push_back(e.utime);
    m.x_m.push_back(e.pose.x);
    m.y_m.push_back(e.pose.y);
    m.yaw_rad.push_back(e.pose.theta);
  }
  m.num_poses = static_cast<int32_t>(m.pose_utime.size());
  return m;
}

// A laser_scan_t's sweep time as the mappers use it: the message's scan_time_s when it is a
// plausible revolution (finite, in (0, 1] s), else 0 (the scan is taken as one instant). A
// lidar slower than 1 Hz is not one of ours; a wild value must not overflow the time arithmetic.
inline float SweepTime(float scan_time_s) {
  return scan_time_s > 0.f && scan_time_s <= 1.f ? scan_time_s : 0.f;  // NaN compares false
}

}  // namespace omni::bus
