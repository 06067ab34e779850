#include "omni/pose_graph_mapper/pose_graph_node.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <limits>

#include <Eigen/Cholesky>

#include "omni/bus/convert.h"
#include "omni/common/log.h"
#include "omni/common/scan_checks.h"
#include "omni/heartbeat_t.hpp"
#include "omni/imu_t.hpp"
#include "omni/laser_scan_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/pose2d_t.hpp"
#include "omni/trajectory_t.hpp"

namespace omni::pgm {

PoseGraphNode::PoseGraphNode(bus::Bus* bus, const PoseGraphNodeOptions& node,
                             const PoseGraphSlamOptions& slam, const BatchOptions& batch,
                             const Clock* clock)
    : bus_(bus),
      o_(node),
      clock_(clock),
      slam_(slam, batch, clock),
      heartbeat_(bus, "pose_graph_mapper", clock) {
  bus_->Subscribe<omni::laser_scan_t>(
      o_.scan_channel, [this](const omni::laser_scan_t& m, int64_t) {
        if (m.seq > 0 && m.seq == seq_gaps_.newest() && m.utime == last_scan_utime_) {
          ++scans_duplicate_;  // the same scan again (a repeating driver or bridge): mapped once
          ++bus_->counters().drops;
          return;
        }
        last_scan_utime_ = m.utime;
        seq_gaps_.Add(m.seq);
        Item it;
        it.kind = Kind::kScan;
        it.utime = m.utime;
        it.scan.utime = m.utime;
        it.scan.laser_in_base = Pose2(m.sensor_x_m, m.sensor_y_m, m.sensor_yaw_rad);
        it.scan.angle_min_rad = m.angle_min_rad;
        it.scan.angle_increment_rad = m.angle_increment_rad;
        it.scan.min_range_m = m.range_min_m;
        it.scan.max_range_m = m.range_max_m;
        it.scan.ranges_m = m.ranges_m;
        it.scan.scan_time_s = bus::SweepTime(m.scan_time_s);
        OnMessage(std::move(it));
      });
  bus_->Subscribe<omni::odometry_t>(o_.odom_channel, [this](const omni::odometry_t& m, int64_t) {
    Item it;
    it.utime = m.utime;
    it.odom = odom_restarts_.Take(m.seq, Pose2(m.x_m, m.y_m, m.yaw_rad));
    OnMessage(std::move(it));
  });
  if (slam.use_gyro)
    // The gyro buffer is ordered by time on its own, so samples go straight in (no queue):
    // a scan waiting for odometry then finds the gyro ahead of it.
    bus_->Subscribe<omni::imu_t>(o_.imu_channel, [this](const omni::imu_t& m, int64_t) {
      (void)slam_.AddImuYawRate(m.utime, m.angular_velocity_rad_s[2]);
    });
  if (!o_.absolute_channel.empty())
    bus_->Subscribe<omni::pose2d_t>(o_.absolute_channel, [this](const omni::pose2d_t& m, int64_t) {
      if (!m.frame.empty() && m.frame != o_.map_frame) {
        ++absolute_wrong_frame_;
        return;
      }
      const Eigen::Matrix3d cov =
          Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(m.covariance);
      const Eigen::LLT<Eigen::Matrix3d> llt(cov);
      if (!cov.allFinite() || (cov - cov.transpose()).norm() > 1e-9 * cov.norm() ||
          llt.info() != Eigen::Success || !std::isfinite(m.x_m) || !std::isfinite(m.y_m) ||
          !std::isfinite(m.yaw_rad)) {
        ++absolute_bad_covariance_;
        return;
      }
      Item it;
      it.kind = Kind::kAbsolute;
      it.utime = m.utime;
      it.odom = Pose2(m.x_m, m.y_m, m.yaw_rad);
      it.information = llt.solve(Eigen::Matrix3d::Identity());
      it.information = 0.5 * (it.information + it.information.transpose()).eval();
      OnMessage(std::move(it));
    });

  const SlamCounters& c = slam_.counters();
  heartbeat_.AddCounter("scans_in", [&c] { return c.scans_in; });
  heartbeat_.AddCounter("scans_used", [&c] { return c.scans_used; });
  heartbeat_.AddCounter("scans_time_backwards", [&c] { return c.scans_time_backwards; });
  heartbeat_.AddCounter("scans_too_few_beams", [&c] { return c.scans_too_few_beams; });
  heartbeat_.AddCounter("scans_bad_geometry", [&c] { return c.scans_bad_geometry; });
  heartbeat_.AddCounter("scans_no_odom", [&c] { return c.scans_no_odom; });
  heartbeat_.AddCounter("invalid_beams", [&c] { return c.invalid_beams; });
  heartbeat_.AddCounter("sweeps_corrected", [&c] { return c.sweeps_corrected; });
  heartbeat_.AddCounter("sweeps_uncorrected", [&c] { return c.sweeps_uncorrected; });
  heartbeat_.AddCounter("odom_in", [&c] { return c.odom_in; });
  heartbeat_.AddCounter("odom_invalid", [&c] { return c.odom_invalid; });
  heartbeat_.AddCounter("odom_out_of_order", [&c] { return c.odom_out_of_order; });
  heartbeat_.AddCounter("odom_jumps", [&c] { return c.odom_jumps; });
  heartbeat_.AddCounter("odom_restarts", [this] { return odom_restarts_.restarts(); });
  heartbeat_.AddCounter("keyframes", [&c] { return c.keyframes; });
  heartbeat_.AddCounter("keyframes_retired", [&c] { return c.keyframes_retired; });
  heartbeat_.AddCounter("keyframes_removed", [&c] { return c.keyframes_removed; });
  heartbeat_.AddCounter("removals_refused", [&c] { return c.removals_refused; });
  heartbeat_.AddCounter("scan_match_factors", [&c] { return c.scan_match_factors; });
  heartbeat_.AddCounter("scan_match_failures", [&c] { return c.scan_match_failures; });
  heartbeat_.AddCounter("loops_accepted", [&c] { return c.loops_accepted; });
  heartbeat_.AddCounter("loops_rejected", [&c] { return c.loops_rejected; });
  heartbeat_.AddCounter("loops_inconsistent", [&c] { return c.loops_inconsistent; });
  heartbeat_.AddCounter("window_failures", [&c] { return c.window_failures; });
  heartbeat_.AddCounter("covariance_failures", [&c] { return c.covariance_failures; });
  heartbeat_.AddCounter("global_optimizations", [&c] { return c.global_optimizations; });
  heartbeat_.AddCounter("global_failures", [&c] { return c.global_failures; });
  heartbeat_.AddCounter("global_time_limited", [&c] { return c.global_time_limited; });
  if (slam.use_gyro) {
    heartbeat_.AddCounter("imu_in", [&c] { return c.imu_in; });
    heartbeat_.AddCounter("imu_rejected", [&c] { return c.imu_rejected; });
    heartbeat_.AddCounter("gyro_missing_steps",
                          [this] { return static_cast<int64_t>(slam_.gyro_missing_steps()); });
    heartbeat_.AddCounter("gyro_bias_samples", [&c] { return c.gyro_bias_samples; });
    heartbeat_.AddCounter("gyro_bias_refused", [&c] { return c.gyro_bias_refused; });
    heartbeat_.AddCounter("gyro_bias_uncovered", [&c] { return c.gyro_bias_uncovered; });
    heartbeat_.AddCounter("gyro_bias_urad_s", [this] {
      return static_cast<int64_t>(std::llround(slam_.gyro_bias_rad_s() * 1e6));
    });
  }
  if (slam.odometry_calibration.enabled) {
    // The odometry self-calibration: matches used / left out, refits, and the fit in ppm.
    for (auto& [name, read] : OdometryCalibrationCounters(slam_.odometry_calibrator()))
      heartbeat_.AddCounter(name, std::move(read));
  }
  heartbeat_.AddCounter("absolute_in", [&c] { return c.absolute_in; });
  heartbeat_.AddCounter("absolute_attached", [&c] { return c.absolute_attached; });
  heartbeat_.AddCounter("absolute_spliced", [&c] { return c.absolute_spliced; });
  heartbeat_.AddCounter("absolute_queued", [&c] { return c.absolute_queued; });
  heartbeat_.AddCounter("absolute_rejected", [&c] { return c.absolute_rejected; });
  heartbeat_.AddCounter("keyframes_for_absolute", [&c] { return c.keyframes_for_absolute; });
  heartbeat_.AddCounter("keyframes_for_odometry", [&c] { return c.keyframes_for_odometry; });
  heartbeat_.AddCounter("absolute_invalid", [&c] { return c.absolute_invalid; });
  heartbeat_.AddCounter("absolute_bad_covariance", [this] { return absolute_bad_covariance_; });
  heartbeat_.AddCounter("absolute_wrong_frame", [this] { return absolute_wrong_frame_; });
  heartbeat_.AddCounter("scans_lost", [this] { return seq_gaps_.lost(); });
  heartbeat_.AddCounter("scans_forced", [this] { return scans_forced_; });
  heartbeat_.AddCounter("time_rebases",
                        [this, &c] { return c.time_rebases + scan_order_.rebases(); });
  heartbeat_.AddCounter("clock_steps_back", [&c] { return c.clock_steps_back; });
  heartbeat_.AddCounter("scans_replayed", [&c] { return c.scans_replayed; });
  heartbeat_.AddCounter("scans_future_dropped", [this] { return scans_future_dropped_; });
  heartbeat_.AddCounter("scans_duplicate", [this] { return scans_duplicate_; });
  heartbeat_.AddCounter("poses_published", [this] { return poses_published_; });
  heartbeat_.AddCounter("grid_render_ms", [this] { return last_grid_render_us_ / 1000; });
  // The last global optimisation's duration (it grows with the graph), and how long the scans
  // behind it waited: in the background (slam.global_in_background), only for what was left of
  // it when the next keyframe came.
  auto last_ms = [](const std::vector<double>& v) {
    return v.empty() ? int64_t{0} : static_cast<int64_t>(std::llround(v.back()));
  };
  heartbeat_.AddCounter("global_ms",
                        [this, last_ms] { return last_ms(slam_.global_latency_ms()); });
  heartbeat_.AddCounter("global_wait_ms",
                        [this, last_ms] { return last_ms(slam_.global_wait_ms()); });
  // Poses in the last TRAJECTORY_PG (thinned, see bus::ThinTrajectoryMessage).
  heartbeat_.AddCounter("trajectory_poses", [this] { return last_trajectory_poses_; });
  heartbeat_.AddCounter("scans_queued", [this] { return static_cast<int64_t>(queued_scans_); });
  heartbeat_.AddCounter("max_scans_queued", [this] { return max_queued_scans_; });
  heartbeat_.SetState(omni::heartbeat_t::STATE_OK, "waiting for scans");
}

void PoseGraphNode::OnMessage(Item item) {
  // A stamp beyond +-2^61 us (tens of thousands of years: corrupt) goes straight to the mapper,
  // which refuses and counts it; queued, the waiting arithmetic on it would overflow.
  if (!StampInRange(item.utime)) {
    if (item.kind == Kind::kScan) HandleScan(item.scan);
    if (item.kind == Kind::kOdometry) slam_.AddOdometry(item.utime, item.odom);
    if (item.kind == Kind::kAbsolute)
      (void)slam_.AddAbsolutePose(item.utime, item.odom, item.information);
    return;
  }
  // Absolute poses may come late by design: they do not advance the time scans wait against.
  if (item.kind == Kind::kScan && scan_order_.Check(item.utime) == StampOrder::Verdict::kRebase) {
    // In-order scans older than the queue's newest keep coming: those newer than this one that
    // no odometry covers were stamped in the future and would hold the queue waiting for
    // odometry that never comes. (Covered ones are real: the clock went back behind them.) Only
    // odometry up to its own stream's newest counts: odometry stamped in the future with the
    // scan covers nothing.
    int64_t odom_reach = handed_odom_utime_;
    for (const Item& q : queue_)
      if (q.kind == Kind::kOdometry) odom_reach = std::max(odom_reach, q.utime);
    odom_reach = std::min(odom_reach, odom_order_.newest());
    // The scans queued when the odometry went back are the old clock's, to be handed over
    // (hand_waiting_), not dropped.
    const size_t before = queue_.size();
    size_t spared = hand_waiting_;
    std::deque<Item> kept;
    for (Item& q : queue_) {
      if (q.kind == Kind::kScan && spared > 0) {
        --spared;
      } else if (q.kind == Kind::kScan && q.utime > item.utime && q.utime > odom_reach) {
        continue;
      }
      kept.push_back(std::move(q));
    }
    queue_.swap(kept);
    const size_t dropped = before - queue_.size();
    queued_scans_ -= dropped;
    scans_future_dropped_ += static_cast<int64_t>(dropped);
    bus_->counters().drops += static_cast<int64_t>(dropped);
    if (dropped > 0) {
      LOG_WARN << dropped
               << " queued scan(s) stamped ahead of the scan stream dropped (time re-based)";
    }
  }
  // The mapper re-bases its own odometry; this keeps the staleness clock honest. A scan
  // waiting when the odometry goes back (a clock step) waits for samples that will not come on
  // its clock: the scans queued now are handed over as they are (the mapper poses them on the
  // odometry it has) instead of waiting to be dropped as stamped in the future.
  if (item.kind == Kind::kOdometry && odom_order_.Check(item.utime) == StampOrder::Verdict::kRebase)
    hand_waiting_ = queued_scans_;
  if (item.kind == Kind::kScan) {
    ++queued_scans_;
    max_queued_scans_ = std::max(max_queued_scans_, static_cast<int64_t>(queued_scans_));
  }
  queue_.push_back(std::move(item));
  // The mapper is far behind or odometry stopped: stay bounded by forcing the oldest scans.
  while (queued_scans_ > kMaxQueued || queue_.size() > kMaxQueuedItems) Drain(true, 1);
  if (!deferred_) Drain(false, INT32_MAX);
}

int PoseGraphNode::ProcessReady(int max_scans) { return Drain(false, max_scans); }

void PoseGraphNode::Flush() {
  Drain(true, INT32_MAX);
  slam_.Finish();
}

int PoseGraphNode::Drain(bool all, int max_scans) {
  const int64_t wait = static_cast<int64_t>(o_.max_odom_wait_s * 1e6);
  int done = 0;
  while (!queue_.empty() && done < max_scans) {
    if (queue_.front().kind == Kind::kOdometry) {
      HandOdometry(queue_.front());
      queue_.pop_front();
      continue;
    }
    if (queue_.front().kind == Kind::kAbsolute) {
      const Item& a = queue_.front();
      (void)slam_.AddAbsolutePose(a.utime, a.odom, a.information);
      queue_.pop_front();
      continue;
    }
    // Odometry up to the last beam, so a sweep can be corrected for the base's motion.
    const int64_t t = queue_.front().utime +
                      std::llround(static_cast<double>(queue_.front().scan.scan_time_s) * 1e6);
    // The scan is covered when odometry at or after its time was handed over, or is queued
    // behind it: then the odometry up to that one goes first, in arrival order.
    bool covered = handed_odom_utime_ >= t;
    if (!covered) {
      size_t reach = 1;
      while (reach < queue_.size() &&
             (queue_[reach].kind != Kind::kOdometry || queue_[reach].utime < t))
        ++reach;
      if (reach < queue_.size()) {
        std::deque<Item> rest;
        for (size_t i = 1; i < queue_.size(); ++i) {
          if (i <= reach && queue_[i].kind == Kind::kOdometry)
            HandOdometry(queue_[i]);
          else
            rest.push_back(std::move(queue_[i]));
        }
        rest.push_front(std::move(queue_.front()));
        queue_.swap(rest);
        covered = true;
      }
    }
    const bool stale = std::max(scan_order_.newest(), odom_order_.newest()) - t > wait;
    const bool odom_went_back = hand_waiting_ > 0;
    if (!covered && !stale && !all && !odom_went_back) break;
    if (!covered && !odom_went_back) ++scans_forced_;
    if (hand_waiting_ > 0) --hand_waiting_;
    HandleScan(queue_.front().scan);
    queue_.pop_front();
    --queued_scans_;
    ++done;
  }
  return done;
}

void PoseGraphNode::HandOdometry(const Item& odom) {
  const int64_t replayed = slam_.counters().scans_replayed;
  slam_.AddOdometry(odom.utime, odom.odom);
  handed_odom_utime_ = slam_.newest_odom_utime();  // moves back when the mapper re-bases
  // A clock step back proven: the scans the mapper held meanwhile are mapped now (the newest
  // one's pose goes out; the others are in the trajectory).
  if (slam_.counters().scans_replayed > replayed) PublishLastPose();
}

void PoseGraphNode::HandleScan(const LaserScan2& scan) {
  if (!slam_.AddScan(scan_index_++, scan)) {
    ++bus_->counters().drops;  // the reason is in the mapper's counters
    return;
  }
  PublishLastPose();
}

void PoseGraphNode::PublishLastPose() {
  ScanPose sp;
  Eigen::Matrix3d cov;
  if (!slam_.LastScanPose(&sp) || !slam_.LastScanCovariance(&cov)) return;
  omni::pose2d_t p{};
  p.utime = sp.utime;
  p.seq = pose_seq_++;
  p.frame = o_.map_frame;
  p.source = "posegraph";
  p.x_m = sp.pose.x;
  p.y_m = sp.pose.y;
  p.yaw_rad = sp.pose.theta;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) p.covariance[3 * r + c] = cov(r, c);
  if (bus_->Publish(o_.pose_channel, p)) ++poses_published_;
  if (!health_.degraded()) heartbeat_.SetState(omni::heartbeat_t::STATE_OK, "mapping");
}

void PoseGraphNode::PublishGrid() {
  const int64_t t0 = MonotonicMicros();
  io::LogOddsOptions g;
  g.resolution_m = o_.grid_resolution_m;
  const io::GridMap map = slam_.RenderMap(g);
  if (map.width == 0) return;
  if (bus::PublishGrid(*bus_, o_.grid_channel, map, clock_->NowUtime(), "posegraph"))
    ++grids_published_;
  last_grid_render_us_ = MonotonicMicros() - t0;
}

void PoseGraphNode::PublishTrajectory() {
  const std::vector<ScanPose> traj = slam_.Trajectory();
  if (traj.empty()) return;
  const omni::trajectory_t m = bus::ToTrajectoryMessage(traj, o_.map_frame, "posegraph");
  last_trajectory_poses_ = m.num_poses;
  if (bus_->Publish(o_.trajectory_channel, m)) ++trajectories_published_;
}

void PoseGraphNode::Tick() {
  const int64_t now = clock_->NowUtime();
  const auto& c = slam_.counters();
  health_.Report(now, c.scans_in, c.scans_no_odom, c.scans_too_few_beams + c.scans_bad_geometry,
                 &heartbeat_, "mapping");
  heartbeat_.Tick();
  const int64_t used = slam_.counters().scans_used;
  auto due = [&](double interval_s, int64_t last_wall, int64_t used_then, int64_t interval_us) {
    return interval_s > 0 && used > used_then && PeriodDue(now, last_wall, interval_us);
  };
  if (due(o_.trajectory_publish_interval_s, last_traj_wall_, used_at_last_traj_,
          static_cast<int64_t>(o_.trajectory_publish_interval_s * 1e6))) {
    PublishTrajectory();
    last_traj_wall_ = now;
    used_at_last_traj_ = used;
  }
  if (due(o_.grid_publish_interval_s, last_grid_wall_, used_at_last_grid_,
          GridIntervalUs(o_.grid_publish_interval_s, last_grid_render_us_))) {
    PublishGrid();
    last_grid_wall_ = now;
    used_at_last_grid_ = used;
  }
}

Status PoseGraphNode::WriteOutputs(const std::string& dir, SlamRunInfo info) {
  // As the RBPF's: the map so far first when scans are still queued (the flush and the final
  // optimisation can outlast the supervisor's grace period), and STOPPING in the last heartbeat.
  if (queued_scans_ > 0 && !slam_.keyframes().empty()) {
    if (Status early = SaveMaps(dir, info); !early.ok()) {
      LOG_WARN << "the map before the last " << queued_scans_
               << " queued scans: " << early.message();
    }
  }
  Flush();
  PublishTrajectory();
  PublishGrid();
  heartbeat_.SetState(omni::heartbeat_t::STATE_STOPPING, "writing map");
  heartbeat_.Tick(true);
  return SaveMaps(dir, std::move(info));
}

Status PoseGraphNode::SaveMaps(const std::string& dir, SlamRunInfo info) const {
  info.grid_resolution_m = o_.grid_resolution_m;
  info.decode_errors = bus_->counters().decode_errors.load();
  info.extra.emplace_back("scans_lost", seq_gaps_.lost());
  info.extra.emplace_back("scans_forced", scans_forced_);
  info.extra.emplace_back("max_scans_queued", max_queued_scans_);
  info.extra.emplace_back("poses_published", poses_published_);
  info.extra.emplace_back("grids_published", grids_published_);
  info.extra.emplace_back("trajectories_published", trajectories_published_);
  info.extra.emplace_back("last_trajectory_poses", last_trajectory_poses_);
  return WriteSlamOutputs(slam_, dir, info);
}

}  // namespace omni::pgm
