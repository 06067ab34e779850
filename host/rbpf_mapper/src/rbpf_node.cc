#include "omni/rbpf_mapper/rbpf_node.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <limits>

#include "omni/bus/convert.h"
#include "omni/common/log.h"
#include "omni/common/scan_checks.h"
#include "omni/heartbeat_t.hpp"
#include "omni/imu_t.hpp"
#include "omni/io/grid.h"
#include "omni/io/image_io.h"
#include "omni/io/trajectory_io.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/pose2d_t.hpp"

namespace omni::rbpf {

RbpfNode::RbpfNode(bus::Bus* bus, const RbpfOptions& options, const Clock* clock)
    : bus_(bus),
      opt_(options),
      clock_(clock),
      slam_(options),
      heartbeat_(bus, "rbpf_mapper", clock) {
  bus_->Subscribe<omni::laser_scan_t>(
      opt_.scan_channel, [this](const omni::laser_scan_t& m, int64_t) {
        ScanInput s;
        s.utime = m.utime;
        s.sensor_in_base = Pose2(m.sensor_x_m, m.sensor_y_m, m.sensor_yaw_rad);
        s.angle_min_rad = m.angle_min_rad;
        s.angle_increment_rad = m.angle_increment_rad;
        s.range_min_m = m.range_min_m;
        s.range_max_m = m.range_max_m;
        s.ranges_m = m.ranges_m;
        s.scan_time_s = bus::SweepTime(m.scan_time_s);
        OnScan(s, m.seq);
      });
  bus_->Subscribe<omni::odometry_t>(opt_.odom_channel, [this](const omni::odometry_t& m, int64_t) {
    if (!slam_.AddOdometry(m.utime, odom_restarts_.Take(m.seq, Pose2(m.x_m, m.y_m, m.yaw_rad)))) {
      ++bus_->counters().drops;
    } else {
      // How far the odometry covers scans: not to a lone sample stamped far ahead (it moves
      // back when such a sample is dropped).
      newest_odom_utime_ = slam_.covered_odom_utime();
    }
    AttachOdometry();
    if (!deferred_) Drain(false, INT32_MAX);
  });
  if (opt_.use_imu) {
    bus_->Subscribe<omni::imu_t>(opt_.imu_channel, [this](const omni::imu_t& m, int64_t) {
      if (!slam_.AddImuYawRate(m.utime, m.angular_velocity_rad_s[2])) ++bus_->counters().drops;
    });
  }
  const RbpfCounters& c = slam_.counters();
  heartbeat_.AddCounter("scans_in", [&c] { return c.scans_in; });
  heartbeat_.AddCounter("scans_processed", [&c] { return c.scans_processed; });
  heartbeat_.AddCounter("scans_gated", [&c] { return c.scans_gated; });
  heartbeat_.AddCounter("scans_too_few_beams", [&c] { return c.scans_too_few_beams; });
  heartbeat_.AddCounter("scans_time_backwards", [&c] { return c.scans_time_backwards; });
  heartbeat_.AddCounter("time_rebases",
                        [this, &c] { return c.time_rebases + scan_stream_.order().rebases(); });
  heartbeat_.AddCounter("scans_future_dropped", [this] { return scans_future_dropped_; });
  heartbeat_.AddCounter("scans_duplicate", [this] { return scans_duplicate_; });
  heartbeat_.AddCounter("scans_late", [this] { return scans_late_; });
  heartbeat_.AddCounter("scans_no_odom", [&c] { return c.scans_no_odom; });
  heartbeat_.AddCounter("scans_bad_geometry", [&c] { return c.scans_bad_geometry; });
  heartbeat_.AddCounter("invalid_beams", [&c] { return c.invalid_beams; });
  heartbeat_.AddCounter("odom_invalid", [&c] { return c.odom_invalid; });
  heartbeat_.AddCounter("odom_out_of_order", [&c] { return c.odom_out_of_order; });
  heartbeat_.AddCounter("odom_jumps", [&c] { return c.odom_jumps; });
  heartbeat_.AddCounter("odom_restarts", [this] { return odom_restarts_.restarts(); });
  heartbeat_.AddCounter("imu_invalid", [&c] { return c.imu_invalid; });
  if (slam_.options().use_imu) {
    heartbeat_.AddCounter("imu_bias_samples", [&c] { return c.imu_bias_samples; });
    heartbeat_.AddCounter("imu_bias_refused", [&c] { return c.imu_bias_refused; });
    heartbeat_.AddCounter("imu_bias_uncovered", [&c] { return c.imu_bias_uncovered; });
    heartbeat_.AddCounter("imu_uncovered_updates", [&c] { return c.imu_uncovered_updates; });
    heartbeat_.AddCounter("imu_bias_urad_s", [this] {
      return static_cast<int64_t>(std::llround(slam_.imu_bias_rad_s() * 1e6));
    });
  }
  heartbeat_.AddCounter("match_failures", [&c] { return c.match_failures; });
  heartbeat_.AddCounter("match_searches", [&c] { return c.match_searches; });
  heartbeat_.AddCounter("resamplings", [&c] { return c.resamplings; });
  heartbeat_.AddCounter("reported_switches", [&c] { return c.reported_switches; });
  heartbeat_.AddCounter("sweeps_corrected", [&c] { return c.sweeps_corrected; });
  heartbeat_.AddCounter("sweeps_uncorrected", [&c] { return c.sweeps_uncorrected; });
  // The grid's cell size in use, and the scan spacing that chose it (0 until decided).
  heartbeat_.AddCounter("grid_cell_mm", [this] {
    return static_cast<int64_t>(std::llround(slam_.options().grid.resolution_m * 1000.0));
  });
  heartbeat_.AddCounter("scan_spacing_mm", [this] {
    const ResolutionChoice& ch = slam_.resolution_choice();
    return ch.decided ? static_cast<int64_t>(std::llround(ch.spacing_m() * 1000.0)) : 0;
  });
  heartbeat_.AddCounter("resolution_switched",
                        [this] { return slam_.resolution_choice().switched ? 1 : 0; });
  // The particles' maps in memory: distinct copy-on-write tiles (64 x 64 cells; 9.5 KiB, or
  // about 3 KiB packed), how many of them are packed, and their KiB. Counted once per heartbeat
  // (it sorts every particle's tile pointers): counters are read in the order they were added.
  heartbeat_.AddCounter("map_tiles", [this] {
    map_memory_ = slam_.map_memory();
    return static_cast<int64_t>(map_memory_.tiles);
  });
  heartbeat_.AddCounter("map_packed_tiles",
                        [this] { return static_cast<int64_t>(map_memory_.packed); });
  heartbeat_.AddCounter("map_kib",
                        [this] { return static_cast<int64_t>(map_memory_.bytes / 1024); });
  // The particles' paths (the trajectory tree) in memory, KiB.
  heartbeat_.AddCounter("path_kib",
                        [this] { return static_cast<int64_t>(slam_.path_memory().bytes / 1024); });
  if (slam_.options().odometry_calibration.enabled) {
    for (auto& [name, read] : OdometryCalibrationCounters(slam_.odometry_calibrator()))
      heartbeat_.AddCounter(name, std::move(read));
  }
  heartbeat_.AddCounter("scans_lost", [this] { return seq_gaps_.lost(); });
  // Poses in the last TRAJECTORY_RBPF (thinned, see bus::ThinTrajectoryMessage).
  heartbeat_.AddCounter("trajectory_poses", [this] { return last_trajectory_poses_; });
  heartbeat_.AddCounter("poses_published", [this] { return poses_published_; });
  heartbeat_.AddCounter("poses_before_map", [this] { return poses_before_map_; });
  heartbeat_.AddCounter("scans_queued", [this] { return static_cast<int64_t>(pending_.size()); });
  heartbeat_.AddCounter("max_scans_queued", [this] { return max_pending_seen_; });
  heartbeat_.SetState(omni::heartbeat_t::STATE_OK, "waiting for scans");
}

void RbpfNode::OnScan(const ScanInput& scan, int64_t seq) {
  if (seq > 0 && seq == seq_gaps_.newest() && scan.utime == last_scan_utime_) {
    ++scans_duplicate_;  // the same scan again (a repeating driver or bridge): mapped once
    ++bus_->counters().drops;
    return;
  }
  last_scan_utime_ = scan.utime;
  seq_gaps_.Add(seq);
  if (!StampInRange(scan.utime)) {
    // Corrupt: straight to the filter, which refuses and counts it; queued, the wait for its
    // odometry would overflow.
    Process(scan);
    return;
  }
  // A scan older than the newest is held: alone it is a late scan and is given up; five in
  // order re-base the stream and are all mapped.
  const auto rebase = [this, &scan](int64_t) {
    // In-order scans older than the queue's newest keep coming: those newer than this one that
    // no odometry covers were stamped in the future and would block the queue waiting for
    // odometry that never comes. (Covered ones are real: the clock went back behind them.)
    const size_t before = pending_.size();
    pending_.erase(
        std::remove_if(pending_.begin(), pending_.end(),
                       [&](const ScanInput& s) { return s.utime > scan.utime && !s.odom; }),
        pending_.end());
    scans_future_dropped_ += static_cast<int64_t>(before - pending_.size());
    bus_->counters().drops += static_cast<int64_t>(before - pending_.size());
    if (before > pending_.size()) {
      LOG_WARN << before - pending_.size()
               << " queued scan(s) stamped ahead of the scan stream dropped (time re-based)";
    }
    // What is queued from before goes first, with the odometry it has; then the filter takes
    // the stream from the held run on.
    Drain(true, INT32_MAX);
    slam_.RestartScanOrder();
  };
  const int64_t abandoned = scan_stream_.abandoned();
  const StampOrder::Verdict order = scan_stream_.Add(
      scan.utime, scan, rebase, [this](int64_t, ScanInput s) { pending_.push_back(std::move(s)); });
  bus_->counters().drops += scan_stream_.abandoned() - abandoned;
  if (order == StampOrder::Verdict::kOld) {
    ++scans_late_;
    return;
  }
  AttachOdometry();
  max_pending_seen_ = std::max(max_pending_seen_, static_cast<int64_t>(pending_.size()));
  while (pending_.size() > kMaxPending) {  // filter far behind or odometry stopped: stay bounded
    Process(pending_.front());
    pending_.pop_front();
  }
  if (!deferred_) Drain(false, INT32_MAX);
}

int64_t RbpfNode::NewestMessageUtime() const {
  return std::max(newest_odom_utime_, scan_stream_.order().newest());
}

int RbpfNode::ProcessReady(int max_scans) { return Drain(false, max_scans); }

void RbpfNode::AttachOdometry() {
  // Queued scans whose odometry has arrived get it now, as it stands on arrival: odometry that
  // comes later (possibly with the same stamp, as in logs with coarse clocks) must not move a
  // scan that was already covered. Scans are attached in order, so walk back from the newest.
  if (newest_odom_utime_ == INT64_MIN) return;
  size_t i = pending_.size();
  while (i > 0 && !pending_[i - 1].odom) --i;
  for (; i < pending_.size() && pending_[i].utime <= newest_odom_utime_; ++i)
    pending_[i].odom = slam_.RawOdometryAt(pending_[i].utime);
}

int RbpfNode::Drain(bool all, int max_scans) {
  const int64_t gap = static_cast<int64_t>(opt_.max_odom_gap_s * 1e6);
  int done = 0;
  while (!pending_.empty() && done < max_scans) {
    const ScanInput& s = pending_.front();
    // Odometry up to the last beam, so a sweep can be corrected for the base's motion.
    const int64_t last_beam = s.utime + std::llround(static_cast<double>(s.scan_time_s) * 1e6);
    const bool odom_ready = newest_odom_utime_ != INT64_MIN && newest_odom_utime_ >= last_beam;
    const bool stale = NewestMessageUtime() - s.utime > gap;
    if (!all && !odom_ready && !stale) break;
    Process(s);
    pending_.pop_front();
    ++done;
  }
  return done;
}

void RbpfNode::Process(const ScanInput& scan) {
  const bool was_decided = slam_.resolution_choice().decided;
  const ScanResult r = slam_.AddScan(scan);
  if (!was_decided && slam_.resolution_choice().decided) {
    const ResolutionChoice& ch = slam_.resolution_choice();
    LOG_INFO << "grid cells of " << slam_.options().grid.resolution_m << " m, likelihood gain "
             << slam_.options().likelihood_gain << ": " << ch.spacing_m()
             << " m of travel per moving scan over the first " << ch.travel_m << " m"
             << (ch.switched ? " (sparse scans: the scans so far were mapped again at this size)"
                             : "");
  }
  if (!r.accepted) {
    ++bus_->counters().drops;
    return;
  }
  if (!r.in_map_frame) {
    // Before the first filter update (the first scans had too few returns) the pose is the raw
    // odometry: published as "map" it sat where the odometry said, 12 m from the map's origin
    // after a drive, and the trajectory then put the same scans near the origin.
    ++poses_before_map_;
    return;
  }
  omni::pose2d_t p{};
  p.utime = scan.utime;
  p.seq = pose_seq_++;
  p.frame = "map";
  p.source = "rbpf";
  p.x_m = r.pose.x;
  p.y_m = r.pose.y;
  p.yaw_rad = r.pose.theta;
  // The particles' weighted spread about their weighted mean as the covariance (x, y, yaw).
  // Not about the published pose: for a scan between filter updates that is the reported
  // particle moved on by odometry, and a 0.2 rad turn since the update read as 0.04 rad^2 of
  // yaw variance with every particle agreeing (review finding).
  const auto& ps = slam_.particles();
  double max_lw = -std::numeric_limits<double>::infinity();
  for (const auto& q : ps) max_lw = std::max(max_lw, q.log_weight);
  double sw = 0, mx = 0, my = 0, ms = 0, mc = 0;
  for (const auto& q : ps) {
    const double w = std::isfinite(max_lw) ? std::exp(q.log_weight - max_lw) : 1.0;
    sw += w;
    mx += w * q.pose.x;
    my += w * q.pose.y;
    ms += w * std::sin(q.pose.theta);
    mc += w * std::cos(q.pose.theta);
  }
  mx /= sw;
  my /= sw;
  const double mt = std::atan2(ms, mc);
  double cxx = 0, cyy = 0, cxy = 0, ctt = 0;
  for (const auto& q : ps) {
    const double w = std::isfinite(max_lw) ? std::exp(q.log_weight - max_lw) : 1.0;
    const double dx = q.pose.x - mx, dy = q.pose.y - my, dt = WrapAngle(q.pose.theta - mt);
    cxx += w * dx * dx;
    cyy += w * dy * dy;
    cxy += w * dx * dy;
    ctt += w * dt * dt;
  }
  p.covariance[0] = cxx / sw;
  p.covariance[1] = p.covariance[3] = cxy / sw;
  p.covariance[4] = cyy / sw;
  p.covariance[8] = ctt / sw;
  if (bus_->Publish(opt_.pose_channel, p)) ++poses_published_;
  if (!health_.degraded()) heartbeat_.SetState(omni::heartbeat_t::STATE_OK, "mapping");
}

namespace {

// How many of the map's cells make one published cell (RbpfOptions::grid_publish_resolution_m).
int PublishFactor(double map_resolution_m, double publish_resolution_m) {
  if (!(publish_resolution_m > 0) || !(map_resolution_m < 0.75 * publish_resolution_m)) return 1;
  return std::max(1, static_cast<int>(std::lround(publish_resolution_m / map_resolution_m)));
}

}  // namespace

void RbpfNode::PublishGrid() {
  const io::GridMap map = slam_.ReportedMap();  // the map of the particle whose poses go out
  if (map.width == 0) return;
  const int factor = PublishFactor(map.resolution_m, opt_.grid_publish_resolution_m);
  const io::GridMap published = factor > 1 ? io::CoarsenGrid(map, factor) : map;
  if (bus::PublishGrid(*bus_, opt_.grid_channel, published, clock_->NowUtime(), "rbpf"))
    ++grids_published_;
}

void RbpfNode::PublishTrajectory() {
  const std::vector<EstimatedPose> traj = slam_.ReportedTrajectory();
  if (traj.empty()) return;
  const omni::trajectory_t m = bus::ToTrajectoryMessage(traj, "map", "rbpf");
  last_trajectory_poses_ = m.num_poses;
  if (bus_->Publish(opt_.trajectory_channel, m)) ++trajectories_published_;
}

void RbpfNode::Tick() {
  const int64_t now = clock_->NowUtime();
  const RbpfCounters& c = slam_.counters();
  health_.Report(now, c.scans_in, c.scans_no_odom, c.scans_too_few_beams + c.scans_bad_geometry,
                 &heartbeat_, "mapping");
  heartbeat_.Tick();
  if (slam_.counters().scans_processed > 0 &&
      PeriodDue(now, last_grid_utime_, static_cast<int64_t>(opt_.grid_publish_interval_s * 1e6))) {
    PublishGrid();
    last_grid_utime_ = now;
  }
  const int64_t processed = slam_.counters().scans_processed;
  if (opt_.trajectory_publish_interval_s > 0 && processed > processed_at_last_traj_ &&
      PeriodDue(now, last_traj_utime_,
                static_cast<int64_t>(opt_.trajectory_publish_interval_s * 1e6))) {
    PublishTrajectory();
    last_traj_utime_ = now;
    processed_at_last_traj_ = processed;
  }
}

void RbpfNode::Flush() { Drain(true, INT32_MAX); }

Status RbpfNode::WriteOutputs(const std::string& dir) {
  // Scans still queued at a stop can take longer to map than the supervisor waits before it
  // kills the process (3000 scans, seconds to a minute on two cores): the map so far is written
  // first, so that a kill during the flush leaves it, not nothing (or the previous run's).
  if (!pending_.empty() && slam_.counters().scans_processed > 0) {
    if (Status early = SaveMaps(dir); !early.ok()) {
      LOG_WARN << "the map before the last " << pending_.size()
               << " queued scans: " << early.message();
    }
  }
  Flush();
  PublishGrid();
  PublishTrajectory();
  // Each scan the flush mapped said "mapping": the process is stopping.
  heartbeat_.SetState(omni::heartbeat_t::STATE_STOPPING, "writing map");
  heartbeat_.Tick(true);
  return SaveMaps(dir);
}

Status RbpfNode::SaveMaps(const std::string& dir) const {
  const io::GridMap map = slam_.BestMap();
  if (map.width == 0)
    return MakeError(ErrorCode::kNotFound, "no scan was mapped: nothing to write to " + dir);
  Status s = io::WriteMapServer(map, dir + "/map");
  if (s.ok()) s = io::WritePng(dir + "/map.png", io::RenderGrid(map, {}, 1));
  std::vector<io::TrajectoryEntry> entries;
  for (const auto& e : slam_.BestTrajectory())
    entries.push_back(io::MakeEntry2D(e.scan_index, UtimeToSeconds(e.utime), e.pose));
  if (s.ok())
    s = io::WriteTrajectory2D(dir + "/trajectory.txt", entries,
                              "scan_index timestamp x y theta (RBPF best particle, final)");
  return s;
}

}  // namespace omni::rbpf
