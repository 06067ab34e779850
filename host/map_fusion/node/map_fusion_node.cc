#include "omni/map_fusion/map_fusion_node.h"

#include <cmath>
#include <cstdio>

#include "omni/bus/convert.h"
#include "omni/common/log.h"
#include "omni/heartbeat_t.hpp"
#include "omni/occupancy_grid_t.hpp"

namespace omni::map_fusion {

MapFusionNode::MapFusionNode(bus::Bus* bus, const FusionOptions& options, const Clock* clock)
    : bus_(bus), o_(options), clock_(clock), heartbeat_(bus, "map_fusion", clock) {
  for (const auto& ch : o_.grid_channels)
    bus_->Subscribe<omni::occupancy_grid_t>(
        ch, [this, ch](const omni::occupancy_grid_t& m, int64_t) { OnGrid(ch, m); });
  heartbeat_.AddCounter("grids_in", [this] { return grids_in_; });
  heartbeat_.AddCounter("grids_rejected", [this] { return grids_rejected_; });
  heartbeat_.AddCounter("fusions", [this] { return fusions_; });
  heartbeat_.AddCounter("fusion_failures", [this] { return fusion_failures_; });
  heartbeat_.AddCounter("sources_rejected", [this] { return sources_rejected_; });
  heartbeat_.AddCounter("alignments_tracked", [this] { return alignments_tracked_; });
  heartbeat_.AddCounter("alignments_searched", [this] { return alignments_searched_; });
  heartbeat_.AddCounter("maps_held", [this] { return static_cast<int64_t>(latest_.size()); });
  heartbeat_.AddCounter(
      "maps_fused", [this] { return last_ ? static_cast<int64_t>(last_->maps_used) : int64_t{0}; });
  heartbeat_.SetState(omni::heartbeat_t::STATE_OK, "waiting for grids");
}

void MapFusionNode::OnGrid(const std::string& channel, const omni::occupancy_grid_t& msg) {
  ++grids_in_;
  auto map = bus::FromGridMessage(msg);
  const bool other_frame = !o_.frame.empty() && !msg.frame.empty() && msg.frame != o_.frame;
  // (A grid turned in its frame arrives resampled onto the frame's axes: FromGridMessage.)
  if (!map.ok() || other_frame) {
    ++grids_rejected_;
    LOG_WARN << "grid on " << channel << " rejected: "
             << (!map.ok() ? map.error().message
                           : "frame '" + msg.frame + "' is not '" + o_.frame + "'");
    return;
  }
  latest_[channel] = std::move(*map);
  newest_utime_ = std::max(newest_utime_, msg.utime);
  changed_ = true;
}

Result<FusionResult> MapFusionNode::FuseNow() {
  std::vector<SourceMap> maps;
  for (const auto& ch : o_.grid_channels)
    if (auto it = latest_.find(ch); it != latest_.end()) maps.push_back({ch, it->second});
  std::vector<SourceReport> reports;
  auto r = Fuse(maps, o_, &hints_, &reports);
  changed_ = false;
  for (const auto& s : reports)
    if (!s.used) ++sources_rejected_;
  if (!r.ok()) {
    ++fusion_failures_;
    LOG_WARN << "no fusion: " << r.error().message;
    heartbeat_.SetState(omni::heartbeat_t::STATE_DEGRADED, r.error().message);
    return r;
  }
  ++fusions_;
  alignments_tracked_ += static_cast<int64_t>(r->alignments_tracked);
  alignments_searched_ += static_cast<int64_t>(r->alignments_searched);
  bus::PublishGrid(*bus_, o_.fused_channel, r->fused,
                   newest_utime_ ? newest_utime_ : clock_->NowUtime(), "fused");
  heartbeat_.SetState(omni::heartbeat_t::STATE_OK,
                      "fused " + std::to_string(r->maps_used) + " maps onto " + r->base);
  last_ = *r;
  return r;
}

void MapFusionNode::Tick() {
  heartbeat_.Tick();
  const int64_t now = clock_->NowUtime();
  if (!changed_ || static_cast<int>(latest_.size()) < o_.min_maps) return;
  if (!PeriodDue(now, last_fuse_utime_, static_cast<int64_t>(o_.fuse_interval_s * 1e6))) return;
  last_fuse_utime_ = now;
  (void)FuseNow();
}

Status MapFusionNode::WriteOutputs(const std::string& dir) {
  auto r = FuseNow();
  if (!r.ok()) return r.error();
  return WriteFusionOutputs(*r, dir);
}

}  // namespace omni::map_fusion
