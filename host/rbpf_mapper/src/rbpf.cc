#include "omni/rbpf_mapper/rbpf.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_set>

#include "omni/common/scan_checks.h"

namespace omni::rbpf {

PathSegment::~PathSegment() {
  // Unlink the chain iteratively: a long path would otherwise be released recursively.
  std::shared_ptr<PathSegment> p = std::move(parent);
  while (p && p.use_count() == 1) {
    std::shared_ptr<PathSegment> next = std::move(p->parent);
    p = std::move(next);
  }
}

void ParticlePath::Append(const Pose2& pose) {
  // In place only when no other path or segment can see this segment. During an update the
  // particles append on several threads; a segment two particles hold stays at a count of at
  // least two for both (a new segment keeps its parent), so neither writes to it.
  if (!seg_ || seg_.use_count() != 1 || len_ != seg_->entries.size() || len_ >= kMaxSegment) {
    auto next = std::make_shared<PathSegment>();
    next->parent = std::move(seg_);
    next->parent_len = len_;
    seg_ = std::move(next);
    len_ = 0;
  }
  seg_->entries.push_back(pose);
  ++len_;
  ++size_;
}

void ParticlePath::Freeze() {
  if (seg_ && seg_.use_count() == 1 && len_ == seg_->entries.size()) seg_->entries.shrink_to_fit();
}

const Pose2* ParticlePath::At(size_t from_end) const {
  const PathSegment* s = seg_.get();
  size_t len = len_;
  while (s) {
    if (from_end <= len) return &s->entries[len - from_end];
    from_end -= len;
    len = s->parent_len;
    s = s->parent.get();
  }
  return nullptr;
}

size_t ParticlePath::segments() const {
  size_t n = 0;
  for (const PathSegment* s = seg_.get(); s; s = s->parent.get()) ++n;
  return n;
}

std::vector<Pose2> ParticlePath::Poses() const {
  std::vector<Pose2> out(size_);
  size_t end = size_;
  size_t len = len_;
  for (const PathSegment* s = seg_.get(); s; len = s->parent_len, s = s->parent.get()) {
    end -= len;
    std::copy(s->entries.begin(), s->entries.begin() + static_cast<std::ptrdiff_t>(len),
              out.begin() + static_cast<std::ptrdiff_t>(end));
  }
  return out;
}

double EffectiveSampleSize(const std::vector<double>& w) {
  double s = 0;
  for (double v : w) s += v * v;
  return s > 0 ? 1.0 / s : 0.0;
}

std::vector<int> LowVarianceResample(const std::vector<double>& w, int n, std::mt19937_64& rng) {
  std::vector<int> out;
  out.reserve(static_cast<size_t>(n));
  if (w.empty() || n <= 0) return out;
  std::uniform_real_distribution<double> u01(0.0, 1.0 / n);
  const double r = u01(rng);
  double c = w[0];
  size_t i = 0;
  for (int m = 0; m < n; ++m) {
    const double target = r + static_cast<double>(m) / n;
    while (target > c && i + 1 < w.size()) c += w[++i];
    out.push_back(static_cast<int>(i));
  }
  return out;
}

Result<RbpfOptions> RbpfOptions::Load(ConfigReader& r) {
  RbpfOptions o;
  r.Get("particles", &o.particles, Optional(), InRange(1, 1000));
  r.Get("threads", &o.threads, Optional(), InRange(1, 256));
  int64_t seed = static_cast<int64_t>(o.seed);
  r.Get("seed", &seed, Optional(), NonNegative<int64_t>());
  o.seed = static_cast<uint64_t>(seed);
  r.Get("linear_update_m", &o.linear_update_m, Optional(), NonNegative<double>());
  r.Get("angular_update_rad", &o.angular_update_rad, Optional(), NonNegative<double>());
  r.Get("temporal_update_s", &o.temporal_update_s, Optional(), NonNegative<double>());
  r.Get("resample_threshold", &o.resample_threshold, Optional(), InRange(0.0, 1.0));
  r.Get("likelihood_gain", &o.likelihood_gain, Optional(), InRange(1e-6, 100.0));
  r.Get("sparse_likelihood_gain", &o.sparse_likelihood_gain, Optional(), InRange(1e-6, 100.0));
  r.Get("report_switch_log_margin", &o.report_switch_log_margin, Optional(), InRange(0.0, 1000.0));
  std::string final_particle = o.final_particle == FinalParticle::kCurrent ? "current" : "ancestry";
  r.Get("final_particle", &final_particle, Optional(), OneOf({"ancestry", "current"}));
  o.final_particle =
      final_particle == "current" ? FinalParticle::kCurrent : FinalParticle::kAncestry;
  std::string proposal = o.proposal == ProposalKind::kGaussian ? "gaussian" : "match";
  r.Get("proposal", &proposal, Optional(), OneOf({"match", "gaussian"}));
  o.proposal = proposal == "gaussian" ? ProposalKind::kGaussian : ProposalKind::kMatch;
  r.Get("proposal_steps", &o.proposal_grid.steps, Optional(), InRange(0, 5));
  r.Get("proposal_step_xy_m", &o.proposal_grid.step_xy_m, Optional(), InRange(1e-4, 0.5));
  r.Get("proposal_step_theta_rad", &o.proposal_grid.step_theta_rad, Optional(), InRange(1e-5, 0.5));
  r.Get("proposal_draw", &o.proposal_draw, Optional());
  r.Get("proposal_keep_best", &o.proposal_keep_best, Optional());
  r.Get("proposal_sigma_xy_m", &o.proposal_sigma_xy_m, Optional(), NonNegative<double>());
  r.Get("proposal_sigma_theta_rad", &o.proposal_sigma_theta_rad, Optional(), NonNegative<double>());
  r.Get("min_valid_beams", &o.min_valid_beams, Optional(), InRange(1, 100000));
  r.Get("max_range_m", &o.max_range_m, Optional(), Positive<double>());
  r.Get("max_hit_range_m", &o.max_hit_range_m, Optional(), Positive<double>());
  r.Get("max_free_range_m", &o.max_free_range_m, Optional(), NonNegative<double>());
  r.Get("max_odom_jump_m", &o.max_odom_jump_m, Optional(), Positive<double>());
  r.Get("max_odom_jump_rad", &o.max_odom_jump_rad, Optional(), Positive<double>());
  r.Get("max_odom_gap_s", &o.max_odom_gap_s, Optional(), InRange(0.0, 60.0));
  r.Get("use_imu", &o.use_imu, Optional());
  r.Get("imu_bias_rad_s", &o.imu_bias_rad_s, Optional());
  ReadGyroBiasOptions(r.Section("imu_bias_learning"), &o.imu_bias_learning);
  r.Get("scan_channel", &o.scan_channel, Optional(), NonEmpty());
  r.Get("odom_channel", &o.odom_channel, Optional(), NonEmpty());
  r.Get("imu_channel", &o.imu_channel, Optional(), NonEmpty());
  r.Get("pose_channel", &o.pose_channel, Optional(), NonEmpty());
  r.Get("grid_channel", &o.grid_channel, Optional(), NonEmpty());
  r.Get("trajectory_channel", &o.trajectory_channel, Optional(), NonEmpty());
  r.Get("grid_publish_interval_s", &o.grid_publish_interval_s, Optional(), InRange(0.05, 3600.0));
  r.Get("trajectory_publish_interval_s", &o.trajectory_publish_interval_s, Optional(),
        InRange(0.0, 3600.0));
  r.Get("grid_publish_resolution_m", &o.grid_publish_resolution_m, Optional(), InRange(0.0, 1.0));
  ConfigReader oc = r.Section("odometry_calibration");
  ReadOdometryCalibratorOptions(oc, &o.odometry_calibration, /*graph_keys=*/false);
  auto g = r.Section("grid");
  g.Get("resolution_m", &o.grid.resolution_m, Optional(), InRange(0.005, 1.0));
  g.Get("sparse_resolution_m", &o.sparse_resolution_m, Optional(), InRange(0.005, 1.0));
  g.Get("sparse_scan_spacing_m", &o.sparse_scan_spacing_m, Optional(), InRange(0.0, 100.0));
  g.Get("spacing_decision_m", &o.spacing_decision_m, Optional(), InRange(0.1, 10000.0));
  // The grid keeps log odds in thousandths within +-30 (tiled_grid.h).
  constexpr float kMax = TiledGrid::kMaxLogOdds, kStep = TiledGrid::kLogOddsStep;
  g.Get("hit_log_odds", &o.grid.hit_log_odds, Optional(), InRange(kStep, kMax));
  g.Get("miss_log_odds", &o.grid.miss_log_odds, Optional(), InRange(-kMax, -kStep));
  g.Get("min_log_odds", &o.grid.min_log_odds, Optional(), InRange(-kMax, -kStep));
  g.Get("max_log_odds", &o.grid.max_log_odds, Optional(), InRange(kStep, kMax));
  g.Get("occupied_threshold", &o.grid.occupied_threshold, Optional(), InRange(-kMax, kMax));
  g.Get("free_threshold", &o.grid.free_threshold, Optional(), InRange(-kMax, kMax));
  g.Get("pack_idle_scans", &o.grid.pack_idle_scans, Optional(), InRange(0, 1000000));
  auto m = r.Section("motion");
  m.Get("a_xx", &o.motion.a_xx, Optional(), NonNegative<double>());
  m.Get("a_xy", &o.motion.a_xy, Optional(), NonNegative<double>());
  m.Get("a_xt", &o.motion.a_xt, Optional(), NonNegative<double>());
  m.Get("a_yx", &o.motion.a_yx, Optional(), NonNegative<double>());
  m.Get("a_yy", &o.motion.a_yy, Optional(), NonNegative<double>());
  m.Get("a_yt", &o.motion.a_yt, Optional(), NonNegative<double>());
  m.Get("a_tt", &o.motion.a_tt, Optional(), NonNegative<double>());
  m.Get("a_td", &o.motion.a_td, Optional(), NonNegative<double>());
  m.Get("min_xy_m", &o.motion.min_xy_m, Optional(), NonNegative<double>());
  m.Get("min_theta_rad", &o.motion.min_theta_rad, Optional(), NonNegative<double>());
  m.Get("imu_yaw_sigma_per_rad", &o.motion.imu_yaw_sigma_per_rad, Optional(),
        NonNegative<double>());
  m.Get("imu_yaw_sigma_min_rad", &o.motion.imu_yaw_sigma_min_rad, Optional(), Positive<double>());
  auto s = r.Section("matcher");
  s.Get("kernel_cells", &o.matcher.kernel_cells, Optional(), InRange(0, 5));
  s.Get("sigma_score_m", &o.matcher.sigma_score_m, Optional(), Positive<double>());
  s.Get("sigma_likelihood_m", &o.matcher.sigma_likelihood_m, Optional(), Positive<double>());
  s.Get("null_log_likelihood", &o.matcher.null_log_likelihood, Optional(), InRange(-1e3, 0.0));
  s.Get("beam_step", &o.matcher.beam_step, Optional(), InRange(1, 100));
  s.Get("max_match_range_m", &o.matcher.max_match_range_m, Optional(), Positive<double>());
  s.Get("refine_step_xy_m", &o.matcher.refine_step_xy_m, Optional(), Positive<double>());
  s.Get("refine_step_theta_rad", &o.matcher.refine_step_theta_rad, Optional(), Positive<double>());
  s.Get("refine_halvings", &o.matcher.refine_halvings, Optional(), InRange(0, 20));
  s.Get("search_xy_m", &o.matcher.search_xy_m, Optional(), InRange(0.0, 5.0));
  s.Get("search_theta_rad", &o.matcher.search_theta_rad, Optional(), InRange(0.0, 3.2));
  s.Get("search_theta_step_rad", &o.matcher.search_theta_step_rad, Optional(), InRange(1e-4, 1.0));
  s.Get("search_beam_step", &o.matcher.search_beam_step, Optional(), InRange(1, 100));
  s.Get("search_below_fraction", &o.matcher.search_below_fraction, Optional(), InRange(0.0, 1.0));
  s.Get("prior_weight", &o.matcher.prior_weight, Optional(), NonNegative<double>());
  s.Get("min_match_fraction", &o.matcher.min_match_fraction, Optional(), InRange(0.0, 1.0));
  if (o.max_hit_range_m > o.max_range_m) r.AddError("max_hit_range_m", "must be <= max_range_m");
  if (o.grid.min_log_odds >= o.grid.max_log_odds)
    r.AddError("grid.min_log_odds", "must be < grid.max_log_odds");
  if (Status st = r.Finish(); !st.ok()) return st.error();
  if (Status st = o.Validate(); !st.ok()) return st.error();
  return o;
}

Status RbpfOptions::Validate() const {
  auto bad = [](const std::string& m) { return MakeError(ErrorCode::kInvalidArgument, m); };
  if (particles < 1) return bad("particles must be >= 1");
  if (threads < 1) return bad("threads must be >= 1");
  if (!(grid.resolution_m > 0)) return bad("grid.resolution_m must be > 0");
  if (!(sparse_resolution_m > 0)) return bad("grid.sparse_resolution_m must be > 0");
  if (!(likelihood_gain > 0)) return bad("likelihood_gain must be > 0");
  if (!(sparse_likelihood_gain > 0)) return bad("sparse_likelihood_gain must be > 0");
  if (!(sparse_scan_spacing_m >= 0)) return bad("grid.sparse_scan_spacing_m must be >= 0");
  if (!(spacing_decision_m > 0)) return bad("grid.spacing_decision_m must be > 0");
  if (!(grid.free_threshold <= grid.occupied_threshold))
    return bad("grid.free_threshold must be <= grid.occupied_threshold");
  if (grid.pack_idle_scans < 0) return bad("grid.pack_idle_scans must be >= 0");
  // The grid keeps log odds in thousandths within +-30 (tiled_grid.h).
  auto within = [](float v, float lo, float hi) { return v >= lo && v <= hi; };
  constexpr float kMax = TiledGrid::kMaxLogOdds, kStep = TiledGrid::kLogOddsStep;
  if (!within(grid.hit_log_odds, kStep, kMax))
    return bad("grid.hit_log_odds must be in [0.001, 30]");
  if (!within(grid.miss_log_odds, -kMax, -kStep))
    return bad("grid.miss_log_odds must be in [-30, -0.001]");
  if (!within(grid.min_log_odds, -kMax, -kStep))
    return bad("grid.min_log_odds must be in [-30, -0.001]");
  if (!within(grid.max_log_odds, kStep, kMax))
    return bad("grid.max_log_odds must be in [0.001, 30]");
  if (!within(grid.occupied_threshold, -kMax, kMax) || !within(grid.free_threshold, -kMax, kMax))
    return bad("grid thresholds must be in [-30, 30]");
  if (!(max_hit_range_m <= max_range_m)) return bad("max_hit_range_m must be <= max_range_m");
  if (!(grid_publish_resolution_m >= 0)) return bad("grid_publish_resolution_m must be >= 0");
  return Status::Ok();
}

ProposalDraw DrawImprovedProposal(const ScanMatcher& matcher, const OmniMotionModel& motion,
                                  const TiledGrid& map, const MatchScan& scan, const Pose2& from,
                                  const Pose2& delta, std::optional<double> imu_dtheta,
                                  const Pose2& optimum, double gain,
                                  const ProposalGridOptions& grid, std::mt19937_64& rng) {
  ProposalDraw d;
  d.gaussian = FitGaussianProposal(optimum, grid, [&](const Pose2& x) {
    return gain * matcher.Score(map, x, scan).log_likelihood +
           motion.LogDensity(from, delta, x, imu_dtheta);
  });
  d.pose = DrawPose(d.gaussian, rng);
  d.log_weight = d.gaussian.log_normalizer;
  return d;
}

RbpfSlam::RbpfSlam(const RbpfOptions& options)
    : opt_(options),
      motion_(options.motion),
      matcher_(options.matcher, options.grid.resolution_m),
      pool_(options.threads),
      master_rng_(options.seed),
      odom_buffer_(100000),
      imu_bias_(options.imu_bias_learning, options.imu_bias_rad_s),
      calibrator_(options.odometry_calibration) {
  InitParticles();
  choice_.decided =
      !(opt_.sparse_scan_spacing_m > 0) || (opt_.sparse_resolution_m == opt_.grid.resolution_m &&
                                            opt_.sparse_likelihood_gain == opt_.likelihood_gain);
}

void RbpfSlam::InitParticles() {
  particles_.clear();
  particles_.resize(static_cast<size_t>(std::max(1, opt_.particles)));
  for (size_t i = 0; i < particles_.size(); ++i) {
    particles_[i].map = TiledGrid(opt_.grid);
    std::seed_seq seq{opt_.seed, static_cast<uint64_t>(i), uint64_t{0x5eed}};
    particles_[i].rng.seed(seq);
  }
}

void RbpfSlam::Reset(const RbpfOptions& o) {
  opt_ = o;
  motion_ = OmniMotionModel(o.motion);
  matcher_ = ScanMatcher(o.matcher, o.grid.resolution_m);
  master_rng_.seed(o.seed);
  counters_ = RbpfCounters{};
  odom_buffer_ = StampedBuffer<Pose2>(100000);
  covered_odom_utime_ = 0;
  imu_.Reset();
  imu_bias_ = StillGyroBias(o.imu_bias_learning, o.imu_bias_rad_s);
  records_.clear();
  next_scan_index_ = 0;
  scan_order_ = StampOrder();
  last_raw_odom_.reset();
  last_raw_odom_utime_ = 0;
  odom_correction_ = Pose2();
  have_update_ = false;
  calibrator_ = OdometryCalibrator(o.odometry_calibration);
  odom_jumps_at_update_ = 0;
  best_lineage_ = 0;
  reported_lineage_ = 0;
  last_update_odom_ = Pose2();
  last_update_utime_ = 0;
  InitParticles();
}

void RbpfSlam::RestartScanOrder() {
  if (!choice_.decided) prelude_.emplace_back(RestartEvent{});
  scan_order_.Reset();
}

void RbpfSlam::MeasureSpacing(const Pose2& odom) {
  if (spacing_prev_odom_) {
    const Pose2 d = spacing_prev_odom_->Between(odom);
    const double step = std::hypot(d.x, d.y);
    if (step > 0.01) {  // standing still says nothing about the spacing
      choice_.travel_m += step;
      ++choice_.moving_scans;
    }
  }
  spacing_prev_odom_ = odom;
}

ScanResult RbpfSlam::MaybeDecide(const ScanResult& r, bool force) {
  if (!force && choice_.travel_m < opt_.spacing_decision_m && prelude_scans_ < kMaxPreludeScans)
    return r;
  choice_.decided = true;
  std::vector<PreludeEvent> events;
  events.swap(prelude_);
  spacing_prev_odom_.reset();
  if (choice_.spacing_m() <= opt_.sparse_scan_spacing_m) return r;  // dense: keep the fine grid
  // Sparse: everything so far again, as if the coarse grid had been chosen from the start.
  choice_.switched = true;
  RbpfOptions o = opt_;
  o.grid.resolution_m = o.sparse_resolution_m;
  o.likelihood_gain = o.sparse_likelihood_gain;
  Reset(o);
  ScanResult last = r;
  for (const PreludeEvent& e : events) {
    if (const auto* od = std::get_if<OdomEvent>(&e)) {
      AddOdometry(od->utime, od->pose);
    } else if (const auto* im = std::get_if<ImuEvent>(&e)) {
      AddImuYawRate(im->utime, im->rate);
    } else if (const auto* sc = std::get_if<ScanInput>(&e)) {
      last = AddScanImpl(*sc);
    } else {
      scan_order_.Reset();
    }
  }
  return last;
}

bool RbpfSlam::AddOdometry(int64_t utime, const Pose2& p) {
  if (!StampInRange(utime)) {  // corrupt: the interpolation bracketing it would overflow
    ++counters_.odom_in;
    ++counters_.odom_invalid;
    return false;
  }
  if (!choice_.decided) {
    // Odometry with no scans (or scans that never move) must not grow the held inputs forever.
    if (prelude_.size() >= kMaxPreludeEvents)
      (void)MaybeDecide(ScanResult{}, /*force=*/true);
    else
      prelude_.emplace_back(OdomEvent{utime, p});
  }
  ++counters_.odom_in;
  if (!PlausibleOdometryPose(p)) {
    ++counters_.odom_invalid;
    return false;
  }
  const int64_t rebases = odom_buffer_.rebases();
  const int64_t newest_before = odom_buffer_.newest_utime();
  const bool had_odom = !odom_buffer_.empty();
  if (!odom_buffer_.Insert(utime, p)) {
    ++counters_.odom_out_of_order;
    return false;
  }
  counters_.time_rebases += odom_buffer_.rebases() - rebases;
  const int64_t newest = odom_buffer_.newest_utime();
  if (newest < newest_before || !had_odom || newest - newest_before <= kMaxOdomSpanUs)
    covered_odom_utime_ = newest;  // (a re-based run, the first sample, or one in step)
  if (opt_.use_imu) {
    // (A re-based, older sample also restarts the estimator's still stretch.)
    imu_bias_.AddOdometry(utime, p, [this](int64_t a, int64_t b) { return ImuRawIncrement(a, b); });
    counters_.imu_bias_samples = imu_bias_.samples();
    counters_.imu_bias_refused = imu_bias_.refused();
    counters_.imu_bias_uncovered = imu_bias_.uncovered();
  }
  return true;
}

bool RbpfSlam::AddImuYawRate(int64_t utime, double rate) {
  if (!StampInRange(utime)) {
    ++counters_.imu_in;
    ++counters_.imu_invalid;
    return false;
  }
  if (!choice_.decided) {
    if (prelude_.size() >= kMaxPreludeEvents)
      (void)MaybeDecide(ScanResult{}, /*force=*/true);
    else
      prelude_.emplace_back(ImuEvent{utime, rate});
  }
  ++counters_.imu_in;
  switch (imu_.Add(utime, rate)) {
    case GyroRateHistory::Added::kRefused:  // non-finite, older, or the same time again
      ++counters_.imu_invalid;
      return false;
    case GyroRateHistory::Added::kRebased:  // the newest samples were stamped in the future
      ++counters_.time_rebases;
      break;
    case GyroRateHistory::Added::kInOrder:
      break;
  }
  return true;
}

std::optional<double> RbpfSlam::ImuYawIncrement(int64_t t0, int64_t t1) const {
  const std::optional<double> raw = ImuRawIncrement(t0, t1);
  if (!raw) return std::nullopt;
  return *raw - imu_bias_.bias() * 1e-6 * static_cast<double>(t1 - t0);
}

std::optional<double> RbpfSlam::ImuRawIncrement(int64_t t0, int64_t t1) const {
  if (t1 <= t0) return std::nullopt;
  return imu_.Between(t0, t1);
}

std::optional<Pose2> RbpfSlam::RawOdometryAt(int64_t utime) const {
  return odom_buffer_.At(utime, static_cast<int64_t>(opt_.max_odom_gap_s * 1e6), kMaxOdomSpanUs);
}

std::optional<Pose2> RbpfSlam::CorrectedOdom(const ScanInput& scan) {
  std::optional<Pose2> raw = scan.odom;
  if (raw && !PlausibleOdometryPose(*raw)) {
    ++counters_.odom_invalid;
    raw.reset();
  }
  if (!raw) raw = RawOdometryAt(scan.utime);
  if (!raw) return std::nullopt;
  if (last_raw_odom_) {
    // Judged step by step through the WHEEL_ODOM samples between the two scans, where there are
    // any: a base that drove 5 m while the lidar was away has not jumped. A jump (reset, wrap,
    // glitch) is left out of the jump-free odometry; the steps around it are kept.
    Pose2 prev = *last_raw_odom_;
    Pose2 kept;
    bool jumped = false;
    const auto step = [&](const Pose2& next) {
      const Pose2 d = prev.Between(next);
      if (std::hypot(d.x, d.y) > opt_.max_odom_jump_m ||
          std::abs(d.theta) > opt_.max_odom_jump_rad) {
        ++counters_.odom_jumps;
        jumped = true;
      } else {
        kept = kept * d;
      }
      prev = next;
    };
    for (const Pose2& p : odom_buffer_.Inside(last_raw_odom_utime_, scan.utime)) step(p);
    step(*raw);
    if (jumped) odom_correction_ = (odom_correction_ * *last_raw_odom_ * kept) * raw->Inverse();
  }
  last_raw_odom_ = raw;
  last_raw_odom_utime_ = scan.utime;
  return odom_correction_ * *raw;
}

Pose2 RbpfSlam::CalibratedStep(const Pose2& raw) const {
  return opt_.odometry_calibration.enabled ? calibrator_.calibration().Correct(raw) : raw;
}

ScanResult RbpfSlam::AddScan(const ScanInput& scan) {
  if (!StampInRange(scan.utime)) {
    // Corrupt (beyond +-2^61 us): no odometry can be stamped there, and the time arithmetic on
    // it (its last beam's stamp, its distance to the odometry) would overflow.
    ++counters_.scans_in;
    ++counters_.scans_no_odom;
    ScanResult res;
    res.scan_index = next_scan_index_++;
    return res;
  }
  if (choice_.decided) return AddScanImpl(scan);
  prelude_.emplace_back(scan);
  ++prelude_scans_;
  return MaybeDecide(AddScanImpl(scan), prelude_.size() >= kMaxPreludeEvents);
}

ScanResult RbpfSlam::AddScanImpl(const ScanInput& scan) {
  ScanResult res;
  ++counters_.scans_in;
  const int64_t index = next_scan_index_++;
  res.scan_index = index;
  if (scan_order_.have() && scan.utime < scan_order_.newest()) {
    if (scan_order_.Check(scan.utime) != StampOrder::Verdict::kRebase) {
      ++counters_.scans_time_backwards;
      return res;
    }
    ++counters_.time_rebases;  // the newest accepted scan was stamped in the future
  }
  if (!PlausibleScanGeometry(scan.angle_min_rad, scan.angle_increment_rad, scan.ranges_m.size(),
                             scan.range_max_m, scan.sensor_in_base)) {
    ++counters_.scans_bad_geometry;
    return res;
  }
  const std::optional<Pose2> odom = CorrectedOdom(scan);
  if (!odom) {
    ++counters_.scans_no_odom;
    return res;
  }
  (void)scan_order_.Check(scan.utime);  // accepted: in order from here on
  if (!choice_.decided) MeasureSpacing(*odom);
  // Accepted: it gets a pose, from the filter or by odometry.
  res.accepted = true;
  const bool first = !have_update_;
  bool process = first;
  if (!first) {
    const Pose2 d = last_update_odom_.Between(*odom);
    process = std::hypot(d.x, d.y) >= opt_.linear_update_m ||
              std::abs(d.theta) >= opt_.angular_update_rad ||
              (opt_.temporal_update_s > 0 &&
               UtimeToSeconds(scan.utime - last_update_utime_) >= opt_.temporal_update_s);
  }
  if (process) {
    int valid = 0;
    const float range_max = ScanRangeLimit(scan.range_max_m);
    for (float r : scan.ranges_m) {
      if (std::isfinite(r) && r > 0.f && r >= scan.range_min_m) {
        if (r < range_max && r < opt_.max_range_m) ++valid;
      } else {
        ++counters_.invalid_beams;  // NaN, inf, <= 0 or below range_min
      }
    }
    if (valid < opt_.min_valid_beams) {
      ++counters_.scans_too_few_beams;
      process = false;
    }
  }
  if (process) {
    Update(scan, *odom, first);
    ++counters_.scans_processed;
    records_.push_back({index, scan.utime, *odom, true});
    res.processed = true;
    res.pose = ReportedPose();
  } else {
    if (!first) ++counters_.scans_gated;
    records_.push_back({index, scan.utime, *odom, false});
    res.pose =
        have_update_ ? ReportedPose() * CalibratedStep(last_update_odom_.Between(*odom)) : *odom;
  }
  res.in_map_frame = have_update_;
  return res;
}

void RbpfSlam::Update(const ScanInput& scan, const Pose2& odom, bool first) {
  // End points in the sensor frame (shared by all particles).
  std::vector<Eigen::Vector2d> points;
  std::vector<uint8_t> hit;
  points.reserve(scan.ranges_m.size());
  hit.reserve(scan.ranges_m.size());
  const double max_hit = std::min(opt_.max_hit_range_m, opt_.max_range_m);
  // The base's motion from the first beam to the last (a spinning lidar's sweep).
  std::optional<Pose2> sweep;
  if (scan.scan_time_s > 0 && scan.scan_time_s <= 1.f && scan.ranges_m.size() > 1) {
    const int64_t t1 = scan.utime + std::llround(static_cast<double>(scan.scan_time_s) * 1e6);
    const auto a = RawOdometryAt(scan.utime);
    const auto b = odom_buffer_.At(t1, 0, kMaxOdomSpanUs);
    // An odometry jump inside the sweep is not motion: the scan is then used as it is.
    const std::optional<Pose2> m = a && b ? std::optional<Pose2>(a->Between(*b)) : std::nullopt;
    if (m && std::hypot(m->x, m->y) <= opt_.max_odom_jump_m &&
        std::abs(m->theta) <= opt_.max_odom_jump_rad) {
      sweep = m;
      ++counters_.sweeps_corrected;
    } else {
      ++counters_.sweeps_uncorrected;
    }
  }
  const Pose2 sensor_inv = scan.sensor_in_base.Inverse();
  const double last_beam = static_cast<double>(scan.ranges_m.size() - 1);
  const float range_max = ScanRangeLimit(scan.range_max_m);
  for (size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const float r = scan.ranges_m[i];
    const double a = static_cast<double>(scan.angle_min_rad) +
                     static_cast<double>(i) * static_cast<double>(scan.angle_increment_rad);
    const bool finite = std::isfinite(r) && r > 0.f && r >= scan.range_min_m;
    double range = 0;
    bool is_hit = false;
    if (finite && r < range_max && r < opt_.max_range_m) {
      range = std::min<double>(r, max_hit);
      is_hit = r <= max_hit;
    } else if (opt_.max_free_range_m > 0 && (finite || std::isnan(r) || (std::isinf(r) && r > 0))) {
      range = opt_.max_free_range_m;  // no return: free space up to max_free_range_m
    }
    if (range <= 0) continue;
    Eigen::Vector2d p(range * std::cos(a), range * std::sin(a));
    if (sweep) {
      // Measured from where the sensor was at its time in the sweep: into the base frame there,
      // back to the base frame at the first beam, and into the sensor frame again.
      const Pose2 at = Interpolate(Pose2(), *sweep, static_cast<double>(i) / last_beam);
      p = sensor_inv.Transform(at.Transform(scan.sensor_in_base.Transform(p)));
    }
    points.push_back(p);
    hit.push_back(is_hit ? 1 : 0);
  }
  const MatchScan mscan =
      MakeMatchScan(points, hit, scan.sensor_in_base, opt_.grid.resolution_m, opt_.matcher);
  const Pose2 raw_delta = first ? Pose2() : last_update_odom_.Between(odom);
  const Pose2 delta = CalibratedStep(raw_delta);
  std::optional<double> imu_dtheta;
  if (opt_.use_imu && !first) {
    imu_dtheta = ImuYawIncrement(last_update_utime_, scan.utime);
    if (!imu_dtheta) ++counters_.imu_uncovered_updates;
  }
  const int n = static_cast<int>(particles_.size());
  std::vector<uint8_t> failed(static_cast<size_t>(n), 0), searched(static_cast<size_t>(n), 0);
  pool_.ParallelFor(n, [&](int i) {
    Particle& p = particles_[static_cast<size_t>(i)];
    if (!first) {
      const Pose2 pred = motion_.Sample(p.pose, delta, p.rng, imu_dtheta);
      const MatchResult m = matcher_.Match(p.map, pred, mscan);
      searched[static_cast<size_t>(i)] = m.searched;
      double log_w;  // weight factor: tempered likelihood, or the proposal's normaliser
      if (m.ok && opt_.proposal == ProposalKind::kGaussian) {
        const ProposalDraw d =
            DrawImprovedProposal(matcher_, motion_, p.map, mscan, p.pose, delta, imu_dtheta, m.pose,
                                 opt_.likelihood_gain, opt_.proposal_grid, p.rng);
        // Without draw, or for the best lineage with keep_best: the optimum, weighed by eta.
        const bool keep = !opt_.proposal_draw || (opt_.proposal_keep_best && i == best_lineage_);
        p.pose = keep ? m.pose : d.pose;
        log_w = d.log_weight;
      } else if (m.ok) {
        p.pose = m.pose;
        if (opt_.proposal_sigma_xy_m > 0 || opt_.proposal_sigma_theta_rad > 0) {
          std::normal_distribution<double> n01(0.0, 1.0);
          p.pose = Pose2(p.pose.x + opt_.proposal_sigma_xy_m * n01(p.rng),
                         p.pose.y + opt_.proposal_sigma_xy_m * n01(p.rng),
                         WrapAngle(p.pose.theta + opt_.proposal_sigma_theta_rad * n01(p.rng)));
        }
        log_w = opt_.likelihood_gain * m.score.log_likelihood;
      } else {
        // Drawn from the motion model alone: the importance weight is the likelihood.
        failed[static_cast<size_t>(i)] = 1;
        p.pose = pred;
        log_w = opt_.likelihood_gain * matcher_.Score(p.map, pred, mscan).log_likelihood;
      }
      p.log_weight += log_w;
      p.path_log_weight += log_w;
    }
    p.map.IntegrateScan(p.pose * scan.sensor_in_base, points, hit);
    p.path.Append(p.pose);
  });
  for (int i = 0; i < n; ++i) {
    counters_.match_failures += failed[static_cast<size_t>(i)];
    counters_.match_searches += searched[static_cast<size_t>(i)];
  }
  have_update_ = true;
  last_update_odom_ = odom;
  last_update_utime_ = scan.utime;
  best_lineage_ = HeaviestIndex();
  const int candidate = ReportCandidate();
  if (candidate != reported_lineage_ &&
      ReportWeight(candidate) - ReportWeight(reported_lineage_) > opt_.report_switch_log_margin) {
    reported_lineage_ = candidate;
    ++counters_.reported_switches;
  }
  // An odometry jump inside the interval left one step out of the jump-free odometry that the
  // match still moved through: no pair then.
  const bool jumped = counters_.odom_jumps != odom_jumps_at_update_;
  odom_jumps_at_update_ = counters_.odom_jumps;
  if (opt_.odometry_calibration.enabled && !first && !jumped &&
      !failed[static_cast<size_t>(best_lineage_)]) {
    // The best particle's matched increment against the raw odometry of the same interval.
    const Particle& b = particles_[static_cast<size_t>(best_lineage_)];
    if (const Pose2* before = b.path.BeforeLast())
      calibrator_.AddPair(raw_delta, before->Between(b.pose));
  }
  if (!first) Resample();
}

void RbpfSlam::Resample() {
  const size_t n = particles_.size();
  double mx = -std::numeric_limits<double>::infinity();
  for (const auto& p : particles_) mx = std::max(mx, p.log_weight);
  std::vector<double> w(n);
  double sum = 0;
  for (size_t i = 0; i < n; ++i) sum += (w[i] = std::exp(particles_[i].log_weight - mx));
  for (auto& v : w) v /= sum;
  // Keep log weights bounded without changing their ratios.
  double path_mx = -std::numeric_limits<double>::infinity();
  for (const auto& p : particles_) path_mx = std::max(path_mx, p.path_log_weight);
  for (auto& p : particles_) {
    p.log_weight -= mx;
    p.path_log_weight -= path_mx;
  }
  if (EffectiveSampleSize(w) >= opt_.resample_threshold * static_cast<double>(n)) return;
  ++counters_.resamplings;
  const std::vector<int> pick = LowVarianceResample(w, static_cast<int>(n), master_rng_);
  const auto child = std::find(pick.begin(), pick.end(), best_lineage_);
  best_lineage_ = child == pick.end() ? 0 : static_cast<int>(child - pick.begin());
  // The reported lineage goes on in its first child; when it left none, in the candidate
  // among the children (below).
  const auto reported_child = std::find(pick.begin(), pick.end(), reported_lineage_);
  const bool reported_lost = reported_child == pick.end();
  if (!reported_lost) reported_lineage_ = static_cast<int>(reported_child - pick.begin());
  // A lineage picked more than once is shared from now on: its segment gives back its slack.
  std::vector<int> picked(n, 0);
  for (int j : pick) ++picked[static_cast<size_t>(j)];
  for (size_t i = 0; i < n; ++i)
    if (picked[i] > 1) particles_[i].path.Freeze();
  std::vector<Particle> next;
  next.reserve(n);
  for (size_t j = 0; j < n; ++j) {
    Particle c;
    const Particle& src = particles_[static_cast<size_t>(pick[j])];
    c.pose = src.pose;
    c.log_weight = 0;
    c.path_log_weight = src.path_log_weight;
    c.map = src.map;  // shares every tile
    c.path = src.path;
    c.rng.seed(master_rng_());
    next.push_back(std::move(c));
  }
  particles_ = std::move(next);
  if (reported_lost) {
    reported_lineage_ = ReportCandidate();
    ++counters_.reported_switches;
  }
}

int RbpfSlam::ReportCandidate() const {
  return opt_.final_particle == FinalParticle::kAncestry ? final_index() : best_lineage_;
}

double RbpfSlam::ReportWeight(int i) const {
  const Particle& p = particles_[static_cast<size_t>(i)];
  return opt_.final_particle == FinalParticle::kAncestry ? p.path_log_weight : p.log_weight;
}

int RbpfSlam::HeaviestIndex() const {
  int best = 0;
  for (size_t i = 1; i < particles_.size(); ++i)
    if (particles_[i].log_weight > particles_[static_cast<size_t>(best)].log_weight)
      best = static_cast<int>(i);
  return best;
}

int RbpfSlam::final_index() const {
  if (opt_.final_particle == FinalParticle::kCurrent) return best_index();
  int best = best_index();  // ties go to the best by the current weight
  for (size_t i = 0; i < particles_.size(); ++i)
    if (particles_[i].path_log_weight > particles_[static_cast<size_t>(best)].path_log_weight)
      best = static_cast<int>(i);
  return best;
}

std::vector<EstimatedPose> RbpfSlam::TrajectoryOf(int particle) const {
  std::vector<EstimatedPose> out;
  if (records_.empty() || particle < 0 || static_cast<size_t>(particle) >= particles_.size())
    return out;
  const Particle& b = particles_[static_cast<size_t>(particle)];
  // Processed scan index -> pose on the particle's path.
  const std::vector<Pose2> path = b.path.Poses();
  size_t k = 0;  // index into path of the processed record at or before the current one
  // Processed records in order, to pair with the path.
  std::vector<size_t> processed;
  for (size_t i = 0; i < records_.size(); ++i)
    if (records_[i].processed) processed.push_back(i);
  if (processed.empty() || path.size() != processed.size()) {
    for (const auto& r : records_) out.push_back({r.index, r.utime, r.odom});
    return out;
  }
  for (size_t i = 0; i < records_.size(); ++i) {
    const ScanRecord& r = records_[i];
    while (k + 1 < processed.size() && processed[k + 1] <= i) ++k;
    const ScanRecord& anchor = records_[processed[k]];
    const Pose2 pose = path[k] * CalibratedStep(anchor.odom.Between(r.odom));
    out.push_back({r.index, r.utime, pose});
  }
  return out;
}

size_t RbpfSlam::total_tile_refs() const {
  size_t n = 0;
  for (const auto& p : particles_) n += p.map.num_tiles();
  return n;
}

RbpfSlam::MapMemory RbpfSlam::map_memory() const {
  std::vector<const TiledGrid::Tile*> all;
  for (const auto& p : particles_) p.map.CollectTiles(&all);
  std::sort(all.begin(), all.end());
  all.erase(std::unique(all.begin(), all.end()), all.end());
  MapMemory m;
  m.tiles = all.size();
  for (const TiledGrid::Tile* t : all) {
    m.packed += t->is_packed();
    m.bytes += t->bytes();
  }
  return m;
}

RbpfSlam::PathMemory RbpfSlam::path_memory() const {
  PathMemory m;
  std::unordered_set<const PathSegment*> seen;
  for (const auto& p : particles_)
    for (const PathSegment* s = p.path.tip(); s && seen.insert(s).second; s = s->parent.get()) {
      ++m.segments;
      m.poses += s->entries.size();
      m.bytes += sizeof(PathSegment) + s->entries.capacity() * sizeof(Pose2);
    }
  return m;
}

}  // namespace omni::rbpf
