// The map_fusion node: bus I/O around the fusion library. Subscribes the configured grid
// channels (occupancy_grid_t; by default GRID_PG, GRID_RBPF and GRID_OCTO) and keeps the latest
// grid of each; at most every fuse_interval_s, when a grid changed and at least min_maps are
// there, fuses them (map_fusion::Fuse) and publishes GRID_FUSED (source "fused") and HEARTBEAT.
//
// A fusion of large maps takes seconds (6.6 s for 108k occupied cells), longer than the
// supervisor's heartbeat timeout, so it runs on a worker thread, one at a time, on a copy of the
// grids: Tick keeps heartbeating and the bus keeps delivering grids meanwhile; the heartbeat's
// text says "fusing N maps for S s" and its counter `fusing` is 1. Tick publishes a finished
// fusion's grid (from the calling thread: the bus is only used there). FuseNow and WriteOutputs
// (MAP_SAVE, shutdown) wait for a running fusion, still heartbeating, so the final fusion is
// done and written.
//
// Bad input is counted, never fused: grids that do not decode (the bus counts decode errors),
// are inconsistent or empty (size, resolution, no known cell: the channel keeps its previous
// grid), rotated by a non-finite angle or in another frame (grids_rejected); maps left out of a
// fusion by a failed alignment or conflicts with the base (sources_rejected, of them
// sources_conflicting); and fusions that could not run (fusion_failures, e.g. too few usable
// maps). GRID_FUSED is stamped with the newest utime among the grids that fusion used.
#pragma once

#include <cstdint>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/common/time.h"
#include "omni/map_fusion/fusion.h"
#include "omni/occupancy_grid_t.hpp"

namespace omni::map_fusion {

class MapFusionNode {
 public:
  MapFusionNode(bus::Bus* bus, const FusionOptions& options, const Clock* clock);
  ~MapFusionNode();  // waits for a running fusion
  MapFusionNode(const MapFusionNode&) = delete;
  MapFusionNode& operator=(const MapFusionNode&) = delete;

  // Heartbeat; publishes a fusion that finished; starts one on the worker when due. Never waits
  // for a fusion: call often.
  void Tick();
  // Waits for a running fusion (publishing it), then fuses what is there now (whatever the
  // interval) and waits for that too, heartbeating meanwhile; publishes on success. The result
  // or why not.
  Result<FusionResult> FuseNow();
  // The last fusion if it is of the grids held now, else FuseNow; then DIR/fused_map.{pgm,yaml,
  // png} and DIR/fusion.json.
  Status WriteOutputs(const std::string& dir);
  // The files WriteOutputs writes in its folder.
  static const std::vector<std::string>& OutputFiles() {
    static const std::vector<std::string> names = {"fused_map.pgm", "fused_map.yaml",
                                                   "fused_map.png", "fusion.json"};
    return names;
  }
  // From now on the heartbeat's state stays STATE_STOPPING (its text still tells what runs).
  void SetStopping();

  bool fusing() const { return job_ != nullptr; }
  int64_t grids_in() const { return grids_in_; }
  int64_t grids_rejected() const { return grids_rejected_; }
  int64_t fusions() const { return fusions_; }
  int64_t fusion_failures() const { return fusion_failures_; }
  int64_t sources_rejected() const { return sources_rejected_; }
  int64_t sources_conflicting() const { return sources_conflicting_; }
  int64_t alignments_tracked() const { return alignments_tracked_; }
  int64_t alignments_searched() const { return alignments_searched_; }
  const std::optional<FusionResult>& last() const { return last_; }
  bus::Heartbeat& heartbeat() { return heartbeat_; }

  // Tests: what the worker calls instead of Fuse (e.g. a slow one). Set before the first Tick.
  using FuseFn =
      std::function<Result<FusionResult>(const std::vector<SourceMap>&, const FusionOptions&,
                                         AlignmentHints*, std::vector<SourceReport>*)>;
  void SetFuseFunctionForTest(FuseFn fn) { fuse_ = std::move(fn); }

 private:
  // One fusion: its inputs (copies) and, once the worker is done, its outputs. The worker
  // touches nothing else.
  struct Job {
    std::vector<SourceMap> maps;
    std::vector<int64_t> utimes;  // of maps, same order
    FusionOptions options;
    AlignmentHints hints;
    std::vector<SourceReport> reports;
    std::optional<Result<FusionResult>> result;
    int64_t started_us = 0;  // MonotonicMicros
  };

  void OnGrid(const std::string& channel, const omni::occupancy_grid_t& msg);
  void StartFusion();
  // Finishes the running fusion if it is done (or, with `wait`, once it is, heartbeating every
  // 50 ms meanwhile): counters, hints, state, GRID_FUSED; its result in `out` (optional).
  // Returns whether none runs any more.
  bool CollectFusion(bool wait, std::optional<Result<FusionResult>>* out = nullptr);
  void SetState(int8_t state, const std::string& text);
  void ShowFusing();

  bus::Bus* bus_;
  FusionOptions o_;
  const Clock* clock_;
  bus::Heartbeat heartbeat_;
  struct Held {
    io::GridMap map;
    int64_t utime = 0;
    std::string frame;  // as it came ("" if the message named none)
  };
  std::map<std::string, Held> latest_;  // by channel
  bool changed_ = false;                // a grid was accepted since the last fusion started
  bool last_current_ = false;           // last_ fused the grids held now
  int64_t last_fuse_utime_ = 0;
  int64_t grids_in_ = 0, grids_rejected_ = 0, fusions_ = 0, fusion_failures_ = 0;
  int64_t sources_rejected_ = 0, sources_conflicting_ = 0;
  int64_t last_fusion_ms_ = 0;
  std::optional<FusionResult> last_;
  AlignmentHints hints_;  // the worker works on a copy, handed back when it is done
  int64_t alignments_tracked_ = 0, alignments_searched_ = 0;
  int8_t state_ = 0;
  std::string state_text_;
  bool stopping_ = false;
  FuseFn fuse_;
  std::unique_ptr<Job> job_;  // the running fusion, if any
  std::future<void> worker_;
};

}  // namespace omni::map_fusion
