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

// How a trajectory is thinned before it goes on the bus. A pose is left out when the receivers'
// interpolation (linear in time between the poses kept around it, the heading along the shorter
// arc, as geometry.h's Interpolate) puts it within `tolerance_m` and `tolerance_rad` of where it
// is, and no two poses kept are more than `max_gap_us` apart unless the input already was (the
// OctoMap builder interpolates across at most its poser's max_pose_gap_s, 2 s by default; a
// receiver set below max_gap_us would stop re-posing inside the gaps). A point r metres from the
// base then lands within tolerance_m + r x tolerance_rad of where the full path puts it: 1.5 cm
// at 5 m by default. Which poses are kept can change from one message to the next as the
// estimate moves, so a receiver sees up to twice that between messages with no correction behind
// it (the OctoMap builder re-poses only for shifts over min_shift_m, 0.1 m by default).
struct TrajectoryThinning {
  double tolerance_m = 0.005;
  double tolerance_rad = 0.002;
  int64_t max_gap_us = 1000000;
};

// A mapper's path as a message holds at most this many poses: 32 bytes a pose, so 1.3 MB.
inline constexpr size_t kMaxTrajectoryMessagePoses = 40000;

// Thins `m`'s poses in place (they must be in time order with unique stamps; a step back in time
// is kept, never interpolated across; arrays of different lengths are left alone); the first and
// the newest always stay. A tolerance of zero or less keeps every pose; a max_gap_us of zero or
// less sets no gap limit. Past `max_poses` (0: no cap) the tolerances are doubled until the path
// fits (at most 8 times, up to 0.64 m and 0.64 rad); a path that cannot fit (one longer than
// max_poses x max_gap, or still too many poses) goes out as every k-th of the thinned poses with
// the first and the newest. Returns the number of tolerance doublings (0 when the first pass
// fitted), or -1 when the every-k-th fallback was needed. A pass costs about n x (poses per
// max_gap) / 2 interpolations: some 30 ms for 8 h of 10 Hz scans on this machine's cores.
int ThinTrajectoryMessage(omni::trajectory_t* m, const TrajectoryThinning& thinning,
                          size_t max_poses = kMaxTrajectoryMessagePoses);

// A whole trajectory as a message: `poses` in time order, each with `utime` (µs) and `pose`
// (a Pose2 in `frame`); the message's utime is the newest pose's. Empty `poses`: no poses, utime 0.
// Of poses on one stamp only the last is sent. The path is then thinned (ThinTrajectoryMessage),
// so that hours of mapping neither make a message larger than a receive buffer nor send a pose a
// receiver could interpolate: 10 Hz scans grow a whole path by 1.15 MB an hour; thinned at the
// defaults, the demo's simulator tour of the pose graph shrinks about 6.6-fold, the RBPF's,
// whose reported path jitters from scan to scan, about 3.5-fold.
template <class Stamped>
omni::trajectory_t ToTrajectoryMessage(const std::vector<Stamped>& poses, const std::string& frame,
                                       const std::string& source,
                                       const TrajectoryThinning& thinning = {},
                                       size_t max_poses = kMaxTrajectoryMessagePoses) {
  omni::trajectory_t m;
  m.utime = poses.empty() ? 0 : poses.back().utime;
  m.frame = frame;
  m.source = source;
  const size_t n = poses.size();
  m.pose_utime.reserve(n);
  m.x_m.reserve(n);
  m.y_m.reserve(n);
  m.yaw_rad.reserve(n);
  for (const auto& e : poses) {
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
  ThinTrajectoryMessage(&m, thinning, max_poses);
  return m;
}

// A laser_scan_t's sweep time as the mappers use it: the message's scan_time_s when it is a
// plausible revolution (finite, in (0, 1] s), else 0 (the scan is taken as one instant). A
// lidar slower than 1 Hz is not one of ours; a wild value must not overflow the time arithmetic.
inline float SweepTime(float scan_time_s) {
  return scan_time_s > 0.f && scan_time_s <= 1.f ? scan_time_s : 0.f;  // NaN compares false
}

}  // namespace omni::bus
