// Scan matching for the pose graph: a likelihood field of a submap (each cell holds
// exp(-d^2 / 2 sigma^2), d = distance to the nearest submap point, computed once per submap) and
// a correlative search over an (x, y, theta) window around an initial guess.
//
// The search is exhaustive in effect but evaluated branch-and-bound style on two resolutions:
// for every rotation, the translations are grouped in blocks of K x K fine cells; the block's
// score is computed on a max-pooled copy of the field (each coarse value is the maximum of the
// K x K fine cells it covers), which bounds the fine score of every translation in the block
// from above. Blocks are visited best bound first and a block is only refined while its bound
// beats the best fine score found, so the result equals the exhaustive fine search (unless it
// scores below SearchWindow::min_score, when the search gives up early).
// The discrete optimum (and the best of each nearby rotation scoring almost as well) is then
// polished by a continuous hill climb on the bilinearly interpolated field (optionally followed
// by point-to-line ICP against the submap points); the
// covariance comes from the spread of the good fine candidates around the optimum (each weighted by
// exp(kappa * n * (score - best)), Olson's correlative matcher idea), plus the discretisation
// variance.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "omni/common/geometry.h"

namespace omni::pgm {

struct LikelihoodFieldOptions {
  double resolution_m = 0.05;  // fine cell size
  double sigma_m = 0.07;       // width of the likelihood around each submap point
  double margin_m = 1.0;       // grid extends this far beyond the submap's bounding box
  int coarse_cells = 8;        // K: coarse blocks are K x K fine cells
};

class LikelihoodField {
 public:
  // Cells a field may have (128 MB of floats: a 560 m square at 5 cm); a submap spanning more
  // gives an empty field.
  static constexpr int64_t kMaxFieldCells = int64_t{1} << 25;
  // `points` in the submap's frame. An empty submap gives an empty field (every score 0).
  LikelihoodField(const std::vector<Eigen::Vector2d>& points, const LikelihoodFieldOptions& o);

  double resolution() const { return res_; }
  // Corner of cell (0, 0) in the submap's frame (cell centres are half a cell in).
  const Eigen::Vector2d& origin() const { return origin_; }
  int coarse_cells() const { return k_; }
  bool empty() const { return w_ == 0; }
  // Integer cell of a point (may be outside the grid).
  Eigen::Vector2i Cell(const Eigen::Vector2d& p) const;
  // Fine value of a cell, 0 outside.
  float Fine(int ix, int iy) const;
  // Max of Fine over [ix, ix+K) x [iy, iy+K), 0 when entirely outside.
  float Pooled(int ix, int iy) const;
  // Bilinear interpolation of the fine field at a point.
  double Interpolated(const Eigen::Vector2d& p) const;
  // Catmull-Rom (bicubic) interpolation: follows a ridge between samples (the hill climb's).
  double InterpolatedCubic(const Eigen::Vector2d& p) const;
  const std::vector<Eigen::Vector2d>& points() const { return points_; }
  // Raw storage for the matcher's inner loops (no bounds checks there): fine values row-major,
  // width() x height(); pooled values row-major, pooled_width() x pooled_height(), with
  // Pooled(ix, iy) at (iy + K) * pooled_width() + (ix + K).
  int width() const { return w_; }
  int height() const { return h_; }
  int pooled_width() const { return w_ + k_; }
  int pooled_height() const { return h_ + k_; }
  const float* fine_data() const { return fine_.data(); }
  const float* pooled_data() const { return pooled_.data(); }
  // True when the outermost rows and columns of both grids are 0 (the margin is wider than the
  // likelihood's reach), so a lookup clamped to the grid gives the same 0 as one outside it.
  bool zero_border() const { return zero_border_; }

 private:
  std::vector<Eigen::Vector2d> points_;
  double res_;
  int k_;
  Eigen::Vector2d origin_ = Eigen::Vector2d::Zero();
  int w_ = 0, h_ = 0;
  std::vector<float> fine_;    // w_ x h_
  std::vector<float> pooled_;  // (w_ + k_) x (h_ + k_), index offset by k_
  bool zero_border_ = false;
};

struct SearchWindow {
  double x_m = 0.5, y_m = 0.5;  // half-widths around the guess
  double theta_rad = 0.35;
  double angle_step_rad = 0.0087;  // about 0.5 deg
  // A candidate counts as "elsewhere" (for the second-best score) when it is farther than this
  // from the best one in translation or rotation.
  double ambiguity_xy_m = 0.5;
  double ambiguity_theta_rad = 0.2;
  double covariance_kappa = 2.0;   // weight exp(kappa * n * (s - s_best)) of the candidates
  double inlier_likelihood = 0.5;  // a point whose field value is >= this is "matched"
  // Blocks whose bound is below this are never refined (the caller would reject such a match
  // anyway); when no candidate reaches it the search stops early with `below_min_score` set.
  double min_score = 0;
  // The polish also starts from the best translation of each rotation within 4 steps of the
  // optimum whose fine score is within this of the best (0: the optimum only).
  double polish_score_gap = 0.02;
  // The polish's objective between the field's samples: bilinear (default), or Catmull-Rom
  // bicubic, which follows a ridge between 5 cm samples (on the simulator's exact data bilinear
  // biases heading by about -0.5 mrad per keyframe on walls a few mrad off the grid's axes and
  // bicubic does not; on the Radish logs bilinear agrees better with the references, see
  // docs/posegraph.md). The reported score is bilinear either way (the thresholds' scale).
  bool cubic_polish = false;
  // Final point-to-line ICP polish against the submap points (pairs closer than icp_pair_m);
  // kept only when it stays within icp_max_shift_m / icp_max_turn_rad of the search result.
  // Off by default: on the Intel scans it does not beat the field's optimum (nearest-neighbour
  // pairs between sparse real scans are biased too); it removes the interpolation bias on
  // densely sampled (synthetic) submaps.
  bool icp_polish = false;
  double icp_pair_m = 0.3;
  double icp_max_shift_m = 0.1;
  double icp_max_turn_rad = 0.035;
};

// A window of +-xy_m in x and y and +-theta_rad, other settings at their defaults.
inline SearchWindow MakeSearchWindow(double xy_m, double theta_rad) {
  SearchWindow w;
  w.x_m = w.y_m = xy_m;
  w.theta_rad = theta_rad;
  return w;
}

struct MatchResult {
  Pose2 pose;                  // the query scan's pose in the submap frame
  double score = 0;            // mean field value of the query points at `pose`, in [0, 1]
  double second_score = 0;     // best score of a candidate "elsewhere" (0 when none)
  double inlier_fraction = 0;  // fraction of query points that are matched
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  long evaluated = 0;            // fine candidates scored (for the search-effort figures)
  long bounded = 0;              // coarse blocks scored
  bool below_min_score = false;  // no candidate reached SearchWindow::min_score (score = 0)
  // The best discrete candidate lies on the window's boundary (x, y or theta): the score may
  // still rise outside the window, so the optimum may not have been found.
  bool on_window_edge = false;
};

// Matches `query` (points in the query's own frame) against the field. `query` must not be
// empty (the caller counts and skips empty scans).
MatchResult MatchScan(const LikelihoodField& field, const std::vector<Eigen::Vector2d>& query,
                      const Pose2& guess, const SearchWindow& window);

// Point-to-line ICP (Gauss-Newton, brute-force nearest neighbours) from `start`; returns the
// refined pose, or `start` when fewer than 10 pairs are found.
Pose2 RefinePointToLine(const std::vector<Eigen::Vector2d>& reference,
                        const std::vector<Eigen::Vector2d>& query, const Pose2& start,
                        double pair_distance_m, int iterations = 15);

// Mean field value of `query` placed at `pose` (bilinear).
double ScoreAt(const LikelihoodField& field, const std::vector<Eigen::Vector2d>& query,
               const Pose2& pose);

}  // namespace omni::pgm
