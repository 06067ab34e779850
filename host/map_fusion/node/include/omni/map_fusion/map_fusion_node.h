// The map_fusion node: bus I/O around the fusion library. Subscribes the configured grid
// channels (occupancy_grid_t; by default GRID_PG, GRID_RBPF and GRID_OCTO) and keeps the latest
// grid of each; at most every fuse_interval_s, when a grid changed and at least min_maps are
// there, fuses them (map_fusion::Fuse) and publishes GRID_FUSED (source "fused") and HEARTBEAT.
//
// Bad input is counted, never fused: grids that do not decode (the bus counts decode errors),
// are inconsistent (size, resolution), rotated (origin_yaw_rad != 0) or in another frame
// (grids_rejected); maps left out of a fusion by a failed alignment (sources_rejected); and
// fusions that could not run (fusion_failures, e.g. too few usable maps).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/common/time.h"
#include "omni/map_fusion/fusion.h"
#include "omni/occupancy_grid_t.hpp"

namespace omni::map_fusion {

class MapFusionNode {
 public:
  MapFusionNode(bus::Bus* bus, const FusionOptions& options, const Clock* clock);

  // Heartbeat and, when due, a fusion and its publication; call often.
  void Tick();
  // Fuses what is there now (whatever the interval), publishes on success; the result or why not.
  Result<FusionResult> FuseNow();
  // FuseNow, then DIR/fused_map.{pgm,yaml,png} and DIR/fusion.json.
  Status WriteOutputs(const std::string& dir);

  int64_t grids_in() const { return grids_in_; }
  int64_t grids_rejected() const { return grids_rejected_; }
  int64_t fusions() const { return fusions_; }
  int64_t fusion_failures() const { return fusion_failures_; }
  int64_t sources_rejected() const { return sources_rejected_; }
  int64_t alignments_tracked() const { return alignments_tracked_; }
  int64_t alignments_searched() const { return alignments_searched_; }
  const std::optional<FusionResult>& last() const { return last_; }
  bus::Heartbeat& heartbeat() { return heartbeat_; }

 private:
  void OnGrid(const std::string& channel, const omni::occupancy_grid_t& msg);

  bus::Bus* bus_;
  FusionOptions o_;
  const Clock* clock_;
  bus::Heartbeat heartbeat_;
  std::map<std::string, io::GridMap> latest_;  // by channel
  int64_t newest_utime_ = 0;
  bool changed_ = false;
  int64_t last_fuse_utime_ = 0;
  int64_t grids_in_ = 0, grids_rejected_ = 0, fusions_ = 0, fusion_failures_ = 0;
  int64_t sources_rejected_ = 0;
  std::optional<FusionResult> last_;
  AlignmentHints hints_;
  int64_t alignments_tracked_ = 0, alignments_searched_ = 0;
};

}  // namespace omni::map_fusion
