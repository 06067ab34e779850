// Bus settings of the pose_graph_mapper process: the `node` section of
// config/pose_graph_mapper.yaml. Kept in the library (no LCM here) so that every reader of that
// file, the offline runner included, checks the section's keys the same way.
#pragma once

#include <string>

#include "omni/common/config.h"
#include "omni/common/result.h"

namespace omni::pgm {

struct PoseGraphNodeOptions {
  std::string scan_channel = "LIDAR_SCAN";
  std::string odom_channel = "WHEEL_ODOM";
  std::string pose_channel = "POSE_PG";
  std::string grid_channel = "GRID_PG";
  std::string trajectory_channel = "TRAJECTORY_PG";
  std::string map_frame = "map";
  // pose2d_t in: absolute (GPS-like) poses of the base in map_frame with their covariance,
  // attached or spliced into the graph (PoseGraphSlam::AddAbsolutePose). Empty: not subscribed.
  std::string absolute_channel;
  // imu_t in, subscribed when the slam section's gyro.enabled is true: the z angular rate.
  std::string imu_channel = "IMU";
  // Scans wait for odometry at or after their time; a scan this far behind the newest message
  // without it is handed to the mapper anyway (which then rejects it if no odometry is near).
  double max_odom_wait_s = 0.5;
  double grid_publish_interval_s = 5.0;        // GRID_PG at most this often (0: only at exit)
  double trajectory_publish_interval_s = 2.0;  // TRAJECTORY_PG at most this often (0: exit)
  double grid_resolution_m = 0.05;             // published and written grid

  // Reads the `node` section (Finish is the caller's).
  static Result<PoseGraphNodeOptions> Load(ConfigReader& r);
};

}  // namespace omni::pgm
