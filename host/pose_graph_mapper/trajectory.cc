#include "omni/pose_graph_mapper/trajectory.h"
#include "omni/pose_graph_mapper/lie.h"

#include <Eigen/LU>

namespace omni::pgm {

std::optional<RelativeMotion> Trajectory::Motion(int64_t t0, int64_t t1) const {
  return source_->Between(t0, t1);
}

Result<int> Trajectory::PoseAt(int64_t utime) {
  // An existing pose within the tolerance.
  auto next = poses_.lower_bound(utime);
  if (next != poses_.end() && next->first - utime <= merge_tolerance_us_) return next->second.id;
  if (next != poses_.begin()) {
    auto prev = std::prev(next);
    if (utime - prev->first <= merge_tolerance_us_) return prev->second.id;
  }
  const bool has_prev = next != poses_.begin();
  const bool has_next = next != poses_.end();
  std::optional<RelativeMotion> before, after;
  if (has_prev) {
    before = Motion(std::prev(next)->first, utime);
    if (!before)
      return MakeError(ErrorCode::kUnavailable, source_->name() + " cannot cover " +
                                                    std::to_string(std::prev(next)->first) +
                                                    " .. " + std::to_string(utime) + " us yet");
  }
  if (has_next) {
    after = Motion(utime, next->first);
    if (!after)
      return MakeError(ErrorCode::kUnavailable, source_->name() + " cannot cover " +
                                                    std::to_string(utime) + " .. " +
                                                    std::to_string(next->first) + " us");
  }
  const int id = next_id_++;
  Pose2 estimate;
  if (has_prev)
    estimate = std::prev(next)->second.estimate * before->delta;
  else if (has_next)
    estimate = next->second.estimate * after->delta.Inverse();
  if (has_prev && has_next) {
    links_.erase(std::prev(next)->first);  // the old link [prev, next] is replaced by two
    ++splices_;
  }
  if (has_prev) {
    const auto& p = *std::prev(next);
    links_[p.first] = LinkFactor{p.second.id, id, p.first, utime, *before};
  }
  if (has_next) links_[utime] = LinkFactor{id, next->second.id, utime, next->first, *after};
  poses_.emplace(utime, Node{id, estimate});
  time_of_[id] = utime;
  return id;
}

std::optional<int64_t> Trajectory::TimeOf(int id) const {
  auto it = time_of_.find(id);
  if (it == time_of_.end()) return std::nullopt;
  return it->second;
}

std::vector<LinkFactor> Trajectory::Links() const {
  std::vector<LinkFactor> out;
  out.reserve(links_.size());
  for (const auto& [t, l] : links_) out.push_back(l);
  return out;
}

std::optional<Pose2> Trajectory::Estimate(int id) const {
  auto t = TimeOf(id);
  if (!t) return std::nullopt;
  return poses_.at(*t).estimate;
}

bool Trajectory::SetEstimate(int id, const Pose2& pose) {
  auto t = TimeOf(id);
  if (!t) return false;
  poses_.at(*t).estimate = pose;
  return true;
}

io::PoseGraph Trajectory::ToPoseGraph() const {
  io::PoseGraph g;
  for (const auto& [t, n] : poses_) g.vertices2.push_back({n.id, n.estimate});
  for (const auto& [t, l] : links_) {
    io::Edge2 e;
    e.from = l.from_id;
    e.to = l.to_id;
    e.measurement = l.motion.delta;
    // A tiny floor keeps a zero-motion, zero-duration link invertible.
    e.information = RelativeInformation(l.motion.delta, l.motion.covariance, 1e-12);
    g.edges2.push_back(e);
  }
  return g;
}

}  // namespace omni::pgm
