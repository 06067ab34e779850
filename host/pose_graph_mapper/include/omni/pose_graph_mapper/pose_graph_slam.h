// Online 2D pose-graph SLAM: the mapper core that drives the pieces of this library.
//
// Odometry and laser scans arrive in time order. A scan becomes a keyframe when the odometry
// moved at least keyframe_distance_m or keyframe_angle_rad since the last keyframe; every other
// scan is stored as (keyframe, odometry motion since it), so every accepted scan gets a pose that
// follows its keyframe's optimised estimate. Consecutive keyframes are linked by the odometry
// source's factor (propagated covariance) and, when it matches, by the keyframe scan-matching
// plugin's factor. After each keyframe the sliding window (last N keyframes) is optimised; then
// the loop-closure plugin runs on the new keyframe, and accepted loops trigger a batch
// optimisation of the whole graph with a robust loss, after which the window is rebuilt from
// the result. Bad input is rejected and counted (SlamCounters), never fatal.
//
// Absolute poses and pose splicing (AddAbsolutePose). The graph's vertices are "nodes": every
// keyframe is a node, and an absolute (GPS-like) measurement whose time falls strictly inside
// the interval between two time-consecutive nodes a < b creates a *pose node* there. Pose nodes
// carry no scan: the scan matcher and the loop closure keep seeing keyframes only (keyframes(),
// their indices, kf_by_utime_), so nothing that counts keyframes changes meaning. Node ids are
// given in creation order; without absolute poses node id == keyframe index, which keeps every
// existing output (graph.g2o, the window, the global solve) exactly as before. Splicing replaces
// the odometry factor a -> b by the odometry source's factors a -> new and new -> b (the
// propagated covariances compose to the old one: no information is counted twice or lost);
// scan-match and loop factors between a and b stay where they are. In the sliding window the
// old factor is removed, the node and its two factors and prior are added (the node joins the
// window at its newest end; the marginalisation is exact in any order). A splice needs a and b
// both still in the window: the factor a -> b of an older interval has already been folded into
// the marginal prior, so such a measurement (and one older than the first node, or at the time
// of a marginalised node) is rejected and counted (absolute_rejected), not re-linearised. A
// measurement at exactly a node's time is attached to it as a prior factor; one newer than the
// newest node waits in a queue until a keyframe at or after its time exists, then is attached or
// spliced. The global optimisation includes pose nodes, both halves and every prior. Every
// accepted scan still gets its pose from its keyframe (Trajectory()).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "omni/common/config.h"
#include "omni/common/geometry.h"
#include "omni/common/gyro_bias.h"
#include "omni/common/odometry_calibration.h"
#include "omni/common/result.h"
#include "omni/common/stamp_order.h"
#include "omni/common/time.h"
#include "omni/io/g2o.h"
#include "omni/io/grid.h"
#include "omni/pose_graph_mapper/batch_optimizer.h"
#include "omni/pose_graph_mapper/continuous_source.h"
#include "omni/pose_graph_mapper/gyro_source.h"
#include "omni/pose_graph_mapper/measurement_plugin.h"
#include "omni/pose_graph_mapper/node_options.h"
#include "omni/pose_graph_mapper/scan_plugins.h"
#include "omni/pose_graph_mapper/window_optimizer.h"

namespace omni::pgm {

struct PoseGraphSlamOptions {
  // Keyframe gating on the odometry motion since the last keyframe.
  double keyframe_distance_m = 0.5;
  double keyframe_angle_rad = 0.35;
  int window_size = 50;  // keyframes optimised per update (N)
  int window_max_iterations = 10;
  // Input checks.
  int min_beams = 30;                // scans with fewer usable beams are rejected
  double max_odom_jump_m = 3.0;      // a larger step between two odometry samples is a jump
  double max_odom_jump_rad = 2.5;    // ... or a larger turn
  double max_scan_odom_gap_s = 0.5;  // a scan this much newer than the odometry is rejected
  // The measurement queue's time window: an absolute pose newer than the newest node waits for
  // the keyframe that covers it; a scan this much (message time) after the oldest waiting one
  // becomes a keyframe even if the base has not moved, so a parked robot's fixes are placed
  // (spliced or attached) instead of waiting for motion that may never come.
  double absolute_max_wait_s = 1.0;
  // Odometry factor covariance growth: 10x the source's defaults on distance and rotation, so
  // the scan matches dominate (intel-raw: ATE 0.21 m with the defaults, 0.10 m with these).
  OdometryNoise odometry_noise{1e-2, 1e-4, 1e-3, 1e-2, 1e-6, 1e-6};
  // Odometry samples held for the factors (not a config key): 1000 s at 100 Hz while the base
  // moves; a base standing still adds none (OdometrySource::AddSample).
  size_t odometry_buffer_samples = 100000;
  double scan_match_information_scale = 1.0;  // scales the keyframe matcher's information
  // The IMU as a continuous source (gyro_source.h): with `use_gyro`, every odometry factor
  // carries the gyro's heading fused step by step (AddImuYawRate feeds it).
  bool use_gyro = false;
  // Online odometry self-calibration (odometry_calibration.h): scale, lateral creep, heading
  // scale and heading drift per metre, fitted to the keyframe scan matches.
  OdometryCalibratorOptions odometry_calibration;
  GyroNoise gyro_noise;
  double gyro_bias_rad_s = 0.0;  // subtracted from every yaw-rate sample until one is learned
  GyroBiasOptions gyro_bias;     // learning the bias while the base stands still
  // Global optimisation on accepted loops.
  std::string global_loss = "cauchy";  // none | huber | cauchy
  double global_loss_scale = 1.0;
  int global_max_iterations = 30;
  // Stop a global optimisation when an iteration lowers the cost by less than this fraction.
  // Most solves run to the iteration cap at 1e-10; 1e-6 saves about 40 % of the iterations
  // (intel-raw 0.8 s) but moves the noisy logs' ATE by up to 0.01 m (docs/posegraph.md).
  double global_function_tolerance = 1e-10;
  int global_min_keyframes_between = 10;  // at most one global optimisation per this many
  // Wall-clock limit of a global optimisation while mapping (Ceres stops between iterations and
  // keeps its best step; the next solve, global_min_keyframes_between keyframes later even
  // without new loops, goes on from there, and nothing is retired or gated before a solve
  // converges); the last one (Finish) has none. A solve holds up the next keyframe (in the
  // background) or the scans behind it (in line), and its iterations grow with the graph: 0.22 s
  // each at 5840 keyframes (30 simulator laps, poses kept), up to 5.9 s a solve without the
  // limit. 0: none.
  double global_max_time_s = 1.0;
  // A global optimisation while mapping runs on its own thread, on a copy of the graph, and is
  // taken in before the graph next changes (the next keyframe, an absolute pose, Finish): the
  // scans until then are posed and published meanwhile, on the estimates before it. The result
  // is the same as solving on the spot, taken in one keyframe later; the last solve (Finish) and
  // a re-solve after the loop gate dropped a loop run on the mapper's thread. false: every solve
  // holds up the scans behind it.
  bool global_in_background = true;
  // Consistency gate: after a global optimisation, a loop closure added since the previous one
  // whose whitened residual e^T Omega e exceeds this is an outlier the robust loss gave up on:
  // it is removed (counted in loops_inconsistent) and the graph optimised again. 0 disables.
  double loop_chi2_gate = 0;
  int loop_every_keyframes = 1;     // loop closure tried on every k-th keyframe
  int loop_cooldown_keyframes = 2;  // no loop attempts for this many after an accepted one
  // Finish() optimises the whole graph once more when loops were closed and keyframes were
  // added since the last global optimisation (the window had undone the loops' correction of
  // its nodes); false: only when loops are pending.
  bool final_global_optimization = true;
  // Trajectory(): a scan between keyframes k and k + 1 follows k by odometry, plus the share of
  // the correction that closes the gap to k + 1's estimate proportional to the odometry motion
  // covered (false: it follows keyframe k only, and the poses jump at every keyframe).
  bool interpolate_scan_poses = true;
  int num_threads = 2;
  // Retiring keyframes that revisit mapped ground, so that a robot driving the same rooms for
  // hours keeps a graph of poses but stores scans for the ground, not for the time. A keyframe
  // is retired (its scan released, left out of the map and of loop candidates; its pose and
  // factors stay) once `delay_keyframes` newer ones exist and every loop closed so far has been
  // through a global optimisation, when a loop was accepted within `loop_reach_keyframes` of it
  // and a kept keyframe at least `loop.min_index_gap` older lies within `distance_m` and
  // `angle_rad` of its estimate.
  struct RetireOptions {
    bool enabled = true;
    double distance_m = 0.4;
    double angle_rad = 0.35;
    int loop_reach_keyframes = 3;
    int delay_keyframes = 15;
    // Retired keyframes older than the window are removed from the graph: marginalised into a
    // tree of relative factors over their neighbours (node_removal.h).
    bool remove_poses = true;
  } retire;
  // The mapper's matchers differ from the plugins' defaults (docs/posegraph.md, "Sparse logs"):
  // submaps follow the surfaces between neighbouring beams, a keyframe match whose optimum is
  // on its window's edge is dropped, and the loop search covers 5 keyframes either side of the
  // candidate in a window that grows with the path since the last loop. Keyframe matches use
  // beams up to 16 m (the loop search keeps 20 m): docs/posegraph.md, "Match range".
  KeyframeMatchOptions match = [] {
    KeyframeMatchOptions m;
    m.max_range_m = 16.0;
    m.fill_gap_m = 0.5;
    m.reject_window_edge = true;
    return m;
  }();
  // Loop-closure candidates are matched on 2 threads here (the plugin's default is 1).
  LoopClosureOptions loop = [] {
    LoopClosureOptions l;
    l.num_threads = 2;
    l.submap_half_width = 5;
    l.fill_gap_m = 0.5;
    l.min_score = 0.78;
    l.window_growth_per_m = 0.03;
    l.max_window_m = 8.0;
    l.field_cache_size = 4;  // the +-5-keyframe filled fields cost enough for the cache to pay
    return l;
  }();

  // Reads the `slam` section (Finish is the caller's).
  static Result<PoseGraphSlamOptions> Load(ConfigReader& r);
  Status Validate() const;
};

// Reads config/pose_graph_mapper.yaml: the `slam` section, the `batch` section (used by the
// global optimisation) and the `node` section (bus settings of the process; checked always,
// returned when `node` is given). Unknown keys anywhere are errors naming file, line and key.
Status LoadSlamConfigFile(const std::string& path, PoseGraphSlamOptions* slam, BatchOptions* batch,
                          PoseGraphNodeOptions* node = nullptr);
// The same from a reader already made (e.g. ConfigReader::FromString).
Status LoadSlamConfig(ConfigReader& reader, PoseGraphSlamOptions* slam, BatchOptions* batch,
                      PoseGraphNodeOptions* node = nullptr);

struct SlamCounters {
  int64_t scans_in = 0, scans_used = 0;
  int64_t scans_time_backwards = 0, scans_too_few_beams = 0, scans_no_odom = 0;
  int64_t scans_bad_geometry = 0;  // NaN or absurd angles, mount pose or range limit
  int64_t invalid_beams = 0;       // NaN/inf or out-of-range beams skipped inside used scans
  int64_t sweeps_corrected = 0;    // used scans corrected for the base's motion in their sweep
  int64_t sweeps_uncorrected = 0;  // used scans with a sweep but no (jump-free) odometry over it
  // odom_invalid: a non-finite or absurd pose (PlausibleOdometryPose), or a stamp beyond
  // +-73,000 years (kMaxStamp).
  int64_t odom_in = 0, odom_invalid = 0, odom_out_of_order = 0, odom_jumps = 0;
  // Odometry whose newest sample was followed by a run of older, in-order samples: it was
  // stamped in the future (or the clock went back); dropped, the run taken (stamp_order.h).
  int64_t time_rebases = 0;
  // Of those, the re-bases that were the odometry source's clock set back (an NTP step, a
  // reboot): a mapped scan already stood on the newer samples, so they were real. Nothing is
  // dropped; the new clock's stamps are laid after the old ones (see AddOdometry).
  int64_t clock_steps_back = 0;
  // Scans refused as older than the last one (counted scans_time_backwards) that such a clock
  // step then put back in order, and mapped.
  int64_t scans_replayed = 0;
  int64_t keyframes = 0;
  int64_t keyframes_retired = 0;  // revisits whose scans were released (`slam.retire`)
  int64_t keyframes_removed = 0;  // retired keyframes marginalised out of the graph
  int64_t removals_refused = 0;   // retired keyframes kept in the graph (see RemoveKeyframe)
  int64_t scan_match_factors = 0, scan_match_failures = 0;
  int64_t loops_accepted = 0, loops_rejected = 0;  // accepted: loops in the graph
  int64_t loops_inconsistent = 0;  // accepted by the matcher, removed by the chi^2 gate
  // Gyro (use_gyro): yaw-rate samples received, rejected (non-finite, not newer than the last).
  int64_t imu_in = 0, imu_rejected = 0;
  // Gyro bias samples taken while the base stood still, and refused (beyond
  // gyro.bias_learning.max_rad_s: the base turned although its wheels did not).
  int64_t gyro_bias_samples = 0, gyro_bias_refused = 0, gyro_bias_uncovered = 0;
  int64_t window_updates = 0, window_failures = 0;
  // Window updates whose information matrix gave no marginal covariance (the published
  // covariance then stays the odometry-predicted one).
  int64_t covariance_failures = 0;
  int64_t global_optimizations = 0, global_failures = 0;
  int64_t global_time_limited = 0;  // global optimisations stopped by global_max_time_s
  // Absolute poses (AddAbsolutePose): received, attached at a node's exact time, spliced in as
  // a new pose node, queued for a future pose (each is later attached, spliced or rejected
  // too), rejected (older than the window / first pose, odometry no longer covering it, queue
  // full), invalid (non-finite pose, information not symmetric positive definite, a stamp
  // beyond +-73,000 years). A fix that comes while the odometry's order is in doubt (a run of
  // older samples open) and is older than the newest keyframe is held (counted queued) until
  // the run decides whether the clock went back.
  int64_t absolute_in = 0, absolute_attached = 0, absolute_spliced = 0, absolute_queued = 0;
  int64_t absolute_rejected = 0, absolute_invalid = 0;
  int64_t keyframes_for_absolute = 0;  // keyframes made only because a fix waited too long
  int64_t keyframes_for_odometry = 0;  // ... because the odometry buffer would have dropped the
                                       // newest keyframe's time (a long stay in one place)
};

enum class AbsoluteOutcome { kAttached, kSpliced, kQueued, kRejected, kInvalid };

struct ScanPose {
  int64_t scan_index = 0;
  int64_t utime = 0;
  Pose2 pose;
};

class PoseGraphSlam {
 public:
  // `clock` (may be null) times the window updates for the latency figures.
  PoseGraphSlam(const PoseGraphSlamOptions& options, const BatchOptions& batch, const Clock* clock);
  ~PoseGraphSlam();  // waits for a global optimisation still running
  PoseGraphSlam(const PoseGraphSlam&) = delete;
  PoseGraphSlam& operator=(const PoseGraphSlam&) = delete;

  // Odometry pose of the robot base in the odometry frame. Stamps are the sources' own; the
  // mapper keeps its own time line, equal to them until the odometry's clock is set back
  // (counters().clock_steps_back): from then on every input's stamp is shifted by one offset so
  // the new clock continues after the old one. Outputs (Trajectory, LastScanPose) keep the
  // scans' own stamps; keyframes().utime is on the mapper's time line.
  void AddOdometry(int64_t utime, const Pose2& odom_pose);
  // The gyro's yaw rate (rad/s, about the base's up axis) at `utime`; used with `use_gyro`.
  // False (counted) for a non-finite rate or a time not newer than the previous sample's.
  bool AddImuYawRate(int64_t utime, double yaw_rate_rad_s);
  // Odometry steps whose heading had no gyro data to fuse (use_gyro; 0 otherwise).
  uint64_t gyro_missing_steps() const { return fused_.gyro_missing_steps(); }
  // The gyro bias in use (rad/s): the configured one until one is learned standing still.
  double gyro_bias_rad_s() const { return gyro_.bias(); }
  // Returns true when the scan was accepted (it then has a pose in Trajectory()). A scan older
  // than the last one may be on a clock that went back: it is refused (scans_time_backwards)
  // but held until the next odometry sample in order, and mapped if the odometry re-bases as a
  // clock step meanwhile and the scan is stamped of the new clock's run (scans_replayed).
  bool AddScan(int64_t scan_index, const LaserScan2& scan);

  // Absolute pose of the robot base at `utime` in the map frame (the frame of the first
  // keyframe) with its information over (x_m, y_m, theta_rad); see the file comment. A
  // measurement that lands in the graph triggers a window update.
  AbsoluteOutcome AddAbsolutePose(int64_t utime, const Pose2& pose,
                                  const Eigen::Matrix3d& information);

  // Final estimate of every accepted scan: its keyframe's estimate composed with the odometry
  // motion since that keyframe.
  std::vector<ScanPose> Trajectory() const;
  // The current estimate of the newest accepted scan (what AddScan just accepted); false when
  // no scan has been accepted yet. O(1), for publishing the pose at scan rate.
  bool LastScanPose(ScanPose* out) const;
  // Covariance over (x, y, theta), in the map frame, of LastScanPose: the window's marginal
  // covariance of its keyframe (SlidingWindowOptimizer::Covariance) composed with the odometry
  // covariance since that keyframe. Computed on demand, once per window update (a dense solve
  // over the window, ~0.5 ms at N = 50), so offline runs that never ask do not pay for it. If
  // the window gives none (counted, covariance_failures), the keyframe's covariance is the
  // previous one propagated through its odometry factor. After a global optimisation the
  // window restarts anchored at its oldest pose, so from then on the covariance is relative to
  // that pose, not to the map origin. False when no scan has been accepted.
  bool LastScanCovariance(Eigen::Matrix3d* covariance);
  // Every keyframe made; one removed from the graph (`retire.remove_poses`) keeps the estimate it
  // had then (its scans follow the kept keyframes around it: Trajectory()).
  const std::vector<Keyframe>& keyframes() const { return keyframes_; }
  // The graph at the current estimates: vertex ids = node ids (keyframes and pose nodes, in
  // creation order; = keyframe indices when nothing was spliced; removed nodes left out),
  // edges = odometry, scan-match and loop factors, then the factors removals folded in. The
  // absolute factors are not g2o edges: absolute_priors().
  io::PoseGraph Graph() const;
  const std::vector<VertexPrior2>& absolute_priors() const { return priors_; }
  size_t num_nodes() const { return nodes_.size(); }  // ever made (node ids are 0..n-1)
  size_t num_live_nodes() const {
    return nodes_.size() - static_cast<size_t>(c_.keyframes_removed);
  }
  size_t num_pose_nodes() const { return nodes_.size() - keyframes_.size(); }
  size_t absolute_pending() const { return absolute_queue_.size() + held_absolute_.size(); }
  static constexpr size_t kMaxQueuedAbsolute = 1000;
  // Occupancy grid of the keyframe scans at their current estimates.
  io::GridMap RenderMap(const io::LogOddsOptions& options) const;
  // Runs a last global optimisation if loops are pending.
  void Finish();

  // Stamp of the newest odometry sample taken (INT64_MIN before the first).
  int64_t newest_odom_utime() const { return have_odom_ ? last_odom_utime_ : INT64_MIN; }
  const SlamCounters& counters() const { return c_; }
  // The odometry self-calibration (enabled or not: its counters stay 0 when off).
  const OdometryCalibrator& odometry_calibrator() const { return calibrator_; }
  const std::vector<double>& window_latency_ms() const { return window_ms_; }
  // Each global optimisation's own time (its solves, on whichever thread ran them).
  const std::vector<double>& global_latency_ms() const { return global_ms_; }
  // How long the mapper's thread waited for each one: the whole solve when it ran on the spot,
  // what was left of it at the next keyframe when it ran in the background.
  const std::vector<double>& global_wait_ms() const { return global_wait_ms_; }
  // A global optimisation launched in the background and not yet taken in (the estimates,
  // counters and latencies are those from before it until the graph next changes).
  bool global_in_flight() const { return global_ != nullptr; }
  std::map<std::string, int64_t> PluginCounters() const;

 private:
  struct KeyframeScan {
    LaserScan2 scan;             // kept for the map
    std::optional<Pose2> sweep;  // the base's motion over the lidar's sweep, when undone
  };
  // A graph vertex: a keyframe (keyframe >= 0; its estimate lives in keyframes_) or a pose
  // node created by splicing (keyframe == -1).
  struct Node {
    int64_t utime;
    int keyframe;
    Pose2 estimate;        // pose nodes only
    bool removed = false;  // marginalised out of the graph (RemoveKeyframe)
  };
  // kFolded: left by removing a node (the tree of node_removal.h), never re-linked.
  enum class LinkKind { kOdometry, kScanMatch, kLoop, kFolded };
  struct Link {
    int from, to;  // node ids
    Pose2 z;
    Eigen::Matrix3d information;
    LinkKind kind;
  };
  struct QueuedAbsolute {
    Pose2 z;
    Eigen::Matrix3d information;
  };
  struct ScanRef {
    int64_t scan_index, utime;
    int keyframe;
    Pose2 delta;  // pose at the scan in the keyframe's frame (odometry)
    // >= 0 once re-anchored by a removal: `delta` is then the estimate's, and the scan follows the
    // keyframe and the next kept one with this share (ScanPoseOf).
    double share = -1;
  };
  Pose2 ScanPoseOf(const ScanRef& s, int next_keyframe) const;  // next: -1 if none
  int NextKeptKeyframe(int k) const;  // the first keyframe after k not removed, or -1
  void RemoveRetired();               // `slam.retire.remove_poses`
  bool RemoveKeyframe(int k);         // false: kept (why in the .cc)
  void NewKeyframe(const LaserScan2& scan, int64_t utime, const RelativeMotion& motion,
                   std::vector<Eigen::Vector2d> points);
  // Attaches or splices a measurement at or before the newest node; `optimize`: update the
  // window now (false when the caller is about to).
  AbsoluteOutcome ApplyAbsolute(int64_t utime, const Pose2& z, const Eigen::Matrix3d& info,
                                bool optimize);
  void DrainAbsoluteQueue();
  Pose2 EstimateOf(int node) const;
  void SetEstimate(int node, const Pose2& pose);
  // A keyframe pair's raw odometry and scan match for the calibrator; applies a new estimate.
  void CalibrateOdometry(int64_t t0_us, int64_t t1_us, const Pose2& matched);
  // Every odometry factor still covered by the buffer, recomputed with the current calibration.
  void RelinkOdometry();
  void OptimizeWindow();
  // `last`: the final solve of Finish, without global_max_time_s (and on this thread).
  void OptimizeGlobal(bool last = false);
  struct GlobalSolve;  // one global optimisation: its copy of the graph, options and result
  // Counts, gates and takes in a finished global optimisation.
  void FinishGlobal(GlobalSolve* s);
  // Waits for the global optimisation in the background, if any, and takes it in. Called before
  // anything changes the graph.
  void JoinGlobal();
  void ResetWindow();
  void RetireRevisits();  // `slam.retire`, for keyframes old enough since the last call
  double NowMs() const;
  void TakeOdometry(int64_t utime, const Pose2& raw);  // in order: into the buffer
  // A stamp on the mapper's time line (saturating).
  int64_t OnTimeLine(int64_t utime) const;
  // The odometry's re-base at source stamp `first` (stamp_order.h): a clock set back, or
  // samples stamped in the future to drop.
  void RebaseOdometry(int64_t first);
  bool AcceptScan(int64_t scan_index, const LaserScan2& scan);  // AddScan without scans_in

  PoseGraphSlamOptions o_;
  BatchOptions batch_;
  const Clock* clock_;
  OdometrySource odom_;
  OdometryCalibrator calibrator_;
  GyroYawSource gyro_;
  OdometryGyroSource fused_{&odom_, &gyro_};
  // The continuous source every odometry factor comes from.
  const ContinuousPoseSource& Motion() const {
    return o_.use_gyro ? static_cast<const ContinuousPoseSource&>(fused_) : odom_;
  }
  bool have_odom_ = false;
  // Logs such as intel.clf stamp several messages with one time: equal stamps are nudged by
  // 1 us so the odometry buffer stays strictly ordered (internal time).
  int64_t last_odom_utime_ = 0;  // as received
  HeldRun<Pose2> odom_stream_;   // raw samples: older ones held until they re-base or give up
  struct OdomState {             // after one taken sample, for a re-base to return to
    int64_t received;            // the source's stamp
    int64_t stamp, internal;     // on the mapper's time line, before and after nudging
    Pose2 raw, corrected, correction;
  };
  StateHistory<OdomState> odom_history_;  // by `stamp`
  int64_t last_odom_stamp_ = 0;           // on the mapper's time line, before nudging
  int64_t last_odom_internal_ = 0;        // after nudging
  int64_t last_odom_period_us_ = 0;       // between the last two samples (internal)
  // Added to every input's stamp: the sum of the clock steps back (see AddOdometry); the one
  // before the last step, and the old clock's newest odometry stamp then (for late fixes).
  int64_t time_offset_ = 0, prev_time_offset_ = 0, old_clock_newest_ = 0;
  // Scans refused as older than the last accepted one since the last in-order odometry sample:
  // a clock step back replays those stamped of the new clock's run, anything else drops them.
  struct HeldScan {
    int64_t index;
    LaserScan2 scan;
  };
  std::vector<HeldScan> held_scans_;
  int64_t step_run_first_ = 0;  // the last clock step's run: its first source stamp
  // Whether a scan at `su` (time line) has odometry not in doubt while a run is open.
  bool CoveredBesideTheRun(int64_t su, int64_t gap_us) const;
  static constexpr size_t kMaxHeldScans = 16;
  bool replay_held_scans_ = false;
  bool replaying_ = false;
  // Absolute poses older than the newest keyframe that came while an older odometry run was
  // open: their clock is in doubt until the run re-bases or breaks (source stamps).
  struct HeldAbsolute {
    int64_t utime;
    Pose2 z;
    Eigen::Matrix3d information;
  };
  std::vector<HeldAbsolute> held_absolute_;
  // Queues or applies a valid fix stamped `utime` by its source (AddAbsolutePose); a fix held
  // before was counted queued already (`count_queued` false).
  AbsoluteOutcome PlaceAbsolute(int64_t utime, const Pose2& z, const Eigen::Matrix3d& info,
                                bool count_queued);
  void PlaceHeldFixes();  // the held fixes, by the clock decided now
  int last_loop_keyframe_ = -1000000;
  Pose2 last_raw_, last_corrected_, correction_;
  // The gyro's bias, learned from the corrected odometry's still stretches (internal time).
  StillGyroBias gyro_bias_;
  int64_t last_scan_utime_ = INT64_MIN;
  std::vector<Keyframe> keyframes_;
  std::vector<KeyframeScan> kf_scans_;
  // Odometry from the previous keyframe (identity for the first); after a removal, the
  // estimated pose from the previous kept keyframe at the time (see ScanPoseOf).
  std::vector<Pose2> kf_odom_;
  std::vector<int> kf_loop_;            // loops accepted at this keyframe (and still in the graph)
  int retire_next_ = 0;                 // first keyframe not yet considered for retiring
  int remove_next_ = 1;                 // first keyframe not yet considered for removal
  std::vector<size_t> kf_first_scan_;   // scans_ index of the keyframe's first scan
  std::map<int64_t, int> kf_by_utime_;  // keyframe index by time
  std::vector<Node> nodes_;             // by node id
  std::vector<int> node_of_kf_;         // keyframe index -> node id
  std::map<int64_t, int> node_by_utime_;
  std::vector<VertexPrior2> priors_;  // absolute factors on nodes
  std::multimap<int64_t, QueuedAbsolute> absolute_queue_;
  std::vector<Link> links_;
  std::vector<ScanRef> scans_;
  std::unique_ptr<SlidingWindowOptimizer> window_;
  // Covariance of the newest keyframe (predicted through its odometry factor, then the window's
  // marginal after each successful update) and of the newest scan's odometry since it.
  Eigen::Matrix3d kf_covariance_ = Eigen::Matrix3d::Zero();
  bool kf_covariance_stale_ = false;  // the window changed since kf_covariance_ was computed
  Eigen::Matrix3d last_scan_motion_covariance_ = Eigen::Matrix3d::Zero();
  KeyframeMatchPlugin match_;
  LoopClosurePlugin loop_;
  bool loops_pending_ = false;
  bool last_global_failed_ = false;    // no keyframe is retired on estimates it did not correct
  std::vector<size_t> pending_loops_;  // links_ indices of loops since the last global
  int last_global_keyframe_ = -1000000;
  bool global_cut_short_ = false;  // the last global optimisation stopped at its time limit
  std::vector<double> window_ms_, global_ms_, global_wait_ms_;
  SlamCounters c_;
  std::unique_ptr<GlobalSolve> global_;  // in the background, not yet taken in
};

}  // namespace omni::pgm
