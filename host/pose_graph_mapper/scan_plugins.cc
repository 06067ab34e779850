#include "omni/pose_graph_mapper/scan_plugins.h"

#include <algorithm>
#include <memory>
#include <thread>
#include <utility>

namespace omni::pgm {

namespace {

std::vector<Eigen::Vector2d> Clip(const std::vector<Eigen::Vector2d>& pts, double max_range) {
  std::vector<Eigen::Vector2d> out;
  out.reserve(pts.size());
  for (const auto& p : pts)
    if (p.norm() <= max_range) out.push_back(p);
  return out;
}

RelativePoseFactor MakeFactor(const Keyframe& from, const Keyframe& to, const MatchResult& m,
                              const std::string& plugin) {
  RelativePoseFactor f;
  f.from_utime = from.utime;
  f.to_utime = to.utime;
  f.delta = m.pose;
  f.covariance = m.covariance;
  f.plugin = plugin;
  f.score = m.score;
  return f;
}

}  // namespace

std::vector<Eigen::Vector2d> BuildSubmap(const std::vector<Keyframe>& keyframes, int first,
                                         int last, int centre, double max_range_m,
                                         double fill_gap_m, double fill_step_m) {
  std::vector<Eigen::Vector2d> out;
  const int n = static_cast<int>(keyframes.size());
  first = std::max(first, 0);
  last = std::min(last, n - 1);
  if (centre < 0 || centre >= n) return out;
  const Pose2 inv = keyframes[centre].estimate.Inverse();
  const bool fill = fill_gap_m > 0 && fill_step_m > 0;
  for (int i = first; i <= last; ++i) {
    const Pose2 rel = inv * keyframes[i].estimate;
    const Eigen::Vector2d* prev = nullptr;
    for (const auto& p : keyframes[i].points) {
      if (p.norm() > max_range_m) {
        prev = nullptr;
        continue;
      }
      if (fill && prev) {
        // Points between two neighbouring end points closer than fill_gap_m: the surface they
        // both lie on, sampled every fill_step_m.
        const double gap = (p - *prev).norm();
        if (gap <= fill_gap_m) {
          const int steps = static_cast<int>(gap / fill_step_m);
          for (int s = 1; s < steps; ++s)
            out.push_back(rel.Transform(*prev + (p - *prev) * (s / static_cast<double>(steps))));
        }
      }
      out.push_back(rel.Transform(p));
      prev = &p;
    }
  }
  return out;
}

std::vector<RelativePoseFactor> KeyframeMatchPlugin::OnKeyframe(
    const std::vector<Keyframe>& keyframes) {
  std::vector<RelativePoseFactor> out;
  if (keyframes.size() < 2) return out;
  Count("attempts");
  const int cur = static_cast<int>(keyframes.size()) - 1, prev = cur - 1;
  const auto query = Clip(keyframes[cur].points, o_.max_range_m);
  if (query.empty()) {
    Count("empty_scan");
    return out;
  }
  const auto submap = BuildSubmap(keyframes, cur - o_.submap_keyframes, prev, prev, o_.max_range_m,
                                  o_.fill_gap_m, o_.field.resolution_m);
  if (submap.empty()) {
    Count("empty_submap");
    return out;
  }
  const LikelihoodField field(submap, o_.field);
  const Pose2 guess = keyframes[prev].estimate.Between(keyframes[cur].estimate);
  SearchWindow w = o_.window;
  w.min_score = o_.min_score;
  last_ = MatchScan(field, query, guess, w);
  if (last_.score < o_.min_score || last_.inlier_fraction < o_.min_inlier_fraction) {
    Count("no_match");
    return out;
  }
  if (o_.reject_window_edge && last_.on_window_edge) {
    Count("window_edge");
    return out;
  }
  Count("accepted");
  out.push_back(MakeFactor(keyframes[prev], keyframes[cur], last_, name()));
  return out;
}

LoopClosurePlugin::CachedField LoopClosurePlugin::FieldKey(const std::vector<Keyframe>& keyframes,
                                                           int candidate) const {
  const int n = static_cast<int>(keyframes.size());
  const int first = std::max(candidate - o_.submap_half_width, 0);
  const int last = std::min(candidate + o_.submap_half_width, n - 1);
  CachedField entry;
  entry.key.push_back(candidate);
  const Pose2 inv = keyframes[candidate].estimate.Inverse();
  for (int i = first; i <= last; ++i) {
    entry.key.push_back(keyframes[i].utime);
    entry.key.push_back(static_cast<int64_t>(keyframes[i].points.size()));
    entry.poses.push_back(inv * keyframes[i].estimate);
  }
  return entry;
}

std::shared_ptr<const LikelihoodField> LoopClosurePlugin::FindField(const CachedField& entry) {
  auto same = [&](const CachedField& c) {
    if (c.key != entry.key) return false;
    for (size_t i = 0; i < c.poses.size(); ++i)
      if (c.poses[i].x != entry.poses[i].x || c.poses[i].y != entry.poses[i].y ||
          c.poses[i].theta != entry.poses[i].theta)
        return false;
    return true;
  };
  for (auto it = cache_.begin(); it != cache_.end(); ++it)
    if (same(*it)) {
      Count("field_cache_hits");
      std::rotate(it, it + 1, cache_.end());  // now the most recently used
      return cache_.back().field;
    }
  return nullptr;
}

std::shared_ptr<const LikelihoodField> LoopClosurePlugin::BuildField(
    const std::vector<Keyframe>& keyframes, int candidate) const {
  const auto submap =
      BuildSubmap(keyframes, candidate - o_.submap_half_width, candidate + o_.submap_half_width,
                  candidate, o_.max_range_m, o_.fill_gap_m, o_.field.resolution_m);
  if (submap.empty()) return nullptr;
  return std::make_shared<const LikelihoodField>(submap, o_.field);
}

void LoopClosurePlugin::CacheField(CachedField entry) {
  if (o_.field_cache_size <= 0 || !entry.field) return;
  if (static_cast<int>(cache_.size()) >= o_.field_cache_size) cache_.erase(cache_.begin());
  cache_.push_back(std::move(entry));
}

LoopAttempt LoopClosurePlugin::Verify(const std::vector<Keyframe>& keyframes, int candidate,
                                      const LikelihoodField& field,
                                      const std::vector<Eigen::Vector2d>& query,
                                      const SearchWindow& window) const {
  LoopAttempt at;
  at.candidate = candidate;
  const int cur = static_cast<int>(keyframes.size()) - 1;
  const Pose2 guess = keyframes[candidate].estimate.Between(keyframes[cur].estimate);
  SearchWindow w = window;
  w.min_score = o_.min_score;
  at.match = MatchScan(field, query, guess, w);
  if (at.match.score < o_.min_score) {
    at.reason = "low_score";
  } else if (at.match.inlier_fraction < o_.min_inlier_fraction) {
    at.reason = "few_inliers";
  } else if (o_.max_ambiguity_ratio > 0 &&
             at.match.second_score > o_.max_ambiguity_ratio * at.match.score) {
    at.reason = "ambiguous";
  } else {
    at.reason = "accepted";
    at.accepted = true;
  }
  return at;
}

LoopAttempt LoopClosurePlugin::TryCandidate(const std::vector<Keyframe>& keyframes, int candidate) {
  LoopAttempt at;
  at.candidate = candidate;
  const int n = static_cast<int>(keyframes.size());
  const auto query = Clip(keyframes[n - 1].points, o_.max_range_m);
  if (query.empty() || candidate < 0 || candidate >= n) {
    at.reason = "empty_scan";
    return at;
  }
  CachedField entry = FieldKey(keyframes, candidate);
  auto field = FindField(entry);
  if (!field) {
    field = BuildField(keyframes, candidate);
    entry.field = field;
    CacheField(std::move(entry));
  }
  if (!field) {
    at.reason = "empty_scan";
    return at;
  }
  return Verify(keyframes, candidate, *field, query, o_.window);
}

std::vector<RelativePoseFactor> LoopClosurePlugin::OnKeyframe(
    const std::vector<Keyframe>& keyframes) {
  std::vector<RelativePoseFactor> out;
  attempts_.clear();
  const int cur = static_cast<int>(keyframes.size()) - 1;
  last_window_m_ = o_.window.x_m;
  if (cur < o_.min_index_gap) return out;
  // The window grows with the path travelled since the last accepted loop.
  SearchWindow window = o_.window;
  double grow = 0;
  if (o_.window_growth_per_m > 0) {
    double path = 0;
    for (int i = std::min(last_loop_keyframe_, cur) + 1; i <= cur; ++i)
      path +=
          (keyframes[i].estimate.translation() - keyframes[i - 1].estimate.translation()).norm();
    const double widest = std::max(o_.max_window_m, std::max(window.x_m, window.y_m));
    grow = std::min(o_.window_growth_per_m * path, widest - std::min(window.x_m, window.y_m));
    window.x_m = std::min(window.x_m + grow, widest);
    window.y_m = std::min(window.y_m + grow, widest);
  }
  last_window_m_ = window.x_m;
  // Candidates far back in the trajectory and near the current estimate, nearest first.
  std::vector<std::pair<double, int>> cands;
  const Eigen::Vector2d here = keyframes[cur].estimate.translation();
  for (int i = 0; i <= cur - o_.min_index_gap; ++i) {
    if (keyframes[i].retired) continue;
    const double d = (keyframes[i].estimate.translation() - here).norm();
    if (d <= o_.search_radius_m + grow) cands.emplace_back(d, i);
  }
  std::sort(cands.begin(), cands.end());
  if (static_cast<int>(cands.size()) > o_.max_candidates) cands.resize(o_.max_candidates);
  if (cands.empty()) return out;

  // Cached fields are looked up here; missing ones are built by the workers and cached after.
  const auto query = Clip(keyframes[cur].points, o_.max_range_m);
  struct Job {
    CachedField entry;
    bool built = false;
    LoopAttempt at;
  };
  std::vector<Job> jobs(cands.size());
  for (size_t j = 0; j < cands.size(); ++j) {
    jobs[j].entry = FieldKey(keyframes, cands[j].second);
    jobs[j].entry.field = FindField(jobs[j].entry);
  }
  auto run = [&](size_t first, size_t step) {
    for (size_t j = first; j < jobs.size(); j += step) {
      Job& job = jobs[j];
      const int c = cands[j].second;
      if (query.empty()) {
        job.at.candidate = c;
        job.at.reason = "empty_scan";
        continue;
      }
      if (!job.entry.field) {
        job.entry.field = BuildField(keyframes, c);
        job.built = true;
      }
      if (!job.entry.field) {
        job.at.candidate = c;
        job.at.reason = "empty_scan";
        continue;
      }
      job.at = Verify(keyframes, c, *job.entry.field, query, window);
    }
  };
  const size_t threads = std::min(jobs.size(), static_cast<size_t>(std::max(1, o_.num_threads)));
  std::vector<std::thread> workers;
  for (size_t t = 1; t < threads; ++t) workers.emplace_back(run, t, threads);
  run(0, threads);
  for (auto& w : workers) w.join();

  for (size_t j = 0; j < jobs.size(); ++j) {
    Job& job = jobs[j];
    if (job.built) CacheField(job.entry);
    Count("attempts");
    Count(job.at.reason);
    attempts_.push_back(std::move(job.at));
    const LoopAttempt& at = attempts_.back();
    if (at.accepted)
      out.push_back(MakeFactor(keyframes[cands[j].second], keyframes[cur], at.match, name()));
  }
  if (!out.empty()) last_loop_keyframe_ = cur;
  return out;
}

}  // namespace omni::pgm
