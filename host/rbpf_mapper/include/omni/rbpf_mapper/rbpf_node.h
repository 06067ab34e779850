// The rbpf_mapper node: bus I/O around the RbpfSlam library. Subscribes LIDAR_SCAN
// (laser_scan_t), WHEEL_ODOM (odometry_t) and IMU (imu_t, when use_imu), publishes POSE_RBPF
// (pose2d_t, the reported particle's pose at every accepted scan:
// RbpfOptions::report_switch_log_margin), GRID_RBPF (occupancy_grid_t, at grid_publish_interval_s),
// TRAJECTORY_RBPF (trajectory_t, the reported particle's path at every accepted scan, thinned by
// bus::ThinTrajectoryMessage, at trajectory_publish_interval_s and at exit: earlier poses move
// when a loop closes or the reported particle changes lineage) and HEARTBEAT with the filter's
// counters.
//
// Scans wait in a queue until odometry at or after their time has arrived (bus order is not
// guaranteed), or until they are older than max_odom_gap_s behind the newest message.
//
// Deferred mode (the process): the bus callbacks only queue, and the owner calls
// ProcessReady() between draining the socket, so a slow filter update never leaves datagrams
// to overflow the kernel's receive buffer; the queue (bounded by max_pending scans, beyond
// which the oldest is processed at once) absorbs bursts and the filter catches up.
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/bus/mapping_health.h"
#include "omni/common/odometry_restart.h"
#include "omni/common/seq_gaps.h"
#include "omni/common/time.h"
#include "omni/rbpf_mapper/rbpf.h"

namespace omni::rbpf {

class RbpfNode {
 public:
  RbpfNode(bus::Bus* bus, const RbpfOptions& options, const Clock* clock);
  // Heartbeat and periodic grid publication; call often (e.g. after every HandleTimeout).
  void Tick();
  // Processes every queued scan (end of input).
  void Flush();
  // Deferred mode: callbacks queue and return; ProcessReady() runs the filter.
  void set_deferred(bool deferred) { deferred_ = deferred; }
  // Processes up to `max_scans` queued scans whose odometry has arrived (or gone stale);
  // returns how many it processed.
  int ProcessReady(int max_scans);
  size_t pending() const { return pending_.size(); }
  int64_t max_pending_seen() const { return max_pending_seen_; }
  // Publishes the final grid and trajectory and writes DIR/map.{pgm,yaml,png} and
  // DIR/trajectory.txt.
  Status WriteOutputs(const std::string& dir);
  // The files WriteOutputs and SaveMaps write in their folder.
  static const std::vector<std::string>& OutputFiles() {
    static const std::vector<std::string> names = {"map.pgm", "map.yaml", "map.png",
                                                   "trajectory.txt"};
    return names;
  }
  // The same files, now, from the best particle as it stands (a map save request while
  // mapping: nothing is flushed, the filter goes on).
  Status SaveMaps(const std::string& dir) const;
  const RbpfSlam& slam() const { return slam_; }
  int64_t poses_published() const { return poses_published_; }
  int64_t grids_published() const { return grids_published_; }
  int64_t trajectories_published() const { return trajectories_published_; }
  int64_t scans_lost() const { return seq_gaps_.lost(); }
  bus::Heartbeat& heartbeat() { return heartbeat_; }

 private:
  void OnScan(const ScanInput& scan, int64_t seq);
  void Process(const ScanInput& scan);
  int Drain(bool all, int max_scans);
  void AttachOdometry();
  void PublishGrid();
  void PublishTrajectory();
  // The time stale scans are measured against: the newest scan or odometry stamp.
  int64_t NewestMessageUtime() const;

  bus::Bus* bus_;
  RbpfOptions opt_;
  const Clock* clock_;
  RbpfSlam slam_;
  RbpfSlam::MapMemory map_memory_;  // the heartbeat's map_* counters, counted once per beat
  bus::Heartbeat heartbeat_;
  MappingHealth health_;  // DEGRADED while scans come in without odometry
  std::deque<ScanInput> pending_;
  int64_t newest_odom_utime_ = INT64_MIN;
  // The scans' order: older ones are held, and five in order re-base it (stamp_order.h).
  HeldRun<ScanInput> scan_stream_;
  int64_t scans_future_dropped_ = 0;  // queued scans dropped by such a re-base
  int64_t last_scan_utime_ = INT64_MIN;
  int64_t scans_duplicate_ = 0;          // same seq and stamp as the scan before: dropped
  int64_t scans_late_ = 0;               // older than the newest scan on arrival (held, see OnScan)
  OdometryRestartBridge odom_restarts_;  // a restarted base bridge's odometry, laid on
  SeqGaps seq_gaps_;  // scans lost between the driver and us, from their sequence numbers
  int64_t poses_published_ = 0;
  int64_t poses_before_map_ = 0;  // scans placed before the first update: no POSE_RBPF for them
  int64_t grids_published_ = 0;
  int64_t last_grid_utime_ = 0;
  int64_t trajectories_published_ = 0;
  int64_t last_trajectory_poses_ = 0;  // poses in the last trajectory message (thinned)
  int64_t last_traj_utime_ = 0;
  int64_t processed_at_last_traj_ = 0;
  int64_t pose_seq_ = 0;
  bool deferred_ = false;
  int64_t max_pending_seen_ = 0;
  static constexpr size_t kMaxPending = 3000;
};

}  // namespace omni::rbpf
