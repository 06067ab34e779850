#include "omni/pose_graph_mapper/pose_graph_slam.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <future>
#include <iterator>
#include <limits>
#include <optional>
#include <system_error>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "omni/common/log.h"
#include "omni/common/scan_checks.h"
#include "omni/pose_graph_mapper/chi2.h"
#include "omni/pose_graph_mapper/lie.h"
#include "omni/pose_graph_mapper/node_removal.h"

namespace omni::pgm {
namespace {

// Stamps beyond +-73,000 years (us) are corrupt: refused, so that no sum of a stamp and the
// time line's offset (at most twice this, AddOdometry) can overflow.
constexpr int64_t kMaxStamp = kMaxStampUs;  // StampInRange (scan_checks.h)

// Anchors the window's oldest pose (1 mm, 1 mrad): the global solution places the window.
Eigen::Matrix3d AnchorInformation() { return 1e6 * Eigen::Matrix3d::Identity(); }

// Information of a continuous-source factor (a tiny floor keeps a standstill's zero covariance
// invertible).
Eigen::Matrix3d MotionInformation(const RelativeMotion& m) {
  return RelativeInformation(m.delta, m.covariance, 1e-9);
}

}  // namespace

Result<PoseGraphSlamOptions> PoseGraphSlamOptions::Load(ConfigReader& r) {
  PoseGraphSlamOptions o;
  r.Get("keyframe_distance_m", &o.keyframe_distance_m, Optional(), Positive<double>());
  r.Get("keyframe_angle_rad", &o.keyframe_angle_rad, Optional(), Positive<double>());
  r.Get("window_size", &o.window_size, Optional(), InRange(2, 100000));
  r.Get("window_max_iterations", &o.window_max_iterations, Optional(), InRange(1, 1000));
  r.Get("min_beams", &o.min_beams, Optional(), InRange(1, 100000));
  r.Get("max_odom_jump_m", &o.max_odom_jump_m, Optional(), Positive<double>());
  r.Get("max_odom_jump_rad", &o.max_odom_jump_rad, Optional(), Positive<double>());
  r.Get("max_scan_odom_gap_s", &o.max_scan_odom_gap_s, Optional(), NonNegative<double>());
  r.Get("absolute_max_wait_s", &o.absolute_max_wait_s, Optional(), InRange(0.0, 3600.0));
  ConfigReader n = r.Section("odometry_noise");
  n.Get("xy_var_per_m", &o.odometry_noise.xy_var_per_m, Optional(), NonNegative<double>());
  n.Get("xy_var_per_rad", &o.odometry_noise.xy_var_per_rad, Optional(), NonNegative<double>());
  n.Get("theta_var_per_m", &o.odometry_noise.theta_var_per_m, Optional(), NonNegative<double>());
  n.Get("theta_var_per_rad", &o.odometry_noise.theta_var_per_rad, Optional(),
        NonNegative<double>());
  n.Get("xy_var_per_s", &o.odometry_noise.xy_var_per_s, Optional(), Positive<double>());
  n.Get("theta_var_per_s", &o.odometry_noise.theta_var_per_s, Optional(), Positive<double>());
  r.Get("scan_match_information_scale", &o.scan_match_information_scale, Optional(),
        Positive<double>());
  ConfigReader g = r.Section("gyro");
  g.Get("enabled", &o.use_gyro, Optional());
  g.Get("angle_var_per_s", &o.gyro_noise.angle_var_per_s, Optional(), Positive<double>());
  g.Get("angle_var_per_rad", &o.gyro_noise.angle_var_per_rad, Optional(), NonNegative<double>());
  g.Get("bias_rad_s", &o.gyro_bias_rad_s, Optional());
  ReadGyroBiasOptions(g.Section("bias_learning"), &o.gyro_bias);
  r.Get("global_loss", &o.global_loss, Optional(), OneOf({"none", "huber", "cauchy"}));
  r.Get("global_loss_scale", &o.global_loss_scale, Optional(), Positive<double>());
  r.Get("global_max_iterations", &o.global_max_iterations, Optional(), InRange(1, 10000));
  r.Get("global_function_tolerance", &o.global_function_tolerance, Optional(), Positive<double>());
  r.Get("global_min_keyframes_between", &o.global_min_keyframes_between, Optional(),
        InRange(0, 100000));
  r.Get("global_max_time_s", &o.global_max_time_s, Optional(), NonNegative<double>());
  r.Get("global_in_background", &o.global_in_background, Optional());
  r.Get("loop_chi2_gate", &o.loop_chi2_gate, Optional(), NonNegative<double>());
  r.Get("loop_every_keyframes", &o.loop_every_keyframes, Optional(), InRange(1, 100000));
  r.Get("final_global_optimization", &o.final_global_optimization, Optional());
  r.Get("interpolate_scan_poses", &o.interpolate_scan_poses, Optional());
  r.Get("loop_cooldown_keyframes", &o.loop_cooldown_keyframes, Optional(), InRange(0, 100000));
  r.Get("num_threads", &o.num_threads, Optional(), InRange(1, 64));
  ConfigReader rt = r.Section("retire");
  rt.Get("enabled", &o.retire.enabled, Optional());
  rt.Get("distance_m", &o.retire.distance_m, Optional(), NonNegative<double>());
  rt.Get("angle_rad", &o.retire.angle_rad, Optional(), InRange(0.0, 3.15));
  rt.Get("loop_reach_keyframes", &o.retire.loop_reach_keyframes, Optional(), InRange(0, 1000));
  rt.Get("delay_keyframes", &o.retire.delay_keyframes, Optional(), InRange(1, 100000));
  rt.Get("remove_poses", &o.retire.remove_poses, Optional());
  ConfigReader m = r.Section("scan_match");
  m.Get("submap_keyframes", &o.match.submap_keyframes, Optional(), InRange(1, 100));
  m.Get("min_score", &o.match.min_score, Optional(), InRange(0.0, 1.0));
  m.Get("min_inlier_fraction", &o.match.min_inlier_fraction, Optional(), InRange(0.0, 1.0));
  m.Get("fill_gap_m", &o.match.fill_gap_m, Optional(), NonNegative<double>());
  m.Get("max_range_m", &o.match.max_range_m, Optional(), InRange(1.0, 1000.0));
  m.Get("reject_window_edge", &o.match.reject_window_edge, Optional());
  m.Get("field_resolution_m", &o.match.field.resolution_m, Optional(), InRange(0.01, 0.2));
  m.Get("cubic_polish", &o.match.window.cubic_polish, Optional());
  m.Get("icp_polish", &o.match.window.icp_polish, Optional());
  m.Get("icp_pair_m", &o.match.window.icp_pair_m, Optional(), Positive<double>());
  ConfigReader oc = r.Section("odometry_calibration");
  ReadOdometryCalibratorOptions(oc, &o.odometry_calibration);
  ConfigReader l = r.Section("loop_closure");
  l.Get("min_index_gap", &o.loop.min_index_gap, Optional(), InRange(1, 1000000));
  l.Get("search_radius_m", &o.loop.search_radius_m, Optional(), Positive<double>());
  l.Get("window_growth_per_m", &o.loop.window_growth_per_m, Optional(), NonNegative<double>());
  l.Get("max_window_m", &o.loop.max_window_m, Optional(), Positive<double>());
  l.Get("fill_gap_m", &o.loop.fill_gap_m, Optional(), NonNegative<double>());
  l.Get("max_range_m", &o.loop.max_range_m, Optional(), InRange(1.0, 1000.0));
  l.Get("submap_half_width", &o.loop.submap_half_width, Optional(), InRange(0, 1000));
  l.Get("max_candidates", &o.loop.max_candidates, Optional(), InRange(1, 100));
  l.Get("min_score", &o.loop.min_score, Optional(), InRange(0.0, 1.0));
  l.Get("min_inlier_fraction", &o.loop.min_inlier_fraction, Optional(), InRange(0.0, 1.0));
  l.Get("max_ambiguity_ratio", &o.loop.max_ambiguity_ratio, Optional(), InRange(0.0, 1.0));
  l.Get("cubic_polish", &o.loop.window.cubic_polish, Optional());
  l.Get("field_cache_size", &o.loop.field_cache_size, Optional(), InRange(0, 1000));
  l.Get("num_threads", &o.loop.num_threads, Optional(), InRange(1, 64));
  return o;
}

Status PoseGraphSlamOptions::Validate() const {
  if (!(keyframe_distance_m > 0) || !(keyframe_angle_rad > 0))
    return MakeError(ErrorCode::kOutOfRange, "keyframe_distance_m/keyframe_angle_rad must be > 0");
  if (window_size < 2) return MakeError(ErrorCode::kOutOfRange, "window_size must be >= 2");
  if (loop.min_index_gap < window_size)
    return MakeError(ErrorCode::kOutOfRange,
                     "loop_closure.min_index_gap must be >= window_size (loops close outside "
                     "the window)");
  if (min_beams < 1) return MakeError(ErrorCode::kOutOfRange, "min_beams must be >= 1");
  if (num_threads < 1) return MakeError(ErrorCode::kOutOfRange, "num_threads must be >= 1");
  if (!(global_max_time_s >= 0))
    return MakeError(ErrorCode::kOutOfRange, "global_max_time_s must be >= 0 (0: no limit)");
  if (!(loop_chi2_gate >= 0))
    return MakeError(ErrorCode::kOutOfRange, "loop_chi2_gate must be >= 0 (0 disables it)");
  if (!(global_function_tolerance > 0))
    return MakeError(ErrorCode::kOutOfRange, "global_function_tolerance must be > 0");
  if (retire.enabled && (retire.delay_keyframes <= match.submap_keyframes ||
                         retire.delay_keyframes < retire.loop_reach_keyframes))
    return MakeError(ErrorCode::kOutOfRange,
                     "retire.delay_keyframes must be > scan_match.submap_keyframes (the keyframe "
                     "matcher's submap) and >= retire.loop_reach_keyframes");
  return Status::Ok();
}

Status LoadSlamConfigFile(const std::string& path, PoseGraphSlamOptions* slam, BatchOptions* batch,
                          PoseGraphNodeOptions* node) {
  auto r = ConfigReader::FromFile(path);
  if (!r.ok()) return r.error();
  return LoadSlamConfig(*r, slam, batch, node);
}

Status LoadSlamConfig(ConfigReader& r, PoseGraphSlamOptions* slam, BatchOptions* batch,
                      PoseGraphNodeOptions* node) {
  ConfigReader b = r.Section("batch");
  auto bo = BatchOptions::Load(b);
  ConfigReader s = r.Section("slam");
  auto so = PoseGraphSlamOptions::Load(s);
  ConfigReader n = r.Section("node");
  auto no = PoseGraphNodeOptions::Load(n);
  if (Status st = r.Finish(); !st.ok()) return st;
  if (!bo.ok()) return bo.error();
  if (!so.ok()) return so.error();
  if (!no.ok()) return no.error();
  *batch = *bo;
  *slam = *so;
  if (node) *node = *no;
  return slam->Validate();
}

PoseGraphSlam::PoseGraphSlam(const PoseGraphSlamOptions& options, const BatchOptions& batch,
                             const Clock* clock)
    : o_(options),
      batch_(batch),
      clock_(clock),
      odom_(options.odometry_noise, std::max<size_t>(options.odometry_buffer_samples, 16)),
      calibrator_(options.odometry_calibration),
      gyro_(options.gyro_noise, options.gyro_bias_rad_s),
      gyro_bias_(options.gyro_bias, options.gyro_bias_rad_s),
      match_(options.match),
      loop_(options.loop) {
  ResetWindow();
}

double PoseGraphSlam::NowMs() const {
  return clock_ ? static_cast<double>(clock_->NowUtime()) * 1e-3 : 0.0;
}

void PoseGraphSlam::AddOdometry(int64_t utime, const Pose2& raw) {
  ++c_.odom_in;
  if (!PlausibleOdometryPose(raw)) {
    ++c_.odom_invalid;
    return;
  }
  if (!StampInRange(utime)) {
    ++c_.odom_invalid;
    return;
  }
  // Older samples are held; a run of them re-bases the stream (RebaseOdometry).
  const auto rebase = [this](int64_t first) { RebaseOdometry(first); };
  const auto take = [this](int64_t t, const Pose2& p) { TakeOdometry(t, p); };
  if (odom_stream_.Add(utime, raw, rebase, take) == StampOrder::Verdict::kOld)
    ++c_.odom_out_of_order;
  if (odom_stream_.order().run_length() > 0) return;  // a run still open: nothing decided
  // The run re-based or broke: the clock of what waited on it is known now.
  std::vector<HeldScan> held;
  held.swap(held_scans_);
  if (replay_held_scans_) {
    // The scans that came with the new clock before the step was proven are covered now. Held
    // scans all came after the last in-order sample (which drops what is held); of those, the
    // new clock's are stamped from about the run's first sample to its last: a scan that came
    // late on the old clock (stamped above the run unless the step was smaller than its
    // lateness) is not replayed.
    replay_held_scans_ = false;
    const int64_t gap_us = static_cast<int64_t>(o_.max_scan_odom_gap_s * 1e6);
    const int64_t slack_us = 2 * std::clamp<int64_t>(last_odom_period_us_, 1000, 1000000);
    held.erase(std::remove_if(held.begin(), held.end(),
                              [&](const HeldScan& h) {
                                return h.scan.utime < step_run_first_ - gap_us ||
                                       h.scan.utime > last_odom_utime_ + slack_us;
                              }),
               held.end());
    std::stable_sort(held.begin(), held.end(), [](const HeldScan& a, const HeldScan& b) {
      return a.scan.utime < b.scan.utime;
    });
    replaying_ = true;
    for (const HeldScan& h : held)
      if (AcceptScan(h.index, h.scan)) ++c_.scans_replayed;
    replaying_ = false;
  }  // else they were late for good (counted scans_time_backwards)
  PlaceHeldFixes();
}

void PoseGraphSlam::PlaceHeldFixes() {
  std::vector<HeldAbsolute> fixes;
  fixes.swap(held_absolute_);
  for (const HeldAbsolute& f : fixes) (void)PlaceAbsolute(f.utime, f.z, f.information, false);
}

bool PoseGraphSlam::CoveredBesideTheRun(int64_t su, int64_t gap_us) const {
  // The samples the open run would drop are in doubt, unless there are as many of them as a
  // run needs to re-base (then they are a stream too: the old clock's, if it went back). A scan
  // near them is covered when they are that many, else only by the newest sample before them.
  const StateHistory<OdomState>::Split split =
      odom_history_.SplitAt(OnTimeLine(odom_stream_.order().run_first()));
  if (split.count >= static_cast<size_t>(StampOrder::kDefaultRebaseAfter)) return true;
  return split.newest_kept && su - *split.newest_kept <= gap_us;
}

int64_t PoseGraphSlam::OnTimeLine(int64_t utime) const {
  int64_t t = 0;
  if (__builtin_add_overflow(utime, time_offset_, &t))
    return time_offset_ > 0 ? std::numeric_limits<int64_t>::max()
                            : std::numeric_limits<int64_t>::min();
  return t;
}

void PoseGraphSlam::RebaseOdometry(int64_t first) {
  ++c_.time_rebases;
  const int64_t at = OnTimeLine(first);
  // A mapped scan is at or after the oldest sample the run would drop, so it stands on them:
  // they were real, and the source's clock went back (an NTP step, a reboot; or a future stamp
  // already mapped with its scan, which then stays). (A scan merely interpolated towards a
  // future sample is older than it: that sample is dropped as below.) Nothing is dropped: from
  // now on stamps are shifted so the run starts one odometry period after the newest sample,
  // and the keyframes, odometry and loops keep their times. The gyro's samples were on the old
  // clock and it restarts; scans that came with the new clock before this was proven are
  // replayed. Inputs are within +-kMaxStamp and a step needs the time line below it, so the
  // offset stays below 2 kMaxStamp + 1 s.
  // (When it would drop every sample remembered, older ones may be forgotten: any scan at or
  // after the run's start then counts.)
  const StateHistory<OdomState>::Split split = odom_history_.SplitAt(at);
  const bool stands = split.all ? last_scan_utime_ >= at
                                : split.oldest_dropped && last_scan_utime_ >= *split.oldest_dropped;
  if (have_odom_ && stands && last_odom_internal_ < kMaxStamp) {
    ++c_.clock_steps_back;
    step_run_first_ = first;
    const int64_t period = std::clamp<int64_t>(last_odom_period_us_, 1000, 1000000);
    prev_time_offset_ = time_offset_;
    old_clock_newest_ = last_odom_utime_;
    time_offset_ = last_odom_internal_ + period - first;
    gyro_.Reset();
    gyro_bias_.Reset();
    replay_held_scans_ = true;
    return;
  }
  // Otherwise the newest samples were stamped ahead of the run: they are dropped and the state
  // is put back as it was after the newest sample kept.
  gyro_bias_.Reset();  // its still stretch may stand on samples dropped here
  const std::optional<OdomState> st = odom_history_.Restore(at);
  // Kept: drop what came after it (by internal time, which nudging may have moved past `at`);
  // none kept: every sample held is newer than the run.
  const bool kept = st && st->stamp < at;
  odom_.DropFrom(kept ? st->internal + 1 : std::numeric_limits<int64_t>::min());
  have_odom_ = kept;
  if (st) {  // the newest dropped one when none is kept: jumps stay bridged across
    last_odom_utime_ = st->received;
    last_odom_stamp_ = st->stamp;
    last_odom_internal_ = st->internal;
    last_raw_ = st->raw;
    last_corrected_ = st->corrected;
    correction_ = st->correction;
  }
}

void PoseGraphSlam::TakeOdometry(int64_t utime, const Pose2& raw) {
  const int64_t stamp = OnTimeLine(utime);
  const int64_t internal = have_odom_ ? std::max(stamp, last_odom_internal_ + 1) : stamp;
  if (have_odom_) last_odom_period_us_ = internal - last_odom_internal_;
  if (have_odom_) {
    const Pose2 step = last_raw_.Between(raw);
    if (std::hypot(step.x, step.y) > o_.max_odom_jump_m ||
        std::abs(step.theta) > o_.max_odom_jump_rad) {
      // A jump (reset or glitch): continue from the last good pose as if the robot stood still.
      ++c_.odom_jumps;
      correction_ = last_corrected_ * raw.Inverse();
    }
  }
  const Pose2 corrected = correction_ * raw;
  odom_.AddSample(internal, corrected);
  if (o_.use_gyro && gyro_bias_.AddOdometry(internal, corrected, [this](int64_t a, int64_t b) {
        return gyro_.RawBetween(a, b);
      }))
    gyro_.set_bias(gyro_bias_.bias());
  c_.gyro_bias_samples = gyro_bias_.samples();
  c_.gyro_bias_refused = gyro_bias_.refused();
  c_.gyro_bias_uncovered = gyro_bias_.uncovered();
  have_odom_ = true;
  last_odom_utime_ = utime;
  last_odom_stamp_ = stamp;
  last_odom_internal_ = internal;
  last_raw_ = raw;
  last_corrected_ = corrected;
  odom_history_.Push(stamp, {utime, stamp, internal, raw, corrected, correction_});
}

bool PoseGraphSlam::AddImuYawRate(int64_t utime, double rate) {
  ++c_.imu_in;
  const int64_t rebases = gyro_.rebases();
  if (!StampInRange(utime) || !gyro_.AddSample(OnTimeLine(utime), rate)) {
    ++c_.imu_rejected;
    return false;
  }
  c_.time_rebases += gyro_.rebases() - rebases;
  return true;
}

bool PoseGraphSlam::AddScan(int64_t scan_index, const LaserScan2& scan) {
  ++c_.scans_in;
  return AcceptScan(scan_index, scan);
}

bool PoseGraphSlam::AcceptScan(int64_t scan_index, const LaserScan2& scan) {
  if (!StampInRange(scan.utime)) {
    ++c_.scans_no_odom;  // no odometry can be stamped there
    return false;
  }
  const int64_t su = OnTimeLine(scan.utime);  // the scan's time on the mapper's time line
  const int64_t gap_us = static_cast<int64_t>(o_.max_scan_odom_gap_s * 1e6);
  const StampOrder& odom_order = odom_stream_.order();
  if (su < last_scan_utime_) {
    ++c_.scans_time_backwards;
    // The odometry's clock may be going back, and then this scan is on the new clock: held
    // until the next odometry sample that is not older than the newest (AddOdometry), which
    // replays it if the odometry re-based as a clock step; the oldest held one gives way.
    if (!replaying_) {
      if (held_scans_.size() >= kMaxHeldScans) held_scans_.erase(held_scans_.begin());
      held_scans_.push_back({scan_index, scan});
    }
    return false;
  }
  if (!PlausibleScanGeometry(scan.angle_min_rad, scan.angle_increment_rad, scan.ranges_m.size(),
                             scan.max_range_m, scan.laser_in_base)) {
    ++c_.scans_bad_geometry;  // NaN or absurd angles, mount pose or range limit: never mapped
    return false;
  }
  // The base's motion from the first beam to the last (a spinning lidar's sweep).
  std::optional<Pose2> sweep;
  if (scan.scan_time_s > 0 && scan.scan_time_s <= 1.f) {  // a plausible sweep (bus::SweepTime)
    const int64_t t1 = su + std::llround(static_cast<double>(scan.scan_time_s) * 1e6);
    if (have_odom_ && su >= odom_.oldest_utime() && t1 <= last_odom_stamp_) {
      auto m = Motion().Between(su, t1);
      // An odometry jump inside the sweep is not motion: the scan is then used as it is.
      if (m && std::hypot(m->delta.x, m->delta.y) <= o_.max_odom_jump_m &&
          std::abs(m->delta.theta) <= o_.max_odom_jump_rad)
        sweep = m->delta;
    }
  }
  ScanConversionStats st;
  std::vector<Eigen::Vector2d> points = ScanToPoints(scan, &st, sweep ? &*sweep : nullptr);
  if (static_cast<int>(points.size()) < o_.min_beams) {
    ++c_.scans_too_few_beams;
    return false;
  }
  if (!have_odom_ || su < odom_.oldest_utime() ||
      static_cast<double>(su - last_odom_stamp_) > o_.max_scan_odom_gap_s * 1e6) {
    ++c_.scans_no_odom;
    return false;
  }
  // While older odometry keeps coming in order behind the newest sample, that sample is in
  // doubt (stamped in the future?): a scan beyond what the older run covers, and beyond the
  // sample before the doubtful one, takes no odometry from it, or it would be mapped on a
  // sample that is then dropped. (A scan of the old clock, just after its last samples, is
  // fine: if the clock went back, it stands on real odometry.)
  if (odom_order.run_length() > 0 && scan.utime - odom_order.run_last() > gap_us &&
      !CoveredBesideTheRun(su, gap_us)) {
    ++c_.scans_no_odom;
    return false;
  }
  // A scan at or slightly after the newest odometry sample uses that sample's pose.
  const int64_t t = su >= last_odom_stamp_ ? last_odom_internal_ : su;
  RelativeMotion motion;
  if (!keyframes_.empty()) {
    const int64_t kt = keyframes_.back().utime;
    if (t < kt) {
      ++c_.scans_no_odom;
      return false;
    }
    auto m = Motion().Between(kt, t);
    if (!m) {
      ++c_.scans_no_odom;
      return false;
    }
    motion = *m;
  }
  last_scan_utime_ = su;
  held_scans_.clear();  // older than this one for good
  ++c_.scans_used;
  c_.invalid_beams += st.not_finite + st.out_of_range;
  if (scan.scan_time_s > 0) ++(sweep ? c_.sweeps_corrected : c_.sweeps_uncorrected);
  const bool moved = keyframes_.empty() ||
                     std::hypot(motion.delta.x, motion.delta.y) >= o_.keyframe_distance_m ||
                     std::abs(motion.delta.theta) >= o_.keyframe_angle_rad;
  // A fix that has waited its time window for a keyframe at or after it gets one now.
  const bool fix_waiting =
      !absolute_queue_.empty() && absolute_queue_.begin()->first <= t &&
      static_cast<double>(su - absolute_queue_.begin()->first) >= o_.absolute_max_wait_s * 1e6;
  // The odometry buffer is about to drop the newest keyframe's time: every later scan would need
  // motion from a time no longer covered, and none could be mapped again (a base creeping or
  // jittering in place for ~15 min at 100 Hz odometry). A keyframe here keeps the chain.
  const bool buffer_ending =
      !keyframes_.empty() && odom_.SamplesAfter(keyframes_.back().utime) >=
                                 odom_.capacity() - std::max<size_t>(odom_.capacity() / 10, 1);
  const bool make_kf = moved || fix_waiting || buffer_ending;
  if (make_kf && !moved) ++(fix_waiting ? c_.keyframes_for_absolute : c_.keyframes_for_odometry);
  last_scan_motion_covariance_ = make_kf ? Eigen::Matrix3d::Zero() : motion.covariance;
  if (make_kf) {
    NewKeyframe(scan, t, motion, std::move(points));
    kf_scans_.back().sweep = sweep;
    scans_.push_back({scan_index, scan.utime, static_cast<int>(keyframes_.size()) - 1, Pose2()});
  } else {
    scans_.push_back(
        {scan_index, scan.utime, static_cast<int>(keyframes_.size()) - 1, motion.delta});
  }
  return true;
}

void PoseGraphSlam::NewKeyframe(const LaserScan2& scan, int64_t utime, const RelativeMotion& motion,
                                std::vector<Eigen::Vector2d> points) {
  JoinGlobal();  // the graph changes from here on
  const int k = static_cast<int>(keyframes_.size());
  const int id = static_cast<int>(nodes_.size());
  Keyframe kf;
  kf.utime = utime;
  kf.estimate = k == 0 ? Pose2() : keyframes_.back().estimate * motion.delta;
  if (k == 0) {
    kf_covariance_ = AnchorInformation().inverse();
  } else {
    kf_covariance_ = ComposeCovariance(keyframes_.back().estimate, kf_covariance_, motion.delta,
                                       motion.covariance);
  }
  kf.points = std::move(points);
  keyframes_.push_back(std::move(kf));
  kf_scans_.push_back({scan, std::nullopt});
  kf_odom_.push_back(k == 0 ? Pose2() : motion.delta);
  kf_loop_.push_back(0);
  kf_first_scan_.push_back(scans_.size());  // AcceptScan adds this keyframe's scan next
  kf_by_utime_[utime] = k;
  nodes_.push_back({utime, k, Pose2()});
  node_of_kf_.push_back(id);
  node_by_utime_[utime] = id;
  ++c_.keyframes;
  (void)window_->AddPose(id, keyframes_.back().estimate);
  if (k == 0) {
    // The gauge: without it the first marginalisation would leave a singular prior.
    (void)window_->AddAbsolute(id, Pose2(), AnchorInformation());
    DrainAbsoluteQueue();
    return;
  }

  // The newest node before this one is always the previous keyframe: pose nodes are only
  // created inside linked intervals.
  const int prev = node_of_kf_[static_cast<size_t>(k - 1)];
  const Eigen::Matrix3d info = MotionInformation(motion);
  links_.push_back({prev, id, motion.delta, info, LinkKind::kOdometry});
  (void)window_->AddRelative(prev, id, motion.delta, info);

  const auto factors = match_.OnKeyframe(keyframes_);
  int used = 0;
  for (const auto& f : factors) {
    auto a = kf_by_utime_.find(f.from_utime), b = kf_by_utime_.find(f.to_utime);
    if (a == kf_by_utime_.end() || b == kf_by_utime_.end()) continue;
    const int na = node_of_kf_[static_cast<size_t>(a->second)];
    const int nb = node_of_kf_[static_cast<size_t>(b->second)];
    const Eigen::Matrix3d fi = o_.scan_match_information_scale * f.Information();
    if (!window_->AddRelative(na, nb, f.delta, fi).ok()) continue;
    links_.push_back({na, nb, f.delta, fi, LinkKind::kScanMatch});
    ++used;
    if (o_.odometry_calibration.enabled && a->second == k - 1 && b->second == k)
      CalibrateOdometry(keyframes_[static_cast<size_t>(k - 1)].utime, utime, f.delta);
  }
  if (used > 0)
    c_.scan_match_factors += used;
  else
    ++c_.scan_match_failures;

  DrainAbsoluteQueue();
  OptimizeWindow();

  if (k % o_.loop_every_keyframes == 0 && k - last_loop_keyframe_ >= o_.loop_cooldown_keyframes) {
    const auto loops = loop_.OnKeyframe(keyframes_);
    for (const auto& at : loop_.last_attempts())
      if (!at.accepted) ++c_.loops_rejected;
    for (const auto& f : loops) {
      auto a = kf_by_utime_.find(f.from_utime), b = kf_by_utime_.find(f.to_utime);
      if (a == kf_by_utime_.end() || b == kf_by_utime_.end()) continue;
      pending_loops_.push_back(links_.size());
      links_.push_back({node_of_kf_[static_cast<size_t>(a->second)],
                        node_of_kf_[static_cast<size_t>(b->second)], f.delta, f.Information(),
                        LinkKind::kLoop});
      ++c_.loops_accepted;
      loops_pending_ = true;
      last_loop_keyframe_ = k;
      ++kf_loop_[static_cast<size_t>(k)];
    }
  }
  if (loops_pending_ && k - last_global_keyframe_ >= o_.global_min_keyframes_between)
    OptimizeGlobal();
  RetireRevisits();
}

void PoseGraphSlam::RetireRevisits() {
  // Estimates are trusted only once every accepted loop has been through a successful global
  // solve.
  if (!o_.retire.enabled || loops_pending_ || last_global_failed_) return;
  const int n = static_cast<int>(keyframes_.size());
  const int last = n - 1 - o_.retire.delay_keyframes;
  const int reach = o_.retire.loop_reach_keyframes;
  for (; retire_next_ <= last; ++retire_next_) {
    const int k = retire_next_;
    bool near_loop = false;
    for (int i = std::max(k - reach, 0); i <= std::min(k + reach, n - 1) && !near_loop; ++i)
      near_loop = kf_loop_[static_cast<size_t>(i)] != 0;
    if (!near_loop) continue;
    Keyframe& kf = keyframes_[static_cast<size_t>(k)];
    bool covered = false;
    for (int j = 0; j <= k - o_.loop.min_index_gap && !covered; ++j) {
      const Keyframe& old = keyframes_[static_cast<size_t>(j)];
      if (old.retired || old.points.empty()) continue;
      const Pose2 d = old.estimate.Between(kf.estimate);
      covered =
          std::hypot(d.x, d.y) <= o_.retire.distance_m && std::abs(d.theta) <= o_.retire.angle_rad;
    }
    if (!covered) continue;
    kf.retired = true;
    std::vector<Eigen::Vector2d>().swap(kf.points);
    std::vector<float>().swap(kf_scans_[static_cast<size_t>(k)].scan.ranges_m);
    ++c_.keyframes_retired;
  }
  RemoveRetired();
}

void PoseGraphSlam::RemoveRetired() {
  // Only on estimates a converged global solve left (RetireRevisits' conditions), with no loop
  // waiting for the gate (pending_loops_ holds links_ indices), and outside the window: a
  // keyframe with more than window_size keyframes after it, and already decided on.
  if (!o_.retire.remove_poses || !pending_loops_.empty()) return;
  const int last =
      std::min(static_cast<int>(keyframes_.size()) - 2 - o_.window_size, retire_next_ - 1);
  for (; remove_next_ <= last; ++remove_next_) {
    if (!keyframes_[static_cast<size_t>(remove_next_)].retired) continue;
    if (RemoveKeyframe(remove_next_))
      ++c_.keyframes_removed;
    else
      ++c_.removals_refused;
  }
}

bool PoseGraphSlam::RemoveKeyframe(int k) {
  // A retired keyframe is kept when it carries an absolute prior, when the node before it in
  // time is a pose node (its scans need a keyframe to follow), when a neighbour is still in the
  // window, when it has more neighbours than a small dense marginal should hold, or when its
  // factors do not determine the marginal (MarginalizeNode's errors). The neighbour cap only
  // bounds the dense marginal (3n x 3n) and the tree's n^2 pairs: a refused keyframe stays for
  // good and becomes a hub that later removals link to (16 refused 1 in 30 on the simulator's
  // laps, 17-19 neighbours each, and the kept graph grew with them; docs/posegraph.md).
  constexpr size_t kMaxNeighbours = 64;
  const int r = node_of_kf_[static_cast<size_t>(k)];
  const Node& node = nodes_[static_cast<size_t>(r)];
  if (node.removed || window_->InWindow(r)) return false;
  for (const auto& p : priors_)
    if (p.id == r) return false;
  const auto at = node_by_utime_.find(node.utime);
  if (at == node_by_utime_.end() || at == node_by_utime_.begin()) return false;
  const int prev = std::prev(at)->second;
  const int pk = nodes_[static_cast<size_t>(prev)].keyframe;
  const int qk = NextKeptKeyframe(k);
  if (pk < 0 || qk < 0) return false;

  std::vector<RelativeFactor2> factors;
  std::map<int, Pose2> estimates{{r, EstimateOf(r)}};
  std::map<int, int64_t> order{{r, node.utime}};
  for (const Link& l : links_) {
    if (l.from != r && l.to != r) continue;
    const int other = l.from == r ? l.to : l.from;
    if (window_->InWindow(other)) return false;
    // Weighted as the global solve's robust loss weighs it at these estimates (its IRLS weight):
    // a loop the loss discounts is not marginalised at full strength.
    const Eigen::Vector3d e = EdgeError2(l.z, EstimateOf(l.from), EstimateOf(l.to));
    // A folded link was weighted when it was made and is solved without the loss.
    const double w = l.kind == LinkKind::kFolded ? 1.0
                                                 : LossWeight(o_.global_loss, o_.global_loss_scale,
                                                              e.dot(l.information * e));
    factors.push_back({l.from, l.to, l.z, w * l.information});
    estimates[other] = EstimateOf(other);
    order[other] = nodes_[static_cast<size_t>(other)].utime;
  }
  if (estimates.size() - 1 > kMaxNeighbours) return false;
  auto tree = MarginalizeNode(r, factors, estimates, order);
  if (!tree.ok()) return false;

  // The scans of the previous kept keyframe and of this one, at their poses now, follow the
  // previous kept keyframe and the next one from here on.
  const size_t s0 = kf_first_scan_[static_cast<size_t>(pk)];
  const size_t s1 = kf_first_scan_[static_cast<size_t>(qk)];
  std::vector<Pose2> poses;
  poses.reserve(s1 - s0);
  for (size_t i = s0; i < s1; ++i)
    poses.push_back(ScanPoseOf(scans_[i], scans_[i].keyframe == pk ? k : qk));
  const Pose2& p_est = keyframes_[static_cast<size_t>(pk)].estimate;
  const Pose2 p_inv = p_est.Inverse();
  for (size_t i = s0; i < s1; ++i) {
    ScanRef& s = scans_[i];
    s.keyframe = pk;
    s.delta = p_inv * poses[i - s0];
    s.share = static_cast<double>(i - s0) / static_cast<double>(s1 - s0);
  }
  kf_odom_[static_cast<size_t>(qk)] = p_est.Between(keyframes_[static_cast<size_t>(qk)].estimate);

  links_.erase(std::remove_if(links_.begin(), links_.end(),
                              [r](const Link& l) { return l.from == r || l.to == r; }),
               links_.end());
  for (const auto& f : *tree) {
    // One folded link per pair of nodes: a second is merged into the first.
    auto same = std::find_if(links_.begin(), links_.end(), [&f](const Link& l) {
      return l.kind == LinkKind::kFolded && l.from == f.from && l.to == f.to;
    });
    if (same == links_.end()) {
      links_.push_back({f.from, f.to, f.z, f.information, LinkKind::kFolded});
      continue;
    }
    const RelativeFactor2 merged =
        MergeRelativeFactors({same->from, same->to, same->z, same->information}, f,
                             EstimateOf(f.from), EstimateOf(f.to));
    same->z = merged.z;
    same->information = merged.information;
  }
  nodes_[static_cast<size_t>(r)].removed = true;
  node_by_utime_.erase(at);
  kf_by_utime_.erase(keyframes_[static_cast<size_t>(k)].utime);
  return true;
}

int PoseGraphSlam::NextKeptKeyframe(int k) const {
  for (size_t j = static_cast<size_t>(k) + 1; j < keyframes_.size(); ++j)
    if (!nodes_[static_cast<size_t>(node_of_kf_[j])].removed) return static_cast<int>(j);
  return -1;
}

void PoseGraphSlam::CalibrateOdometry(int64_t t0, int64_t t1, const Pose2& matched) {
  const auto steps = odom_.Steps(t0, t1);
  if (!steps || steps->size() < 2) return;
  const auto motion = odom_.Between(t0, t1);
  if (!motion) return;
  const Pose2 raw = steps->front().second.Between(steps->back().second);
  const int64_t before = calibrator_.updates();
  // The covariance is linear in the noise model: divided by the scale in use, the configured one.
  calibrator_.AddPair(raw, matched, motion->covariance / odom_.noise_scale());
  if (calibrator_.updates() != before) {
    odom_.SetCalibration(calibrator_.calibration());
    odom_.SetNoiseScale(calibrator_.noise_scale());
  }
}

void PoseGraphSlam::RelinkOdometry() {
  for (Link& l : links_) {
    if (l.kind != LinkKind::kOdometry) continue;
    const auto m = Motion().Between(nodes_[static_cast<size_t>(l.from)].utime,
                                    nodes_[static_cast<size_t>(l.to)].utime);
    if (!m) continue;  // no longer in the odometry buffer: keeps its factor
    l.z = m->delta;
    l.information = MotionInformation(*m);
  }
}

void PoseGraphSlam::OptimizeWindow() {
  const double t0 = NowMs();
  auto u = window_->Update();
  if (clock_) window_ms_.push_back(NowMs() - t0);
  ++c_.window_updates;
  if (!u.ok()) {
    ++c_.window_failures;
    return;
  }
  kf_covariance_stale_ = true;
  for (int id : window_->WindowIds())
    if (auto e = window_->Estimate(id)) SetEstimate(id, *e);
}

Pose2 PoseGraphSlam::EstimateOf(int node) const {
  const Node& n = nodes_[static_cast<size_t>(node)];
  return n.keyframe >= 0 ? keyframes_[static_cast<size_t>(n.keyframe)].estimate : n.estimate;
}

void PoseGraphSlam::SetEstimate(int node, const Pose2& pose) {
  Node& n = nodes_[static_cast<size_t>(node)];
  if (n.keyframe >= 0)
    keyframes_[static_cast<size_t>(n.keyframe)].estimate = pose;
  else
    n.estimate = pose;
}

AbsoluteOutcome PoseGraphSlam::AddAbsolutePose(int64_t utime, const Pose2& z,
                                               const Eigen::Matrix3d& info) {
  ++c_.absolute_in;
  const bool finite =
      std::isfinite(z.x) && std::isfinite(z.y) && std::isfinite(z.theta) && info.allFinite();
  if (!finite || (info - info.transpose()).norm() > 1e-9 * info.norm() ||
      Eigen::LLT<Eigen::Matrix3d>(info).info() != Eigen::Success) {
    ++c_.absolute_invalid;
    return AbsoluteOutcome::kInvalid;
  }
  if (!StampInRange(utime)) {
    ++c_.absolute_invalid;
    return AbsoluteOutcome::kInvalid;
  }
  // While older odometry comes in order behind the newest sample, a fix older than the newest
  // keyframe may be on a clock that went back: it waits until the run decides (AddOdometry).
  if (odom_stream_.order().run_length() > 0 && !keyframes_.empty() &&
      OnTimeLine(utime) <= keyframes_.back().utime) {
    if (held_absolute_.size() >= kMaxQueuedAbsolute) {
      ++c_.absolute_rejected;
      return AbsoluteOutcome::kRejected;
    }
    held_absolute_.push_back({utime, z, info});
    ++c_.absolute_queued;
    return AbsoluteOutcome::kQueued;
  }
  return PlaceAbsolute(utime, z, info, true);
}

AbsoluteOutcome PoseGraphSlam::PlaceAbsolute(int64_t utime, const Pose2& z,
                                             const Eigen::Matrix3d& info, bool count_queued) {
  // After a clock step back, a fix stamped on the old clock (ahead of the new clock's newest
  // odometry by more than a scan may be, and not after the old clock's newest sample) came
  // late through a slower path: it keeps the old clock's place on the time line. (A step
  // shorter than that gap cannot be told apart: such a fix is placed by the new clock.)
  const int64_t gap_us = static_cast<int64_t>(o_.max_scan_odom_gap_s * 1e6);
  if (c_.clock_steps_back > 0 && utime <= old_clock_newest_ && utime - last_odom_utime_ > gap_us)
    utime += prev_time_offset_;
  else
    utime = OnTimeLine(utime);
  if (keyframes_.empty() || utime > keyframes_.back().utime) {
    // No pose at or after this time yet: wait for the keyframe that covers it.
    if (absolute_queue_.size() >= kMaxQueuedAbsolute) {
      ++c_.absolute_rejected;
      return AbsoluteOutcome::kRejected;
    }
    absolute_queue_.emplace(utime, QueuedAbsolute{z, info});
    if (count_queued) ++c_.absolute_queued;
    return AbsoluteOutcome::kQueued;
  }
  return ApplyAbsolute(utime, z, info, true);
}

void PoseGraphSlam::DrainAbsoluteQueue() {
  const int64_t newest = keyframes_.back().utime;
  while (!absolute_queue_.empty() && absolute_queue_.begin()->first <= newest) {
    auto node = absolute_queue_.extract(absolute_queue_.begin());
    (void)ApplyAbsolute(node.key(), node.mapped().z, node.mapped().information, false);
  }
}

AbsoluteOutcome PoseGraphSlam::ApplyAbsolute(int64_t utime, const Pose2& z,
                                             const Eigen::Matrix3d& info, bool optimize) {
  JoinGlobal();  // the graph may change from here on
  auto reject = [this] {
    ++c_.absolute_rejected;
    return AbsoluteOutcome::kRejected;
  };
  if (auto at = node_by_utime_.find(utime); at != node_by_utime_.end()) {
    // At a node's time: a prior factor on it, if it is still optimised.
    if (!window_->AddAbsolute(at->second, z, info).ok()) return reject();
    priors_.push_back({at->second, z, info});
    ++c_.absolute_attached;
    if (optimize) OptimizeWindow();
    return AbsoluteOutcome::kAttached;
  }
  const auto next = node_by_utime_.upper_bound(utime);
  if (next == node_by_utime_.begin() || next == node_by_utime_.end()) return reject();
  const auto prev = std::prev(next);
  const int a = prev->second, b = next->second;
  if (!window_->InWindow(a) || !window_->InWindow(b)) return reject();
  // The continuous-source factor of [a, b]: consecutive nodes have exactly one.
  auto link = std::find_if(links_.begin(), links_.end(), [&](const Link& l) {
    return l.kind == LinkKind::kOdometry && l.from == a && l.to == b;
  });
  if (link == links_.end()) return reject();
  const auto before = Motion().Between(prev->first, utime);
  const auto after = Motion().Between(utime, next->first);
  if (!before || !after) return reject();
  if (!window_->RemoveRelative(a, b, link->z)) return reject();
  const int id = static_cast<int>(nodes_.size());
  const Pose2 estimate = EstimateOf(a) * before->delta;
  nodes_.push_back({utime, -1, estimate});
  node_by_utime_[utime] = id;
  const Eigen::Matrix3d info_before = MotionInformation(*before);
  const Eigen::Matrix3d info_after = MotionInformation(*after);
  // The old link becomes the first half in place (indices of pending loops stay valid).
  *link = {a, id, before->delta, info_before, LinkKind::kOdometry};
  links_.push_back({id, b, after->delta, info_after, LinkKind::kOdometry});
  (void)window_->AddPose(id, estimate);
  (void)window_->AddRelative(a, id, before->delta, info_before);
  (void)window_->AddRelative(id, b, after->delta, info_after);
  (void)window_->AddAbsolute(id, z, info);
  priors_.push_back({id, z, info});
  ++c_.absolute_spliced;
  if (optimize) OptimizeWindow();
  return AbsoluteOutcome::kSpliced;
}

io::PoseGraph PoseGraphSlam::Graph() const {
  io::PoseGraph g;
  g.vertices2.reserve(num_live_nodes());
  for (size_t i = 0; i < nodes_.size(); ++i)
    if (!nodes_[i].removed)
      g.vertices2.push_back({static_cast<int>(i), EstimateOf(static_cast<int>(i))});
  g.edges2.reserve(links_.size());
  // The folded links last (OptimizeGlobal solves them without the robust loss).
  for (const bool folded : {false, true}) {
    for (const auto& l : links_) {
      if ((l.kind == LinkKind::kFolded) != folded) continue;
      io::Edge2 e;
      e.from = l.from;
      e.to = l.to;
      e.measurement = l.z;
      e.information = 0.5 * (l.information + l.information.transpose());
      g.edges2.push_back(e);
    }
  }
  return g;
}

// One global optimisation: the graph as it was when it started, its options and outcome. Owned
// by the mapper; while in the background only its thread touches g and result.
struct PoseGraphSlam::GlobalSolve {
  io::PoseGraph g;
  BatchOptions b;
  std::vector<VertexPrior2> priors;
  std::vector<size_t> pending;  // the loops it is the first solve of (links_ indices)
  size_t folded = 0;            // folded links (solved without the loss, last in g.edges2)
  Result<BatchResult> result = MakeError(ErrorCode::kInternal, "global optimisation not run");
  double solve_ms = 0;  // the solve's own time (steady clock)
  std::future<void> done;

  void Run() {
    const auto t0 = std::chrono::steady_clock::now();
    result = OptimizeGraph(&g, b, priors.empty() ? nullptr : &priors);
    solve_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
};

PoseGraphSlam::~PoseGraphSlam() {
  if (global_ && global_->done.valid()) global_->done.wait();
}

void PoseGraphSlam::JoinGlobal() {
  if (!global_) return;
  std::unique_ptr<GlobalSolve> s = std::move(global_);
  const auto t0 = std::chrono::steady_clock::now();
  s->done.get();
  const double waited =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (clock_) global_wait_ms_.push_back(waited);
  FinishGlobal(s.get());
  // What NewKeyframe does after a solve on the spot, on the same keyframes: the graph is then as
  // an in-line solve would have left it.
  RetireRevisits();
}

void PoseGraphSlam::OptimizeGlobal(bool last) {
  JoinGlobal();
  if (o_.odometry_calibration.enabled && o_.odometry_calibration.relink_on_global &&
      calibrator_.active())
    RelinkOdometry();
  auto s = std::make_unique<GlobalSolve>();
  s->g = Graph();
  BatchOptions& b = s->b;
  b = batch_;
  b.initialization = Initialization::kNone;
  b.loss = o_.global_loss;
  b.loss_scale = o_.global_loss_scale;
  b.max_iterations = o_.global_max_iterations;
  b.function_tolerance = o_.global_function_tolerance;
  b.num_threads = o_.num_threads;
  b.max_time_s = last ? 0 : o_.global_max_time_s;
  // A folded link's information went through the loss's weight when it was made (RemoveKeyframe),
  // and its residual is meant to be non-zero (it carries the removed factors' pull): no loss.
  // Graph() puts them last.
  s->folded = static_cast<size_t>(std::count_if(
      links_.begin(), links_.end(), [](const Link& l) { return l.kind == LinkKind::kFolded; }));
  b.first_plain_edge2 = s->g.edges2.size() - s->folded;
  s->priors = priors_;
  s->pending.swap(pending_loops_);
  last_global_keyframe_ = static_cast<int>(keyframes_.size()) - 1;
  if (!last && o_.global_in_background) {
    // loops_pending_ stays set until it is taken in: nothing is retired or removed meanwhile.
    GlobalSolve* run = s.get();
    try {
      s->done = std::async(std::launch::async, [run] { run->Run(); });
      global_ = std::move(s);
      return;
    } catch (const std::system_error& e) {  // no thread to be had: solved here instead
      LOG_WARN << "global optimisation in line: no thread for it (" << e.what() << ")";
    }
  }
  s->Run();
  if (clock_) global_wait_ms_.push_back(s->solve_ms);
  FinishGlobal(s.get());
}

void PoseGraphSlam::FinishGlobal(GlobalSolve* s) {
  io::PoseGraph& g = s->g;
  BatchOptions& b = s->b;
  double solve_ms = s->solve_ms;
  // Its bookkeeping: counted, cut short by the time limit or failed.
  auto count = [&](const Result<BatchResult>& r) {
    ++c_.global_optimizations;
    global_cut_short_ = r.ok() && r->time_limited;
    if (global_cut_short_) ++c_.global_time_limited;
    last_global_failed_ = !r.ok();
    if (!r.ok()) ++c_.global_failures;
    return r.ok();
  };
  const bool solved = count(s->result);
  loops_pending_ = false;
  std::vector<size_t> pending;
  pending.swap(s->pending);
  if (!solved) {
    if (clock_) global_ms_.push_back(solve_ms);
    return;
  }
  if (global_cut_short_) {
    // Not converged: its estimates are taken (every accepted step lowered the cost) and the
    // window rebuilt from them, but the new loops stay pending, so the next solve comes
    // global_min_keyframes_between keyframes later even without new loops, the chi-square gate
    // waits for a converged solution (`pending` is left empty) and no keyframe is retired
    // before one.
    pending_loops_.insert(pending_loops_.begin(), pending.begin(), pending.end());
    pending.clear();
    loops_pending_ = true;
  }
  // The new loops' whitened residuals at the solution: an outlier is dropped and the graph
  // solved again without it (the robust loss only bounds its pull).
  std::vector<size_t> outliers;
  std::vector<int> at(nodes_.size(), -1);  // node id -> g.vertices2 index (removed: -1)
  for (size_t i = 0; i < g.vertices2.size(); ++i)
    at[static_cast<size_t>(g.vertices2[i].id)] = static_cast<int>(i);
  for (size_t i : pending) {
    const Link& l = links_[i];
    const Eigen::Vector3d e =
        EdgeError2(l.z, g.vertices2[static_cast<size_t>(at[static_cast<size_t>(l.from)])].pose,
                   g.vertices2[static_cast<size_t>(at[static_cast<size_t>(l.to)])].pose);
    const double chi2 = e.dot(l.information * e);
    if (o_.loop_chi2_gate > 0 && chi2 > o_.loop_chi2_gate) outliers.push_back(i);
  }
  if (!outliers.empty()) {
    std::sort(outliers.rbegin(), outliers.rend());
    for (size_t i : outliers) {
      // The removed loop no longer vouches for its newer keyframe (RetireRevisits).
      const int kf = nodes_[static_cast<size_t>(links_[i].to)].keyframe;
      if (kf >= 0 && kf_loop_[static_cast<size_t>(kf)] > 0) --kf_loop_[static_cast<size_t>(kf)];
      links_.erase(links_.begin() + static_cast<std::ptrdiff_t>(i));
    }
    const auto n = static_cast<int64_t>(outliers.size());
    c_.loops_inconsistent += n;
    c_.loops_accepted -= n;
    g = Graph();
    b.first_plain_edge2 = g.edges2.size() - s->folded;  // the dropped loops were not folded
    // On this thread: the graph has just changed and the estimates wait for it.
    s->Run();
    solve_ms += s->solve_ms;
    if (clock_) global_wait_ms_.back() += s->solve_ms;
    if (!count(s->result)) {
      if (clock_) global_ms_.push_back(solve_ms);
      return;
    }
    loops_pending_ = global_cut_short_;  // solved again later, nothing retired before
  }
  for (const auto& v : g.vertices2) SetEstimate(v.id, v.pose);
  ResetWindow();
  if (clock_) global_ms_.push_back(solve_ms);
}

void PoseGraphSlam::ResetWindow() {
  WindowOptions w;
  w.window_size = o_.window_size;
  w.max_iterations = o_.window_max_iterations;
  w.num_threads = 1;
  window_ = std::make_unique<SlidingWindowOptimizer>(w);
  // The newest window_size nodes in time order (the newest keyframes when nothing was spliced).
  std::vector<int> ids;
  for (auto it = node_by_utime_.rbegin();
       it != node_by_utime_.rend() && static_cast<int>(ids.size()) < o_.window_size; ++it)
    ids.push_back(it->second);
  std::reverse(ids.begin(), ids.end());
  std::vector<char> in(nodes_.size(), 0);
  for (int id : ids) {
    in[static_cast<size_t>(id)] = 1;
    (void)window_->AddPose(id, EstimateOf(id));
  }
  if (!ids.empty()) (void)window_->AddAbsolute(ids[0], EstimateOf(ids[0]), AnchorInformation());
  // Only links inside the window are kept; the others are in the global solution.
  for (const auto& l : links_)
    if (in[static_cast<size_t>(l.from)] && in[static_cast<size_t>(l.to)])
      (void)window_->AddRelative(l.from, l.to, l.z, l.information);
  for (const auto& p : priors_)
    if (in[static_cast<size_t>(p.id)]) (void)window_->AddAbsolute(p.id, p.z, p.information);
}

void PoseGraphSlam::Finish() {
  JoinGlobal();
  // Fixes still waiting for an odometry run that never decided: placed by the current clock.
  PlaceHeldFixes();
  // The window after the last global optimisation holds its newest nodes to the scan-match
  // chain (its links only, the oldest anchored): the loops into it are not in the window and
  // their correction of those nodes is undone. A last solve of the whole graph restores it.
  if (loops_pending_ || global_cut_short_ ||
      (o_.final_global_optimization && c_.loops_accepted > 0 &&
       last_global_keyframe_ < static_cast<int>(keyframes_.size()) - 1))
    OptimizeGlobal(/*last=*/true);
}

std::vector<ScanPose> PoseGraphSlam::Trajectory() const {
  std::vector<ScanPose> out;
  out.reserve(scans_.size());
  // The next kept keyframe after each keyframe (scans are anchored to kept ones only).
  std::vector<int> next(keyframes_.size(), -1);
  for (size_t k = keyframes_.size(); k-- > 1;)
    next[k - 1] =
        nodes_[static_cast<size_t>(node_of_kf_[k])].removed ? next[k] : static_cast<int>(k);
  for (const auto& s : scans_)
    out.push_back({s.scan_index, s.utime, ScanPoseOf(s, next[static_cast<size_t>(s.keyframe)])});
  return out;
}

Pose2 PoseGraphSlam::ScanPoseOf(const ScanRef& s, int next_keyframe) const {
  const Pose2& kf = keyframes_[static_cast<size_t>(s.keyframe)].estimate;
  const Pose2 pose = kf * s.delta;
  if (!o_.interpolate_scan_poses || next_keyframe < 0) return pose;
  const Pose2& ref = kf_odom_[static_cast<size_t>(next_keyframe)];
  const Pose2& next = keyframes_[static_cast<size_t>(next_keyframe)].estimate;
  if (s.share >= 0) {
    // Re-anchored by a removal (RemoveKeyframe): where the scan would be if it moved rigidly with
    // this keyframe, and with the next one (`ref` was their relative pose then), blended by its
    // share of the scans between them.
    return Interpolate(pose, next * ref.Inverse() * s.delta, s.share);
  }
  // Motion "length" of a step, for the share of the correction: metres plus radians.
  auto length = [](const Pose2& d) { return std::hypot(d.x, d.y) + std::abs(d.theta); };
  // The correction C with estimate_k * odometry * C = estimate_{k+1}, applied in part.
  const Pose2 c = (kf * ref).Inverse() * next;
  const double total = length(ref);
  const double f = total > 0 ? std::clamp(length(s.delta) / total, 0.0, 1.0) : 0.0;
  return pose * ExpSE2(f * LogSE2(c));
}

bool PoseGraphSlam::LastScanPose(ScanPose* out) const {
  if (scans_.empty()) return false;
  const ScanRef& s = scans_.back();
  *out = {s.scan_index, s.utime, keyframes_[static_cast<size_t>(s.keyframe)].estimate * s.delta};
  return true;
}

bool PoseGraphSlam::LastScanCovariance(Eigen::Matrix3d* covariance) {
  if (scans_.empty()) return false;
  if (kf_covariance_stale_) {
    kf_covariance_stale_ = false;
    if (auto cov = window_->Covariance(node_of_kf_.back()))
      kf_covariance_ = *cov;
    else
      ++c_.covariance_failures;
  }
  // The newest scan belongs to the newest keyframe.
  const ScanRef& s = scans_.back();
  *covariance = ComposeCovariance(keyframes_[static_cast<size_t>(s.keyframe)].estimate,
                                  kf_covariance_, s.delta, last_scan_motion_covariance_);
  return true;
}

io::GridMap PoseGraphSlam::RenderMap(const io::LogOddsOptions& options) const {
  io::LogOddsGrid grid(options);
  std::vector<float> ranges;
  for (size_t i = 0; i < keyframes_.size(); ++i) {
    if (keyframes_[i].retired) continue;
    const LaserScan2& s = kf_scans_[i].scan;
    const std::optional<Pose2>& sweep = kf_scans_[i].sweep;
    // The beams matching left out (below min_range: the robot's own chassis or mast) are no
    // walls in the map either; max_range 0 means no limit here too (the grid takes it as none).
    ranges = s.ranges_m;
    for (float& r : ranges)
      if (r < s.min_range_m) r = std::numeric_limits<float>::quiet_NaN();
    const float max_range =
        s.max_range_m > 0 ? s.max_range_m : std::numeric_limits<float>::infinity();
    if (!sweep || s.ranges_m.size() < 2) {
      grid.IntegrateScan(keyframes_[i].estimate * s.laser_in_base, ranges, s.angle_min_rad,
                         s.angle_increment_rad, max_range);
      continue;
    }
    // A sweep: each beam from where the laser was when it measured it (as ScanToPoints).
    const double last = static_cast<double>(s.ranges_m.size() - 1);
    const Pose2& kf = keyframes_[i].estimate;
    grid.IntegrateScan(
        [&](size_t b) {
          return kf * Interpolate(Pose2(), *sweep, static_cast<double>(b) / last) * s.laser_in_base;
        },
        ranges, s.angle_min_rad, s.angle_increment_rad, max_range);
  }
  if (grid.refused_beams() > 0) {
    LOG_WARN << "map: " << grid.refused_beams()
             << " beams left out: the grid would have outgrown its cap of " << options.max_cells
             << " cells (a keyframe estimate far from the others?)";
  }
  return grid.ToGridMap();
}

std::map<std::string, int64_t> PoseGraphSlam::PluginCounters() const {
  std::map<std::string, int64_t> out;
  for (const auto& [k, v] : match_.counters()) out["scan_match." + k] = v;
  for (const auto& [k, v] : loop_.counters()) out["loop_closure." + k] = v;
  if (o_.use_gyro) out["gyro.missing_steps"] = static_cast<int64_t>(fused_.gyro_missing_steps());
  return out;
}

}  // namespace omni::pgm
