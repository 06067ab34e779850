// The mapper core's trajectory: one pose per measurement timestamp ("pose for this time" is the
// one way a measurement plugin gets a pose), and every pair of time-consecutive poses linked by
// one factor from the continuous pose source (odometry, or the null motion model).
//
// Pose splicing (OmniMapper's future work, section III): a pose requested for a time inside an
// interval that is already linked replaces that interval's factor by two factors (earlier ->
// new, new -> later), computed by the source for the two sub-intervals, so the information of
// the old factor is neither kept twice nor lost (see continuous_source.h).
#pragma once

#include <cstdint>
#include <iterator>
#include <map>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "omni/common/geometry.h"
#include "omni/common/result.h"
#include "omni/io/g2o.h"
#include "omni/pose_graph_mapper/continuous_source.h"

namespace omni::pgm {

struct LinkFactor {
  int from_id = 0, to_id = 0;
  int64_t from_utime = 0, to_utime = 0;
  RelativeMotion motion;  // pose `to` in the frame of `from`, covariance in that frame
};

class Trajectory {
 public:
  // `source` must outlive the trajectory. Requests within `merge_tolerance_us` of an existing
  // pose return that pose.
  explicit Trajectory(const ContinuousPoseSource* source, int64_t merge_tolerance_us = 0)
      : source_(source), merge_tolerance_us_(merge_tolerance_us) {}

  // The id of the pose for `utime`, created (and linked, or spliced in) when absent.
  // kUnavailable when the source cannot yet cover the interval to a neighbour: nothing changes
  // and the caller keeps the measurement queued.
  Result<int> PoseAt(int64_t utime);

  size_t size() const { return poses_.size(); }
  std::optional<int64_t> TimeOf(int id) const;
  // Links between consecutive poses, in time order (size() - 1 of them).
  std::vector<LinkFactor> Links() const;
  int splices() const { return splices_; }

  // Current estimate of a pose (new poses are chained from a neighbour's estimate).
  std::optional<Pose2> Estimate(int id) const;
  bool SetEstimate(int id, const Pose2& pose);

  // The trajectory as a pose graph (vertices = poses with their estimates, edges = links with
  // information = covariance^-1), for the batch optimiser or g2o output.
  io::PoseGraph ToPoseGraph() const;

 private:
  struct Node {
    int id;
    Pose2 estimate;
  };
  std::optional<RelativeMotion> Motion(int64_t t0, int64_t t1) const;

  const ContinuousPoseSource* source_;
  int64_t merge_tolerance_us_;
  std::map<int64_t, Node> poses_;        // by time
  std::map<int64_t, LinkFactor> links_;  // by the earlier pose's time
  std::map<int, int64_t> time_of_;
  int next_id_ = 0;
  int splices_ = 0;
};

// Measurement queueing (OmniMapper section III): measurements wait `window_us` before they are
// committed to the graph, so slower sensors can catch up; what arrives later than the window
// (older than the last committed time) is handed out as late, for pose splicing.
template <typename M>
class MeasurementQueue {
 public:
  explicit MeasurementQueue(int64_t window_us) : window_us_(window_us) {}
  void Push(int64_t utime, M m) { pending_.emplace(utime, std::move(m)); }
  // Every pending measurement with utime <= now - window, in time order; `late` (optional)
  // receives how many of them are older than what was committed before (they need splicing).
  std::vector<std::pair<int64_t, M>> PopCommitted(int64_t now_us, int* late = nullptr) {
    std::vector<std::pair<int64_t, M>> out;
    const int64_t horizon = now_us - window_us_;
    int n_late = 0;
    while (!pending_.empty() && pending_.begin()->first <= horizon) {
      auto node = pending_.extract(pending_.begin());
      if (node.key() < committed_until_) ++n_late;
      out.emplace_back(node.key(), std::move(node.mapped()));
    }
    if (horizon > committed_until_) committed_until_ = horizon;
    if (late) *late = n_late;
    return out;
  }
  size_t pending() const { return pending_.size(); }

 private:
  int64_t window_us_;
  int64_t committed_until_ = INT64_MIN;
  std::multimap<int64_t, M> pending_;
};

}  // namespace omni::pgm
