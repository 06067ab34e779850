// Rao-Blackwellized particle filter SLAM (GMapping's class) for an omnidirectional base: the
// library behind the rbpf_mapper process and `omni slam rbpf`. No LCM, no wall clock, no global
// RNG: time comes with the data, randomness from `RbpfOptions::seed`.
//
// Per update (gated by distance / angle / time travelled): every particle draws its pose from
// the omni motion model, refines it by scan matching against its own map (improved proposal;
// a failed match falls back to the odometry sample and is counted), multiplies its weight by
// the scan likelihood at that pose and integrates the scan into its map. Then, when the
// effective sample size Neff falls below `resample_threshold * particles`, the particles are
// resampled with the low-variance resampler. Maps are TiledGrids (copy-on-write tiles shared
// between particles); paths live in a trajectory tree shared the same way (ParticlePath).
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "omni/common/config.h"
#include "omni/common/geometry.h"
#include "omni/common/gyro_bias.h"
#include "omni/common/gyro_history.h"
#include "omni/common/odometry_calibration.h"
#include "omni/common/result.h"
#include "omni/common/stamp_order.h"
#include "omni/common/time.h"
#include "omni/io/grid.h"
#include "omni/rbpf_mapper/motion_model.h"
#include "omni/rbpf_mapper/proposal.h"
#include "omni/rbpf_mapper/scan_matcher.h"
#include "omni/rbpf_mapper/thread_pool.h"
#include "omni/rbpf_mapper/tiled_grid.h"

namespace omni::rbpf {

// Which particle is the final estimate (RbpfOptions::final_particle).
enum class FinalParticle { kAncestry, kCurrent };

// How a particle's new pose follows from its scan match.
enum class ProposalKind {
  kMatch,     // the particle becomes the match optimum; weight: likelihood there
  kGaussian,  // drawn from the Gaussian fitted around the optimum (proposal.h); weight: eta
};

struct RbpfOptions {
  int particles = 30;
  int threads = 2;
  uint64_t seed = 1;
  // The grid's cell size is grid.resolution_m (fine, for a dense stream of scans) unless the
  // scans turn out to be sparse: once the base has moved `spacing_decision_m` (or the filter
  // has held `kMaxPreludeScans` scans), the mean travel per moving scan so far is compared with
  // `sparse_scan_spacing_m`; above it, the filter starts again from the first scan with cells
  // of `sparse_resolution_m` and weights tempered by `sparse_likelihood_gain` instead of
  // `likelihood_gain` (docs/rbpf.md, "The grid's cell size follows the scan spacing" and "Flat
  // weights for a dense stream"). sparse_scan_spacing_m = 0: always the dense settings.
  GridOptions grid = [] {
    GridOptions g;
    g.resolution_m = 0.025;
    return g;
  }();
  double sparse_resolution_m = 0.05;
  // likelihood_gain once the stream is found sparse: the same flat weights by default (the
  // steep 0.33 it had before lets one history take over on sparse streams, docs/rbpf.md "One
  // flat gain for sparse streams too").
  double sparse_likelihood_gain = 0.01;
  double sparse_scan_spacing_m = 0.4;
  double spacing_decision_m = 20.0;
  MotionNoise motion;
  MatcherOptions matcher;
  double linear_update_m = 0.25;    // process a scan after this much travel ...
  double angular_update_rad = 0.2;  // ... or this much turning ...
  double temporal_update_s = 0.0;   // ... or this much time (0: never on time alone)
  double resample_threshold = 0.5;  // resample when Neff < threshold * particles
  // Weight exponent on the scan likelihood. 0.01 is about GMapping's 1/(3 x particles) for 30
  // particles: flat weights, rare resampling, so the particles keep distinct histories until a
  // loop tells them apart (sparse streams use sparse_likelihood_gain, by default the same).
  double likelihood_gain = 0.01;
  // The particle whose pose is returned per scan (the process's POSE_RBPF) and whose map is
  // published stays the same lineage until another particle's log weight exceeds its own by
  // this much; 0: always the best. The weight is final_particle's: with kAncestry the weight
  // summed over the whole ancestry (so the reported particle is the final one's, give or take
  // the margin), with kCurrent the weight since the last resampling. With flat weights the
  // best changes often between particles whose paths differ, and each change is a jump of the
  // published pose (docs/rbpf.md, "Flat weights").
  double report_switch_log_margin = 3.0;
  // The particle whose path and map are the final estimate (BestTrajectory, BestMap): kAncestry
  // the highest weight summed over every update of its whole ancestry (GMapping's choice for
  // its final map); kCurrent the heaviest since the last resampling (best_index()). With flat
  // weights the weights since a resampling hardly differ, and the whole path's weight is the
  // better judge (docs/rbpf.md, "The final particle by its whole path's weight").
  FinalParticle final_particle = FinalParticle::kAncestry;
  ProposalKind proposal = ProposalKind::kMatch;
  ProposalGridOptions proposal_grid;  // kGaussian: the points the Gaussian is fitted on
  bool proposal_draw = true;  // kGaussian: draw the pose (false: keep the optimum, weigh by eta)
  bool proposal_keep_best = false;   // kGaussian: the best particle takes the optimum, undrawn
  double proposal_sigma_xy_m = 0.0;  // kMatch: noise drawn around the matched pose
  double proposal_sigma_theta_rad = 0.0;
  int min_valid_beams = 20;       // scans with fewer valid returns are rejected
  double max_range_m = 30.0;      // returns at or beyond this are "no return"
  double max_hit_range_m = 25.0;  // longer returns clear free space but are not walls
  double max_free_range_m = 0.0;  // > 0: no-return beams clear free space up to this
  double max_odom_jump_m = 3.0;   // larger odometry increments between scans are jumps
  double max_odom_jump_rad = 2.0;
  double max_odom_gap_s = 0.5;  // scan without its own odometry: max distance in time
  bool use_imu = false;         // fuse the gyro's yaw increment into the motion model
  // The gyro's bias (rad/s), taken out of its yaw increments; learned while the odometry says
  // the base stands still (omni/common/gyro_bias.h), this is where the estimate starts.
  double imu_bias_rad_s = 0.0;
  GyroBiasOptions imu_bias_learning;
  // Odometry self-calibration (common/odometry_calibration.h): fitted to the best particle's
  // matched increments, taken out of each odometry increment before the motion model.
  OdometryCalibratorOptions odometry_calibration;
  std::string scan_channel = "LIDAR_SCAN";
  std::string odom_channel = "WHEEL_ODOM";
  std::string imu_channel = "IMU";
  std::string pose_channel = "POSE_RBPF";
  std::string grid_channel = "GRID_RBPF";
  // The reported particle's whole path (trajectory_t, thinned by bus::ThinTrajectoryMessage), so
  // a consumer posed by POSE_RBPF can re-pose what it placed when that path changes (the OctoMap
  // builder's `repose`).
  std::string trajectory_channel = "TRAJECTORY_RBPF";
  double grid_publish_interval_s = 5.0;
  double trajectory_publish_interval_s = 2.0;  // 0: only at exit
  // The published grid's cell size: a finer map is published on cells an integer multiple of
  // its own (the multiple nearest this size; each takes the largest value it covers, so walls
  // stay), a quarter of the bytes for 2.5 cm cells. 0: the map's own cells. Map files on disk
  // always keep the map's own cells.
  double grid_publish_resolution_m = 0.05;

  // Reads the keys (all optional) from `reader` and calls Finish(); errors name the key.
  static Result<RbpfOptions> Load(ConfigReader& reader);
  // Cross-field checks; the message names the violated rule.
  Status Validate() const;
};

struct RbpfCounters {
  int64_t scans_in = 0;
  int64_t scans_processed = 0;     // particle filter updates
  int64_t sweeps_corrected = 0;    // updates whose scan was corrected for the sweep's motion
  int64_t sweeps_uncorrected = 0;  // ... that had a sweep but no odometry over all of it
  int64_t scans_gated = 0;         // not enough motion since the last update (pose from odometry)
  int64_t scans_too_few_beams = 0;
  int64_t scans_time_backwards = 0;
  // A stream (scans, odometry, IMU) whose newest stamp was followed by a run of older, in-order
  // stamps: the newest was stamped in the future or the source's clock went back, and the stream
  // continues from the run (common/stamp_order.h).
  int64_t time_rebases = 0;
  int64_t scans_no_odom = 0;
  int64_t scans_bad_geometry = 0;  // non-finite angles / mount
  int64_t invalid_beams = 0;       // NaN, inf, negative or below range_min
  int64_t odom_in = 0;
  int64_t odom_invalid = 0;  // non-finite or absurd pose (PlausibleOdometryPose)
  int64_t odom_out_of_order = 0;
  int64_t odom_jumps = 0;
  int64_t imu_in = 0;
  int64_t imu_invalid = 0;
  // Gyro bias samples taken while the base stood still, and refused (the base turned beyond
  // imu_bias_learning.max_rad_s although its wheels did not).
  int64_t imu_bias_samples = 0, imu_bias_refused = 0, imu_bias_uncovered = 0;
  // use_imu: filter updates whose interval the gyro did not cover (its samples late or
  // missing), which fell back to the odometry's turn.
  int64_t imu_uncovered_updates = 0;
  int64_t match_failures = 0;  // particle updates that fell back to odometry
  int64_t match_searches = 0;  // particle updates that needed the correlative search
  int64_t resamplings = 0;
  int64_t reported_switches = 0;  // the reported particle became another lineage
};

// How the grid's cell size and the likelihood gain were chosen
// (RbpfOptions::sparse_scan_spacing_m).
struct ResolutionChoice {
  bool decided = false;   // false while the first spacing_decision_m are being travelled
  bool switched = false;  // started again with sparse_resolution_m and sparse_likelihood_gain
  double travel_m = 0;    // odometry travel over the moving scans measured (steps > 1 cm)
  int64_t moving_scans = 0;
  double spacing_m() const {
    return moving_scans > 0 ? travel_m / static_cast<double>(moving_scans) : 0.0;
  }
};

// One laser scan as the filter takes it.
struct ScanInput {
  int64_t utime = 0;
  Pose2 sensor_in_base;
  float angle_min_rad = 0;
  float angle_increment_rad = 0;
  float range_min_m = 0;
  float range_max_m = 0;  // readings at or above: no return
  std::vector<float> ranges_m;
  // First to last beam. > 0 (a spinning lidar): each end point is corrected for the base's
  // motion during the sweep, from odometry, when odometry covers the last beam's time.
  float scan_time_s = 0;
  std::optional<Pose2> odom;  // the base's odometry pose at this scan, when the source has it
};

// A stretch of consecutive updates of one lineage (the particle's pose after each). It continues
// `parent`'s first `parent_len` entries. Only a particle that holds it alone appends to it; once
// resampling gives it to several children it is never changed again, and each child goes on in a
// new segment.
struct PathSegment {
  std::shared_ptr<PathSegment> parent;
  size_t parent_len = 0;
  std::vector<Pose2> entries;
  ~PathSegment();  // releases long parent chains iteratively (no deep recursion)
};

// A particle's path: its pose after every filter update, as a chain of segments shared with the
// other particles of its ancestry (the trajectory tree). Copying it (resampling) is O(1);
// appending is amortised O(1). Between resamplings a pose costs 24 bytes (a tree node per update
// and particle cost about 80 with its control block before); each child a resampling branches
// off opens a segment (about 100 bytes with its first pose), so a filter that resamples after
// nearly every update costs about as much per pose as the node did.
class ParticlePath {
 public:
  ParticlePath() = default;
  ParticlePath(const ParticlePath&) = default;
  ParticlePath& operator=(const ParticlePath&) = default;
  // A moved-from path is empty.
  ParticlePath(ParticlePath&& o) noexcept
      : seg_(std::move(o.seg_)), len_(std::exchange(o.len_, 0)), size_(std::exchange(o.size_, 0)) {}
  ParticlePath& operator=(ParticlePath&& o) noexcept {
    seg_ = std::move(o.seg_);
    len_ = std::exchange(o.len_, 0);
    size_ = std::exchange(o.size_, 0);
    return *this;
  }
  void Append(const Pose2& pose);
  size_t size() const { return size_; }
  // The last pose and the one before it; null when the path is shorter.
  const Pose2* Last() const { return At(1); }
  const Pose2* BeforeLast() const { return At(2); }
  // Every pose, oldest first.
  std::vector<Pose2> Poses() const;
  // The same path (siblings right after a resampling, before either moves on).
  bool SameAs(const ParticlePath& o) const { return seg_ == o.seg_ && len_ == o.len_; }
  // Before the path is shared: its own segment gives back its spare capacity.
  void Freeze();
  // Segments on the path (for tests and memory accounting); the newest, null when empty.
  size_t segments() const;
  const PathSegment* tip() const { return seg_.get(); }
  // A segment's length is capped so that growing one never copies much at once.
  static constexpr size_t kMaxSegment = 1024;

 private:
  const Pose2* At(size_t from_end) const;
  std::shared_ptr<PathSegment> seg_;
  size_t len_ = 0;   // poses of seg_ on this path
  size_t size_ = 0;  // poses on the whole path
};

struct Particle {
  Pose2 pose;
  double log_weight = 0;       // since the last resampling
  double path_log_weight = 0;  // every update's factor over the whole ancestry (shifted together)
  TiledGrid map;
  ParticlePath path;
  std::mt19937_64 rng;
};

struct ScanResult {
  bool accepted = false;   // the scan has a pose (processed or placed by odometry)
  bool processed = false;  // a particle filter update ran
  // The map frame exists (the filter has made its first update, which anchors it). Before it,
  // `pose` is the raw odometry: the frame is not known yet, so it is no map pose to publish.
  bool in_map_frame = false;
  int64_t scan_index = -1;
  Pose2 pose;  // best particle's estimate of the base
};

struct EstimatedPose {
  int64_t scan_index;
  int64_t utime;
  Pose2 pose;
};

// Effective sample size of normalised weights: 1 / sum(w^2).
double EffectiveSampleSize(const std::vector<double>& normalized_weights);
// Low-variance (systematic) resampling: `n` indices drawn with probability proportional to the
// normalised weights, using one uniform offset from `rng`.
std::vector<int> LowVarianceResample(const std::vector<double>& normalized_weights, int n,
                                     std::mt19937_64& rng);

// One particle's draw from the improved proposal (kGaussian): the Gaussian fitted to
// p(z | m, x)^likelihood_gain * p(x | from, delta) around the match `optimum`, the pose drawn from
// it, and the log weight factor log(eta).
struct ProposalDraw {
  Pose2 pose;
  double log_weight = 0;
  GaussianProposal gaussian;
};
ProposalDraw DrawImprovedProposal(const ScanMatcher& matcher, const OmniMotionModel& motion,
                                  const TiledGrid& map, const MatchScan& scan, const Pose2& from,
                                  const Pose2& delta, std::optional<double> imu_dtheta_rad,
                                  const Pose2& optimum, double likelihood_gain,
                                  const ProposalGridOptions& grid, std::mt19937_64& rng);

class RbpfSlam {
 public:
  explicit RbpfSlam(const RbpfOptions& options);

  bool AddOdometry(int64_t utime, const Pose2& pose);
  // The raw odometry at `utime` from what AddOdometry has received so far (interpolated, or
  // the nearest sample within max_odom_gap_s), as AddScan would look it up now.
  // Odometry samples further apart than this bound a gap (the driver was down, or the later
  // sample is stamped in the future): no pose is interpolated across it.
  static constexpr int64_t kMaxOdomSpanUs = 10000000;
  std::optional<Pose2> RawOdometryAt(int64_t utime) const;
  // Forgets the newest scan stamp: the next scan is in order whatever its time (the process
  // calls it when its scan stream re-based, so the held run is not refused again here).
  void RestartScanOrder();
  // Stamp of the newest odometry sample held (0 before the first).
  int64_t newest_odom_utime() const { return odom_buffer_.newest_utime(); }
  // How far the odometry covers scans: the newest sample that continues the ones before it
  // (within kMaxOdomSpanUs). A lone sample far ahead (stamped in the future, dropped once the
  // stream re-bases) does not cover the scans stamped before it: they wait for the samples that
  // bracket them, instead of taking the last good sample as theirs.
  int64_t covered_odom_utime() const { return covered_odom_utime_; }
  // Gyro yaw rate about the base's z axis (rad/s, CCW).
  bool AddImuYawRate(int64_t utime, double yaw_rate_rad_s);
  // The gyro bias in use (rad/s): imu_bias_rad_s until one is learned standing still.
  double imu_bias_rad_s() const { return imu_bias_.bias(); }
  ScanResult AddScan(const ScanInput& scan);

  // The best particle: the heaviest after the last update, or, when that update resampled (every
  // weight is then equal), the heaviest's child.
  int best_index() const { return best_lineage_; }
  Pose2 BestPose() const { return particles_[static_cast<size_t>(best_index())].pose; }
  // The final estimate's particle (RbpfOptions::final_particle); BestMap and BestTrajectory
  // are its map and path.
  int final_index() const;
  io::GridMap BestMap() const {
    return particles_[static_cast<size_t>(final_index())].map.ToGridMap();
  }
  // The reported particle (RbpfOptions::report_switch_log_margin): its pose is the one AddScan
  // returns; the process publishes its map. It follows final_particle's weight.
  int reported_index() const { return reported_lineage_; }
  Pose2 ReportedPose() const { return particles_[static_cast<size_t>(reported_lineage_)].pose; }
  io::GridMap ReportedMap() const {
    return particles_[static_cast<size_t>(reported_lineage_)].map.ToGridMap();
  }
  // The best particle's path at every accepted scan (processed scans from its trajectory tree,
  // the others placed by odometry relative to the nearest processed scan).
  std::vector<EstimatedPose> BestTrajectory() const { return TrajectoryOf(final_index()); }
  // The reported particle's path, the same way: what POSE_RBPF would have carried had the
  // particle's present estimate been known at each scan.
  std::vector<EstimatedPose> ReportedTrajectory() const { return TrajectoryOf(reported_lineage_); }
  std::vector<EstimatedPose> TrajectoryOf(int particle) const;
  const std::vector<Particle>& particles() const { return particles_; }
  const RbpfCounters& counters() const { return counters_; }
  // The options in use: grid.resolution_m is the cell size chosen (see ResolutionChoice).
  const RbpfOptions& options() const { return opt_; }
  const ResolutionChoice& resolution_choice() const { return choice_; }
  // Until the cell size is decided, the inputs are kept to be run again, bounded by this many
  // scans and this many inputs of any kind (then the spacing measured so far decides).
  static constexpr int64_t kMaxPreludeScans = 3000;
  static constexpr size_t kMaxPreludeEvents = 100000;
  const OdometryCalibrator& odometry_calibrator() const { return calibrator_; }
  // Tiles referenced by all particles, and distinct tile objects among them.
  size_t total_tile_refs() const;
  size_t distinct_tiles() const { return map_memory().tiles; }
  // The particles' maps in memory: distinct tiles, how many of them are packed, and the bytes
  // they hold (malloc's own headers not counted).
  struct MapMemory {
    size_t tiles = 0;
    size_t packed = 0;
    size_t bytes = 0;
  };
  MapMemory map_memory() const;
  // The particles' paths in memory: distinct poses and segments, and the bytes they hold (with
  // the segments' spare capacity; malloc's own headers not counted).
  struct PathMemory {
    size_t poses = 0;
    size_t segments = 0;
    size_t bytes = 0;
  };
  PathMemory path_memory() const;

 private:
  struct ScanRecord {
    int64_t index;
    int64_t utime;
    Pose2 odom;  // jump-free odometry
    bool processed;
  };
  struct OdomEvent {
    int64_t utime;
    Pose2 pose;
  };
  struct ImuEvent {
    int64_t utime;
    double rate;
  };
  struct RestartEvent {};
  using PreludeEvent = std::variant<OdomEvent, ImuEvent, ScanInput, RestartEvent>;
  // Every mutable member back to its state after construction with `options`.
  void Reset(const RbpfOptions& options);
  void InitParticles();
  ScanResult AddScanImpl(const ScanInput& scan);
  // Measures the spacing from an accepted scan's jump-free odometry; decides once enough is in.
  void MeasureSpacing(const Pose2& odom);
  // Called after each scan while undecided: decides when due, and when the scans are sparse
  // runs every input again at sparse_resolution_m; returns the (possibly re-run) result.
  // `force`: decide now whatever has been travelled.
  ScanResult MaybeDecide(const ScanResult& r, bool force = false);
  std::optional<Pose2> CorrectedOdom(const ScanInput& scan);
  // A raw odometry step with the calibration's systematic error taken out (when enabled).
  Pose2 CalibratedStep(const Pose2& raw) const;
  // The gyro's heading change over [t0, t1] with its bias taken out; as measured (Raw).
  std::optional<double> ImuYawIncrement(int64_t t0, int64_t t1) const;
  std::optional<double> ImuRawIncrement(int64_t t0, int64_t t1) const;
  void Update(const ScanInput& scan, const Pose2& odom, bool first);
  void Resample();
  // The particle with the largest weight now (the first on a tie).
  int HeaviestIndex() const;
  // The particle the reported one would switch to, and the weight the switch compares
  // (final_particle's: the whole ancestry's, or since the last resampling).
  int ReportCandidate() const;
  double ReportWeight(int i) const;

  RbpfOptions opt_;
  OmniMotionModel motion_;
  ScanMatcher matcher_;
  ThreadPool pool_;
  std::mt19937_64 master_rng_;
  std::vector<Particle> particles_;
  RbpfCounters counters_;
  StampedBuffer<Pose2> odom_buffer_;
  GyroRateHistory imu_{100000};  // the gyro's yaw rates as measured
  StillGyroBias imu_bias_;       // learned from the odometry's still stretches
  std::vector<ScanRecord> records_;
  int64_t next_scan_index_ = 0;
  StampOrder scan_order_;
  std::optional<Pose2> last_raw_odom_;  // raw odometry of the previous accepted scan
  int64_t last_raw_odom_utime_ = 0;     // ... and that scan's stamp
  Pose2 odom_correction_;               // jump-free odometry = correction * raw
  bool have_update_ = false;
  int64_t covered_odom_utime_ = 0;  // covered_odom_utime()
  OdometryCalibrator calibrator_;
  int64_t odom_jumps_at_update_ = 0;  // counters_.odom_jumps at the last update
  int best_lineage_ = 0;              // the particle that descends from the last update's best
  int reported_lineage_ = 0;          // the reported particle (report_switch_log_margin)
  Pose2 last_update_odom_;
  int64_t last_update_utime_ = 0;
  // Cell-size choice (kept across Reset) and the inputs held until it is made.
  ResolutionChoice choice_;
  std::optional<Pose2> spacing_prev_odom_;
  std::vector<PreludeEvent> prelude_;
  int64_t prelude_scans_ = 0;
};

}  // namespace omni::rbpf
