// Map fusion (SLAMfusion, paper 003 of ../shared/seeds): several 2D occupancy grids of the same
// place, made by different mappers, are aligned onto one of them (rotation + translation,
// coarse-to-fine) and every cell is decided by a vote. The library of the map_fusion process: no
// LCM, no clock.
//
// The vote, per cell, over the maps' normalised values (-1 unknown, 0 free, 1 occupied, as the
// paper and omni::eval normalise them): the value with the most votes wins; when two or more
// values share the most votes (e.g. two maps that disagree, or three that all differ) the tie
// rule decides — "occupied" in the paper, whose disagreements were mostly at the border between
// free and unknown space, where there usually is an obstacle. With `unknown_votes: false` a map
// that has not seen a cell abstains instead of voting "unknown" (the paper lets it vote), so a
// region seen by one mapper only (e.g. beyond the depth camera's range) keeps that mapper's value.
#pragma once

#include <cstddef>
#include <map>
#include <string>
#include <vector>

#include "omni/common/config.h"
#include "omni/common/result.h"
#include "omni/eval/eval.h"
#include "omni/io/grid.h"

namespace omni::map_fusion {

enum class TieRule { kOccupied, kFree, kUnknown };

struct FusionOptions {
  // Node: the grids to fuse (latest of each) and where the result goes.
  std::vector<std::string> grid_channels = {"GRID_PG", "GRID_RBPF", "GRID_OCTO"};
  std::string fused_channel = "GRID_FUSED";
  std::string frame = "map";
  double fuse_interval_s = 5.0;  // node: fuse at most this often, when a grid changed
  int min_maps = 2;              // fewer usable maps: no fusion (counted)
  // Node: a grid with more cells is rejected (counted) before it is decoded. The fusion holds
  // several copies of each (about 10 of the base's size): at the default, what the bus decoder
  // allows (2^28 cells; octomap_builder's projection may be that large), one absurd grid takes
  // gigabytes; a PC with little memory sets it lower (the 2D mappers' grids stop at 64 Mi).
  int64_t max_input_cells = io::kMaxGridCells;
  // The map the others are aligned onto and whose grid the result uses: a name from
  // grid_channels (node) or an input's name (offline); "" = the first usable input (the node
  // passes its maps in grid_channels order, so the pose-graph map by default). Not "the map
  // with the most known cells": a drifting map is the largest.
  std::string base;
  // Search ranges; `align: false` trusts the maps' frames. `max_cells` bounds the cells the
  // search scores before its last level (`align.max_cells`): a 90 m floor's 102k occupied cells
  // take 1.1 s instead of 9.9 (omni-bench-fusion).
  eval::MapCompareOptions align = [] {
    eval::MapCompareOptions o;
    o.max_cells = 10000;
    return o;
  }();
  // An aligned map whose occupied cells land near the base's occupied cells less often than
  // this is left out of the vote (counted): a failed alignment must not corrupt the result.
  double min_overlap_fraction = 0.3;
  // Occupied-on-occupied overlap alone accepts a map turned by a multiple of pi/2 (outside the
  // rotation search) in a rectilinear building: its walls lie along the base's. So an aligned map
  // is also left out (counted) when, over the cells both maps know, too many of the occupied cells
  // of either map fall on the other's free space (no occupied cell within
  // align.match_tolerance_cells cells of the coarser grid): `conflict_fraction` = such cells /
  // occupied cells of either map there (CountConflicts) above this, *and* both ways: each map's
  // share of its own walls on the other's free space above half of it. A map that only adds
  // walls the base has as free (people the camera saw once, low boxes under the lidar's plane) is
  // not misaligned, and the vote decides those cells, if at least two other maps are used (with
  // one, its extra walls would tie and the tie rule decide: it is left out then). 1 disables the
  // check. Measured in docs/map_fusion.md.
  double max_conflict_fraction = 0.25;
  TieRule tie = TieRule::kOccupied;
  // The paper lets "unknown" vote; here a map abstains where it has not seen a cell (false),
  // which on the simulator's floor gives a 20 % lower map error (docs/map_fusion.md).
  bool unknown_votes = false;

  // Every key above is optional; unknown keys and bad values are errors naming the key.
  static Result<FusionOptions> Load(ConfigReader& reader);
  // On the bus the maps come from grid_channels: more min_maps than channels could never fuse.
  // (Offline, --fuse takes files and ignores grid_channels.)
  Status ValidateForBus() const;
};

struct SourceMap {
  std::string name;
  io::GridMap map;
};

struct SourceReport {
  std::string name;
  bool used = false;
  std::string reason;  // why it was left out ("" when used)
  eval::MapAlignment alignment;
  double overlap_fraction = 0;    // alignment.overlap / alignment.occupied
  double conflict_fraction = 0;   // MapConflicts::fraction() against the base (0 for the base)
  double walls_on_base_free = 0;  // its walls on the base's free space (moved_fraction())
  double base_walls_on_free = 0;  // the base's walls on its free space (base_fraction())
  size_t known_cells = 0;
};

struct FusionResult {
  io::GridMap fused;  // on the base map's grid; cells -1, 0 or 100
  std::string base;
  std::vector<SourceReport> sources;  // one per input, in input order
  size_t maps_used = 0;
  size_t unanimous = 0;  // known-or-not cells where every voting map agreed
  size_t majority = 0;   // decided by a strict plurality that was not unanimous
  size_t ties = 0;       // decided by the tie rule
  // Alignments started from a previous one (hints) and kept, and full searches.
  size_t alignments_tracked = 0, alignments_searched = 0;
};

// Previous alignments onto a base, by map name: Fuse first searches a small window around each
// (kTrackRotationRad, kTrackShiftM) and keeps the result unless its overlap fell by more than
// 0.05 or below min_overlap_fraction, in which case the full search runs. Maps grow between two
// fusions but rarely move, so this replaces most full searches by one about six times cheaper
// (Intel lab, 12k occupied cells: 1.8 s against 0.3 s with another build running; the
// AlignmentRecoversAKnownTransformOfARealMap test prints both).
struct AlignmentHints {
  std::string base;  // the hints hold for this base only
  std::map<std::string, eval::MapAlignment> by_name;
};
inline constexpr double kTrackRotationRad = 0.04;
inline constexpr double kTrackShiftM = 0.25;

// Whether a map can take part in a fusion: a consistent non-empty grid (cells = width x height),
// a finite positive cell size and a finite origin, and at least one known cell. `why` (optional)
// says what is wrong. Fuse leaves such maps out; the node refuses them on arrival.
bool UsableMap(const io::GridMap& m, std::string* why = nullptr);

// Where a map moved onto the base's grid (eval::ResampleOnto) contradicts the base, over the cells
// both know: `occupied` counts the occupied cells of either map there, `conflicts` those of them
// lying on the other map's free space with no occupied cell of the other within
// `tolerance_cells` (a wall one cell off is not a conflict). `moved` must have `base`'s size.
struct MapConflicts {
  size_t occupied = 0;   // occupied cells of either map where both know the cell
  size_t conflicts = 0;  // of them, on the other's free space
  // The two directions: the moved map's walls on the base's free space, and the base's walls on
  // the moved map's free space.
  size_t moved_occupied = 0, moved_on_free = 0;
  size_t base_occupied = 0, base_on_free = 0;
  static double Ratio(size_t n, size_t d) {
    return d == 0 ? 0.0 : static_cast<double>(n) / static_cast<double>(d);
  }
  double fraction() const { return Ratio(conflicts, occupied); }
  double moved_fraction() const { return Ratio(moved_on_free, moved_occupied); }
  double base_fraction() const { return Ratio(base_on_free, base_occupied); }
};
MapConflicts CountConflicts(const io::GridMap& base, const io::GridMap& moved, int tolerance_cells);

// The vote on one cell: `votes[v + 1]` = number of maps saying v (v = -1, 0, 1). Returns the
// normalised winner; `tied` (optional) tells whether the tie rule decided.
int VoteCell(const size_t votes[3], TieRule tie, bool* tied = nullptr);

// Aligns every map onto the base, resamples it onto the base's grid and votes. Errors: fewer
// than min_maps inputs that are non-empty and well aligned, or a configured base that is not
// among the inputs.
// `hints` (optional): previous alignments (see AlignmentHints); updated with this fusion's.
// `sources` (optional): the per-map reports, also when the fusion fails (which maps were left
// out, and why).
Result<FusionResult> Fuse(const std::vector<SourceMap>& maps, const FusionOptions& options,
                          AlignmentHints* hints = nullptr,
                          std::vector<SourceReport>* sources = nullptr);

// A one-line JSON object per source and the vote counts, for logs and stats files.
std::string ReportJson(const FusionResult& result);

// DIR/fused_map.{pgm,yaml,png} and DIR/fusion.json (ReportJson), creating DIR.
Status WriteFusionOutputs(const FusionResult& result, const std::string& dir);

}  // namespace omni::map_fusion
