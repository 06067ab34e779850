// Evaluation: trajectory error (ATE after least-squares rigid alignment, RPE) and map error
// (the SLAMfusion metric of paper 003: sqrt of the sum of squared cell differences with cells
// normalised to -1 unknown / 0 free / 1 occupied, after a translation + rotation alignment).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "omni/common/result.h"
#include "omni/io/grid.h"
#include "omni/io/trajectory_io.h"

namespace omni::eval {

struct Association {
  std::vector<size_t> ref_index;
  std::vector<size_t> est_index;
  // Matched by time to a stamp that several estimate poses share (a log's scans on one stamp):
  // which of them is the reference's pose is a guess. Reference poses on one stamp take the
  // estimate's poses on the matched stamp in file order.
  size_t ambiguous = 0;
};
// Pairs entries: by scan index when both files are in the indexed form (an index that appears
// twice in either file is an error), otherwise by the nearest timestamp within max_dt_s (TUM).
// Errors when nothing matches.
Result<Association> Associate(const io::Trajectory& ref, const io::Trajectory& est,
                              double max_dt_s = 0.02);

struct AteResult {
  size_t matched = 0;
  size_t reference_poses = 0;  // the reference's poses: matched < this leaves some unscored
  double rmse_m = 0;
  double mean_m = 0;
  double max_m = 0;
  double rot_rmse_rad = 0;
  Eigen::Isometry3d alignment = Eigen::Isometry3d::Identity();  // applied to the estimate
  size_t ambiguous = 0;                                         // Association::ambiguous
};
// Rigid alignment: SE(2) (rotation about z + planar translation) when `se3` is false,
// otherwise SE(3); both least squares (Umeyama without scale).
Result<AteResult> ComputeAte(const io::Trajectory& ref, const io::Trajectory& est, bool se3 = false,
                             double max_dt_s = 0.02);

struct RpeResult {
  size_t pairs = 0;
  size_t matched = 0;          // reference poses matched by the estimate
  size_t reference_poses = 0;  // the reference's poses
  double trans_rmse_m = 0;
  double trans_max_m = 0;
  double rot_rmse_rad = 0;
  double rot_max_rad = 0;
  size_t ambiguous = 0;  // Association::ambiguous
};
// Relative pose error between consecutive matched poses (`delta` matched steps apart).
Result<RpeResult> ComputeRpe(const io::Trajectory& ref, const io::Trajectory& est, int delta = 1,
                             double max_dt_s = 0.02);

struct MapCompareOptions {
  double max_rotation_rad = 0.35;  // search range for the rotation of the estimate
  double max_shift_m = 2.0;        // search range for the translation
  int match_tolerance_cells = 1;   // occupied-cell precision/recall tolerance
  bool align = true;               // false: compare in the maps' own frames
  // The search: the first level tries ±range in `coarse_steps` steps per side; each of the
  // `levels` - 1 further levels tries ± the previous step in `refine_divisions` steps per side.
  int coarse_steps = 8;
  int refine_divisions = 4;
  int levels = 6;
  int threads = 0;  // threads scoring the rotations of a level; 0: one per core
  // The first level's rotation step is also at most (its shift step) / (the RMS distance of the
  // estimate's occupied cells from its centre), so a large map's walls move by no more than a
  // shift step per rotation step (more rotations to try on a large map; at most 128 a side).
  bool rotation_step_from_extent = true;
  // > 0: every level but the last scores at most this many of the estimate's occupied cells (a
  // fixed, evenly spread random subset), so those levels cost what a map of that many cells
  // would (the rotations still grow with the map's extent, and the last level scores every
  // cell); the overlap reported uses every cell. 0: every cell at every level.
  int max_cells = 0;
};

struct MapCompareResult {
  double error = 0;  // SLAMfusion error over the reference grid
  size_t cells = 0;  // reference cells compared
  size_t differing_cells = 0;
  double precision = 0;  // occupied cells of the estimate near an occupied reference cell
  double recall = 0;     // occupied reference cells near an occupied estimate cell
  double dx_m = 0, dy_m = 0, rotation_rad = 0;  // alignment applied to the estimate
};
// A rigid alignment of one grid onto another: a point p of `est`'s frame maps to
// R(rotation) (p - c) + c + (dx, dy), c = (cx, cy) the estimate's map centre.
struct MapAlignment {
  double rotation_rad = 0, dx_m = 0, dy_m = 0;
  double cx_m = 0, cy_m = 0;
  size_t occupied = 0;  // occupied cells of the estimate
  size_t overlap = 0;   // of them, landing within one cell of an occupied reference cell
  void Apply(double x, double y, double* ox, double* oy) const;
  // The inverse: a point of the reference frame to the estimate's frame.
  void Invert(double x, double y, double* ox, double* oy) const;
};
// Coarse-to-fine search over rotation (±max_rotation_rad) and translation (±max_shift_m)
// maximising the overlap of occupied cells; the identity when `align` is off or either map has
// no occupied cell. With `guess` the search is centred on that rigid transform instead of the
// identity (its centre may differ from this estimate's: the transform is what counts), e.g. the
// previous alignment of a map that has grown since, with small ranges.
MapAlignment AlignMap(const io::GridMap& ref, const io::GridMap& est,
                      const MapCompareOptions& options = {}, const MapAlignment* guess = nullptr);
// `est` moved by `a` and sampled (nearest cell) onto `geometry`'s grid: same resolution, origin
// and size as `geometry`; -1 where the estimate has no cell. An estimate with finer cells is
// sampled k x k times per cell (k = the ratio of the cell sizes) and the largest value kept, so
// a wall one fine cell thick is a wall on the coarser grid.
io::GridMap ResampleOnto(const io::GridMap& geometry, const io::GridMap& est,
                         const MapAlignment& a);

// Aligns `est` onto `ref` (AlignMap), then scores it on the reference grid.
MapCompareResult CompareMaps(const io::GridMap& ref, const io::GridMap& est,
                             const MapCompareOptions& options = {});

// -1 unknown, 0 free, 1 occupied (> 50 %), as in SLAMfusion's normalisation.
int NormalizedCell(int8_t v);

}  // namespace omni::eval
