// Two laser measurement plugins built on scan_matching.h:
//  - KeyframeMatchPlugin: the new keyframe's scan against a local submap of the previous few
//    keyframes, searched in a small window around the odometry guess (the estimates' relative
//    pose); one factor previous -> new, or "no match" (counted) when the score is poor.
//  - LoopClosurePlugin: the new keyframe against the submaps of keyframes far back in the
//    trajectory (index gap >= min_index_gap) whose estimate is within search_radius_m, in a wide
//    window; a match is only added once verified (score, matched beams, ambiguity); every
//    rejection is counted by reason and kept in last_attempts().
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "omni/pose_graph_mapper/measurement_plugin.h"
#include "omni/pose_graph_mapper/scan_matching.h"

namespace omni::pgm {

// The points of keyframes [first, last] mapped into the frame of keyframe `centre` with the
// current estimates. Points farther than `max_range_m` from their own keyframe are dropped.
// With fill_gap_m > 0, two consecutive points of one keyframe (neighbouring beams) at most
// fill_gap_m apart are joined by points about fill_step_m apart (the gap split into
// floor(gap / fill_step_m) equal steps): the field then follows the surface instead of having a
// bump per beam end (sparse beams along a corridor wall otherwise give false optima along it).
std::vector<Eigen::Vector2d> BuildSubmap(const std::vector<Keyframe>& keyframes, int first,
                                         int last, int centre, double max_range_m,
                                         double fill_gap_m = 0, double fill_step_m = 0);

inline LikelihoodFieldOptions FieldWithMargin(double margin_m) {
  LikelihoodFieldOptions o;
  o.margin_m = margin_m;
  return o;
}

struct KeyframeMatchOptions {
  int submap_keyframes = 3;   // previous keyframes in the local submap
  double max_range_m = 20.0;  // beams longer than this are ignored
  double min_score = 0.35;    // below: "no match"
  double min_inlier_fraction = 0.4;
  double fill_gap_m = 0;  // submap: neighbouring end points this close joined (BuildSubmap)
  // A match whose best candidate lies on the window's boundary gives no factor ("window_edge"):
  // the scan fits better outside the window, far from the odometry guess.
  bool reject_window_edge = false;
  LikelihoodFieldOptions field;
  SearchWindow window = MakeSearchWindow(0.3, 0.17);
};

class KeyframeMatchPlugin final : public MeasurementPlugin {
 public:
  explicit KeyframeMatchPlugin(KeyframeMatchOptions o = {}) : o_(o) {}
  std::string name() const override { return "scan_match"; }
  std::vector<RelativePoseFactor> OnKeyframe(const std::vector<Keyframe>& keyframes) override;
  const MatchResult& last_match() const { return last_; }

 private:
  KeyframeMatchOptions o_;
  MatchResult last_;
};

struct LoopClosureOptions {
  int min_index_gap = 50;        // candidates are at least this many keyframes back
  double search_radius_m = 5.0;  // ... and within this distance of the current estimate
  int max_candidates = 3;        // nearest candidates tried per keyframe
  int submap_half_width = 2;     // submap = candidate +- this many keyframes
  double max_range_m = 20.0;
  double fill_gap_m = 0;  // submap: neighbouring end points this close joined (BuildSubmap)
  // Verification.
  // Defaults from the Intel tests (plugin_test.cc): true revisits score >= 0.79 with >= 84 % of
  // beams matched, the best false loop (a similar corridor) 0.68 / 72 %.
  double min_score = 0.73;
  double min_inlier_fraction = 0.78;
  double max_ambiguity_ratio = 0.9;  // second best elsewhere / best; <= 0 disables the check
  // The grid reaches 2.5 m beyond the submap (1 m for the keyframe matcher): wider than the
  // +-2 m window, so query points over the submap stay on the grid for every translation and
  // are scored without bounds checks (the scores are the same; only the zero border grows).
  LikelihoodFieldOptions field = FieldWithMargin(2.5);
  SearchWindow window = MakeSearchWindow(2.0, 0.5);
  // The drift the search must cover grows with the path travelled since the robot's pose was
  // last tied to the old map: the path length (sum of the keyframe estimates' steps) since the
  // last accepted loop, or since the first keyframe before any, times this rate widens the
  // window's x and y half-widths and the candidate radius (0: fixed window and radius). The
  // half-width is capped at max_window_m; the candidate radius grows by the same amount.
  double window_growth_per_m = 0;
  double max_window_m = 2.0;
  // Likelihood fields of the most recent candidates' submaps kept for reuse: consecutive
  // keyframes near one place try the same old keyframes, whose submap is unchanged until a
  // global optimisation moves them. A field is reused only when the submap's keyframes (times,
  // point counts, poses relative to the candidate) are exactly those it was built from, so the
  // result is the same as without the cache. Off by default: with the field built in about
  // 0.5 ms, 8 cached fields saved no measurable time on intel-raw (half the attempts hit) and
  // raised the peak memory from 34 to 55 MB (ACES: 52 to 89 MB).
  int field_cache_size = 0;
  // Candidates of one keyframe matched concurrently on this many threads (the calling thread
  // and num_threads - 1 started per keyframe). Candidates are independent and their results are
  // merged in candidate order, so the factors are the same for any number of threads.
  int num_threads = 1;
};

struct LoopAttempt {
  int candidate = -1;  // keyframe index
  bool accepted = false;
  std::string reason;  // "accepted", "low_score", "few_inliers", "ambiguous", "empty_scan"
  MatchResult match;
};

class LoopClosurePlugin final : public MeasurementPlugin {
 public:
  explicit LoopClosurePlugin(LoopClosureOptions o = {}) : o_(o) {}
  std::string name() const override { return "loop_closure"; }
  std::vector<RelativePoseFactor> OnKeyframe(const std::vector<Keyframe>& keyframes) override;
  // Checks one candidate against the newest keyframe (also used by OnKeyframe).
  LoopAttempt TryCandidate(const std::vector<Keyframe>& keyframes, int candidate);
  const std::vector<LoopAttempt>& last_attempts() const { return attempts_; }
  // The x/y half-width of the last OnKeyframe's search window (window.x_m until it grows).
  double last_window_m() const { return last_window_m_; }

 private:
  // A candidate submap's field and what it was built from (see field_cache_size).
  struct CachedField {
    std::vector<int64_t> key;  // candidate, then per keyframe: utime, point count
    std::vector<Pose2> poses;  // submap keyframes relative to the candidate
    std::shared_ptr<const LikelihoodField> field;
  };
  // What a candidate's field is built from; the cached field when there is one.
  CachedField FieldKey(const std::vector<Keyframe>& keyframes, int candidate) const;
  std::shared_ptr<const LikelihoodField> FindField(const CachedField& key);
  // Builds the key's field (null for an empty submap); touches no member, so threads may call it.
  std::shared_ptr<const LikelihoodField> BuildField(const std::vector<Keyframe>& keyframes,
                                                    int candidate) const;
  void CacheField(CachedField entry);
  // Matches and verifies the query against a candidate's field; const, for the worker threads.
  LoopAttempt Verify(const std::vector<Keyframe>& keyframes, int candidate,
                     const LikelihoodField& field, const std::vector<Eigen::Vector2d>& query,
                     const SearchWindow& window) const;

  LoopClosureOptions o_;
  int last_loop_keyframe_ = 0;  // newest keyframe with an accepted loop (0 before any)
  double last_window_m_ = 0;
  std::vector<LoopAttempt> attempts_;
  std::vector<CachedField> cache_;  // most recently used last
};

}  // namespace omni::pgm
