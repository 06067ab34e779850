#include "omni/map_fusion/map_fusion_node.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <system_error>
#include <utility>

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
  heartbeat_.AddCounter("fusing", [this] { return job_ ? int64_t{1} : int64_t{0}; });
  heartbeat_.AddCounter("last_fusion_ms", [this] { return last_fusion_ms_; });
  heartbeat_.AddCounter("sources_rejected", [this] { return sources_rejected_; });
  heartbeat_.AddCounter("sources_conflicting", [this] { return sources_conflicting_; });
  heartbeat_.AddCounter("alignments_tracked", [this] { return alignments_tracked_; });
  heartbeat_.AddCounter("alignments_searched", [this] { return alignments_searched_; });
  heartbeat_.AddCounter("maps_held", [this] { return static_cast<int64_t>(latest_.size()); });
  heartbeat_.AddCounter(
      "maps_fused", [this] { return last_ ? static_cast<int64_t>(last_->maps_used) : int64_t{0}; });
  SetState(omni::heartbeat_t::STATE_OK, "waiting for grids");
}

MapFusionNode::~MapFusionNode() {
  if (worker_.valid()) worker_.wait();
}

void MapFusionNode::SetState(int8_t state, const std::string& text) {
  state_ = state;
  state_text_ = text;
  if (stopping_)
    heartbeat_.SetState(omni::heartbeat_t::STATE_STOPPING, "writing the map; " + text);
  else
    heartbeat_.SetState(state, text);
}

void MapFusionNode::SetStopping() {
  stopping_ = true;
  SetState(state_, state_text_);
}

void MapFusionNode::ShowFusing() {
  if (!job_) return;
  char buf[96];
  std::snprintf(buf, sizeof(buf), "fusing %zu maps for %.1f s", job_->maps.size(),
                static_cast<double>(MonotonicMicros() - job_->started_us) * 1e-6);
  const std::string text = std::string(buf) + " (last: " + state_text_ + ")";
  if (stopping_)
    heartbeat_.SetState(omni::heartbeat_t::STATE_STOPPING, "writing the map; " + text);
  else
    heartbeat_.SetState(state_, text);
}

void MapFusionNode::OnGrid(const std::string& channel, const omni::occupancy_grid_t& msg) {
  ++grids_in_;
  if (static_cast<int64_t>(msg.width) * msg.height > o_.max_input_cells) {
    // Before decoding: the cap is there to keep its memory from being taken.
    ++grids_rejected_;
    LOG_WARN << "grid on " << channel << " rejected: " << msg.width << " x " << msg.height
             << " cells, more than max_input_cells (" << o_.max_input_cells << ")"
             << (latest_.count(channel) ? "; keeping the previous one" : "");
    return;
  }
  auto map = bus::FromGridMessage(msg);
  // (A grid turned in its frame arrives resampled onto the frame's axes: FromGridMessage.)
  std::string why;
  if (!map.ok()) {
    why = map.error().message;
  } else if (!o_.frame.empty() && !msg.frame.empty() && msg.frame != o_.frame) {
    why = "frame '" + msg.frame + "' is not '" + o_.frame + "'";
  } else if (static_cast<int64_t>(map->width) * map->height > o_.max_input_cells) {
    // (A grid turned in its frame grows when resampled onto the frame's axes.)
    why = std::to_string(map->width) + " x " + std::to_string(map->height) +
          " cells once on the frame's axes, more than max_input_cells (" +
          std::to_string(o_.max_input_cells) + ")";
  } else if (std::string unusable; !UsableMap(*map, &unusable)) {
    // The same checks as Fuse's: an empty grid (a mapper that restarted) must not replace the
    // channel's last good one.
    why = "occupancy grid from '" + msg.source + "': " + unusable;
  }
  if (!why.empty()) {
    ++grids_rejected_;
    LOG_WARN << "grid on " << channel << " rejected: " << why
             << (latest_.count(channel) ? "; keeping the previous one" : "");
    return;
  }
  latest_[channel] = Held{std::move(*map), msg.utime, msg.frame};
  changed_ = true;
  last_current_ = false;
}

void MapFusionNode::StartFusion() {
  auto job = std::make_unique<Job>();
  for (const auto& ch : o_.grid_channels)
    if (auto it = latest_.find(ch); it != latest_.end()) {
      job->maps.push_back({ch, it->second.map});
      job->utimes.push_back(it->second.utime);
    }
  job->options = o_;
  job->hints = hints_;
  job->started_us = MonotonicMicros();
  changed_ = false;
  Job* j = job.get();
  const FuseFn fuse = fuse_ ? fuse_ : FuseFn(&Fuse);
  auto run = [j, fuse] { j->result = fuse(j->maps, j->options, &j->hints, &j->reports); };
  job_ = std::move(job);
  try {
    worker_ = std::async(std::launch::async, run);
  } catch (const std::system_error& e) {
    LOG_WARN << "no worker thread (" << e.what() << "): fusing on this one";
    worker_ = {};
    run();
  }
  ShowFusing();
}

bool MapFusionNode::CollectFusion(bool wait, std::optional<Result<FusionResult>>* out) {
  if (!job_) return true;
  if (worker_.valid()) {
    while (worker_.wait_for(std::chrono::milliseconds(wait ? 50 : 0)) !=
           std::future_status::ready) {
      if (!wait) return false;
      ShowFusing();
      heartbeat_.Tick();
    }
    try {
      worker_.get();
    } catch (const std::exception& e) {  // e.g. bad_alloc: a failed fusion, not a crash
      job_->result = Result<FusionResult>(
          MakeError(ErrorCode::kInternal, std::string("fusion failed: ") + e.what()));
    }
  }
  const std::unique_ptr<Job> job = std::move(job_);
  hints_ = std::move(job->hints);
  last_fusion_ms_ = (MonotonicMicros() - job->started_us) / 1000;
  for (const auto& s : job->reports)
    if (!s.used) {
      ++sources_rejected_;
      if (s.conflict_fraction > job->options.max_conflict_fraction) ++sources_conflicting_;
    }
  if (!job->result)
    job->result = Result<FusionResult>(MakeError(ErrorCode::kInternal, "the fusion did not run"));
  if (out) *out = *job->result;
  if (!job->result->ok()) {
    const std::string& why = job->result->error().message;
    ++fusion_failures_;
    last_current_ = false;
    LOG_WARN << "no fusion: " << why;
    SetState(omni::heartbeat_t::STATE_DEGRADED, why);
    return true;
  }
  FusionResult& r = **job->result;
  ++fusions_;
  alignments_tracked_ += static_cast<int64_t>(r.alignments_tracked);
  alignments_searched_ += static_cast<int64_t>(r.alignments_searched);
  // The newest of the grids this fusion used: not a running maximum over every grid ever
  // received, which one grid stamped in the future (or a source clock set back) would pin.
  int64_t stamp = 0;
  for (size_t i = 0; i < r.sources.size() && i < job->utimes.size(); ++i)
    if (r.sources[i].used) stamp = std::max(stamp, job->utimes[i]);
  // In the inputs' frame (`frame`, or with "" the frame the base grid came in), not always "map".
  std::string frame = o_.frame;
  if (frame.empty()) {
    const auto base = latest_.find(r.base);
    frame = base != latest_.end() && !base->second.frame.empty() ? base->second.frame : "map";
  }
  bus::PublishGrid(*bus_, o_.fused_channel, r.fused, stamp > 0 ? stamp : clock_->NowUtime(),
                   "fused", frame);
  char secs[32];
  std::snprintf(secs, sizeof(secs), "%.1f", static_cast<double>(last_fusion_ms_) * 1e-3);
  SetState(omni::heartbeat_t::STATE_OK,
           "fused " + std::to_string(r.maps_used) + " maps onto " + r.base + " in " + secs + " s");
  last_ = std::move(r);
  last_current_ = !changed_;
  return true;
}

Result<FusionResult> MapFusionNode::FuseNow() {
  CollectFusion(true);
  StartFusion();
  std::optional<Result<FusionResult>> r;
  CollectFusion(true, &r);
  if (!r) return MakeError(ErrorCode::kInternal, "the fusion did not run");
  return std::move(*r);
}

void MapFusionNode::Tick() {
  CollectFusion(false);
  ShowFusing();
  heartbeat_.Tick();
  if (job_) return;  // one fusion at a time
  const int64_t now = clock_->NowUtime();
  if (!changed_ || static_cast<int>(latest_.size()) < o_.min_maps) return;
  if (!PeriodDue(now, last_fuse_utime_, static_cast<int64_t>(o_.fuse_interval_s * 1e6))) return;
  last_fuse_utime_ = now;
  StartFusion();
}

Status MapFusionNode::WriteOutputs(const std::string& dir) {
  CollectFusion(true);
  if (last_ && last_current_) return WriteFusionOutputs(*last_, dir);
  auto r = FuseNow();
  if (!r.ok()) return r.error();
  return WriteFusionOutputs(*r, dir);
}

}  // namespace omni::map_fusion
