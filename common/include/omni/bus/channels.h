// Channel names of the omni bus (DESIGN.md). Processes take these as defaults and let the
// config override them, so two robots or two mapper variants can share one network.
#pragma once

namespace omni::channels {

inline constexpr const char* kLidarScan = "LIDAR_SCAN";            // omni.laser_scan_t
inline constexpr const char* kImu = "IMU";                         // omni.imu_t
inline constexpr const char* kDepth = "DEPTH";                     // omni.depth_image_t
inline constexpr const char* kColor = "RGB";                       // omni.color_image_t
inline constexpr const char* kWheelEncoders = "WHEEL_ENCODERS";    // omni.wheel_encoders_t
inline constexpr const char* kWheelOdom = "WHEEL_ODOM";            // omni.odometry_t
inline constexpr const char* kBaseCmd = "BASE_CMD";                // omni.base_cmd_t
inline constexpr const char* kBaseStatus = "BASE_STATUS";          // omni.base_status_t
inline constexpr const char* kPoseRbpf = "POSE_RBPF";              // omni.pose2d_t
inline constexpr const char* kGridRbpf = "GRID_RBPF";              // omni.occupancy_grid_t
inline constexpr const char* kTrajectoryRbpf = "TRAJECTORY_RBPF";  // omni.trajectory_t
inline constexpr const char* kPosePg = "POSE_PG";                  // omni.pose2d_t
inline constexpr const char* kGridPg = "GRID_PG";                  // omni.occupancy_grid_t
inline constexpr const char* kTrajectoryPg = "TRAJECTORY_PG";      // omni.trajectory_t
inline constexpr const char* kOctomap = "OCTOMAP";                 // omni.octomap_t
inline constexpr const char* kGridOcto = "GRID_OCTO";              // omni.occupancy_grid_t
inline constexpr const char* kGridFused = "GRID_FUSED";            // omni.occupancy_grid_t
inline constexpr const char* kGridOdom = "GRID_ODOM";   // omni.occupancy_grid_t (odometry-only map)
inline constexpr const char* kHeartbeat = "HEARTBEAT";  // omni.heartbeat_t

}  // namespace omni::channels
