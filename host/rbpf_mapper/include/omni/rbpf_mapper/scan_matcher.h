// Scan matching of one scan against an occupancy grid (a particle's own map), as in GMapping's
// improved proposal: a correlative search over a window of poses (integer cell shifts x a set of
// headings, scored on a subset of beams) when the start pose matches poorly, then a local
// refinement (hill climbing with shrinking steps) on the likelihood-field score.
//
// Score of a beam (GMapping's kernel): among the cells within `kernel_cells` of the end point
// that are occupied *and* whose counterpart one step back along the beam is free (so walls are
// only matched from the side they were seen from), take the nearest; the beam scores
// exp(-d^2 / (2 sigma_score^2)) and adds -d^2 / (2 sigma_lik^2) to the log likelihood, or
// `null_log_likelihood` when no cell qualifies.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "omni/common/geometry.h"
#include "omni/rbpf_mapper/tiled_grid.h"

namespace omni::rbpf {

struct MatcherOptions {
  int kernel_cells = 1;
  double sigma_score_m = 0.05;
  double sigma_likelihood_m = 0.075;
  double null_log_likelihood = -1.0;  // per beam without a qualifying cell (in units of 1/2sigma^2)
  int beam_step = 1;                  // use every n-th valid beam for matching
  double max_match_range_m = 25.0;    // longer returns are not matched
  // Local refinement.
  double refine_step_xy_m = 0.05;
  double refine_step_theta_rad = 0.05;
  int refine_halvings = 5;
  // Correlative search, run when the start pose matches less than `search_below_fraction`.
  double search_xy_m = 0.3;
  double search_theta_rad = 0.25;
  double search_theta_step_rad = 0.02;
  int search_beam_step = 3;
  double search_below_fraction = 0.6;  // 1.0: always search; 0: never
  // Charge for leaving the start pose, in matched-beam fraction at the window's edge
  // (x/y at search_xy_m or heading at search_theta_rad); against aliasing along corridors.
  double prior_weight = 0.1;
  // A match explaining fewer beams than this fraction is a failure (odometry fallback).
  double min_match_fraction = 0.25;
};

// Beam end points of one scan in the robot base frame, ready for matching.
struct MatchScan {
  std::vector<Eigen::Vector2d> hits;   // end points (base frame)
  std::vector<Eigen::Vector2d> frees;  // one free step back along each beam (base frame)
  std::vector<Eigen::Vector2d> coarse_hits;
  std::vector<Eigen::Vector2d> coarse_frees;
};
// `points`: end points in the sensor frame with `hit` flags (no-return beams are skipped);
// `sensor_in_base`: mounting pose.
MatchScan MakeMatchScan(const std::vector<Eigen::Vector2d>& points, const std::vector<uint8_t>& hit,
                        const Pose2& sensor_in_base, double resolution_m,
                        const MatcherOptions& options);

struct ScoreResult {
  double score = 0;           // sum of per-beam kernel scores
  double log_likelihood = 0;  // sum of per-beam log likelihoods
  int matched = 0;            // beams with a qualifying cell
  int beams = 0;
  double fraction() const { return beams > 0 ? static_cast<double>(matched) / beams : 0.0; }
};

struct MatchResult {
  Pose2 pose;  // robot base in the map frame
  ScoreResult score;
  bool ok = false;        // enough beams explained
  bool searched = false;  // the correlative search ran
};

class ScanMatcher {
 public:
  // `resolution_m`: the grids' cell size (the score's kernel is tabulated for it).
  explicit ScanMatcher(const MatcherOptions& options = {}, double resolution_m = 0.05);
  ScoreResult Score(const TiledGrid& grid, const Pose2& base_pose, const MatchScan& scan) const;
  // Best pose near `start` (robot base in the map frame).
  MatchResult Match(const TiledGrid& grid, const Pose2& start, const MatchScan& scan) const;
  // The correlative search alone: best pose of the window around `start` on the coarse beams.
  Pose2 CorrelativeSearch(const TiledGrid& grid, const Pose2& start, const MatchScan& scan) const;
  const MatcherOptions& options() const { return opt_; }
  // Hill climbing on the score from *pose (updated).
  ScoreResult Refine(const TiledGrid& grid, const MatchScan& scan, Pose2* pose) const;

 private:
  double Prior(const Pose2& start, const Pose2& p) const;
  static constexpr int kTable = 512;
  MatcherOptions opt_;
  double table_resolution_m_;
  double table_max_d2_ = 0;
  std::vector<double> table_;
};

}  // namespace omni::rbpf
