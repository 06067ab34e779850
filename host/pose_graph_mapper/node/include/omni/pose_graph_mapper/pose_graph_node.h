// The pose_graph_mapper node: bus I/O around the PoseGraphSlam library. Subscribes LIDAR_SCAN
// (laser_scan_t) and WHEEL_ODOM (odometry_t); publishes POSE_PG (pose2d_t, the estimate of every
// accepted scan when it is accepted), TRAJECTORY_PG (trajectory_t, the accepted scans at the
// current optimised estimate, thinned by bus::ThinTrajectoryMessage: poses move when a loop
// closes), GRID_PG (occupancy_grid_t rendered
// from the optimised keyframes) and HEARTBEAT with the mapper's and the plugins' counters.
// With node.absolute_channel set it also subscribes absolute poses (pose2d_t in map_frame, the
// covariance's inverse as information); a covariance that is not finite, symmetric and positive
// definite, or another frame, is dropped and counted (absolute_bad_covariance,
// absolute_wrong_frame); the rest go to PoseGraphSlam::AddAbsolutePose in arrival order
// (queued with the scans and odometry, never reordered).
//
// Input order: messages are queued in arrival order. Odometry is handed to the mapper in that
// order; a scan waits until odometry at or after its time has arrived (then the odometry that
// arrived before it, plus what is needed to reach its time, is added first, so logs that stamp
// several messages with one time give each scan the odometry it arrived with), or until it is
// max_odom_wait_s behind the newest message, when the mapper decides with what it has.
//
// Deferred mode (the process): the bus callbacks only queue and the owner calls ProcessReady()
// between draining the socket, so a slow keyframe (matching, loop search, global optimisation)
// never leaves datagrams to overflow the kernel buffer. The queue is bounded (kMaxQueued scans,
// kMaxQueuedItems in all): beyond it the oldest scan is processed at once.
//
// POSE_PG's covariance: PoseGraphSlam::LastScanCovariance (the window's marginal of the scan's
// keyframe composed with the odometry since it).
#pragma once

#include <algorithm>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/bus/mapping_health.h"
#include "omni/common/odometry_restart.h"
#include "omni/common/seq_gaps.h"
#include "omni/common/time.h"
#include "omni/pose_graph_mapper/node_options.h"
#include "omni/pose_graph_mapper/pose_graph_slam.h"
#include "omni/pose_graph_mapper/slam_outputs.h"

namespace omni::pgm {

class PoseGraphNode {
 public:
  PoseGraphNode(bus::Bus* bus, const PoseGraphNodeOptions& node, const PoseGraphSlamOptions& slam,
                const BatchOptions& batch, const Clock* clock);

  // Heartbeat and the periodic grid and trajectory publications; call often.
  void Tick();
  void set_deferred(bool deferred) { deferred_ = deferred; }
  // Handles queued messages until `max_scans` scans were given to the mapper or nothing more is
  // ready; returns the number of scans handled.
  int ProcessReady(int max_scans);
  // End of input: every queued message is handed to the mapper and pending loops are optimised.
  void Flush();
  // Flush, publish the final grid and trajectory, write DIR/{trajectory.txt, map.*, graph.g2o,
  // stats.json}.
  Status WriteOutputs(const std::string& dir, SlamRunInfo info);
  // The files WriteOutputs and SaveMaps write in their folder.
  static const std::vector<std::string>& OutputFiles() {
    static const std::vector<std::string> names = {
        "trajectory.txt",     "map.pgm",   "map.yaml",  "map.png",
        "map_trajectory.png", "graph.g2o", "stats.json"};
    return names;
  }
  // The same files, now, at the current optimised estimate (a map save request while mapping:
  // nothing is flushed and no final optimisation runs; the mapper goes on).
  Status SaveMaps(const std::string& dir, SlamRunInfo info) const;

  const PoseGraphSlam& slam() const { return slam_; }
  bus::Heartbeat& heartbeat() { return heartbeat_; }
  size_t queued_scans() const { return queued_scans_; }
  size_t queued_items() const { return queue_.size(); }
  int64_t max_queued_scans() const { return max_queued_scans_; }
  int64_t scans_lost() const { return seq_gaps_.lost(); }
  int64_t poses_published() const { return poses_published_; }
  int64_t grids_published() const { return grids_published_; }
  int64_t trajectories_published() const { return trajectories_published_; }
  int64_t scans_forced() const { return scans_forced_; }
  int64_t scans_future_dropped() const { return scans_future_dropped_; }
  int64_t absolute_bad_covariance() const { return absolute_bad_covariance_; }
  int64_t absolute_wrong_frame() const { return absolute_wrong_frame_; }

  static constexpr size_t kMaxQueued = 3000;  // scans
  // Everything queued (odometry and absolute poses too): odometry older than a waiting scan
  // piled up behind it without bound when the scan's time was never reached (a lidar clock
  // ahead of the base's, then the lidar stopped).
  static constexpr size_t kMaxQueuedItems = 32768;
  // The grid is rendered from every keyframe, so its cost grows with the run (about 2 s per
  // render after an 8 h shift): the wait between grid messages is at least this many times the
  // last render's duration, which keeps rendering to a tenth of the node's time.
  static constexpr double kGridRenderShare = 10.0;
  static int64_t GridIntervalUs(double configured_s, int64_t last_render_us) {
    return std::max(static_cast<int64_t>(configured_s * 1e6),
                    static_cast<int64_t>(kGridRenderShare * static_cast<double>(last_render_us)));
  }
  int64_t last_grid_render_us() const { return last_grid_render_us_; }

 private:
  enum class Kind { kOdometry, kScan, kAbsolute };
  struct Item {
    Kind kind = Kind::kOdometry;
    int64_t utime = 0;
    Pose2 odom;  // odometry item; the pose of an absolute item
    Eigen::Matrix3d information = Eigen::Matrix3d::Zero();  // absolute item
    LaserScan2 scan;                                        // scan item
  };
  void OnMessage(Item item);
  int Drain(bool all, int max_scans);
  void HandOdometry(const Item& odom);
  void HandleScan(const LaserScan2& scan);
  void PublishLastPose();  // the mapper's newest scan pose on the pose channel
  void PublishGrid();
  void PublishTrajectory();

  bus::Bus* bus_;
  PoseGraphNodeOptions o_;
  const Clock* clock_;
  PoseGraphSlam slam_;
  bus::Heartbeat heartbeat_;
  MappingHealth health_;  // DEGRADED while scans come in without odometry
  std::deque<Item> queue_;
  size_t queued_scans_ = 0;
  int64_t max_queued_scans_ = 0;
  // Newest scan and odometry stamps (stale scans are measured against them), re-based when a
  // message stamped in the future is followed by in-order ones (common/stamp_order.h).
  StampOrder scan_order_, odom_order_;
  int64_t scans_future_dropped_ = 0;  // queued scans dropped by such a re-base
  size_t hand_waiting_ = 0;  // scans queued when the odometry re-based: handed, not waited for
  int64_t last_scan_utime_ = INT64_MIN;
  int64_t scans_duplicate_ = 0;            // same seq and stamp as the scan before: dropped
  int64_t handed_odom_utime_ = INT64_MIN;  // newest odometry given to the mapper
  OdometryRestartBridge odom_restarts_;    // a restarted base bridge's odometry, laid on
  SeqGaps seq_gaps_;  // scans lost between the driver and us, from their sequence numbers
  int64_t scan_index_ = 0;
  int64_t scans_forced_ = 0;
  int64_t poses_published_ = 0, grids_published_ = 0, trajectories_published_ = 0;
  int64_t last_trajectory_poses_ = 0;  // poses in the last trajectory message (thinned)
  int64_t pose_seq_ = 0;
  int64_t absolute_bad_covariance_ = 0, absolute_wrong_frame_ = 0;
  int64_t last_grid_wall_ = 0, last_traj_wall_ = 0;
  int64_t last_grid_render_us_ = 0;  // monotonic time the last grid took to render and send
  int64_t used_at_last_grid_ = 0, used_at_last_traj_ = 0;
  bool deferred_ = false;
};

}  // namespace omni::pgm
