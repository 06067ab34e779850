// Poses depth frames with the 2D SLAM's robot poses: the robot pose at the frame's time,
// interpolated between pose messages, composed with the camera's mounting pose.
//
// Latency rule: a frame waits until a pose at or after its time has arrived, so it can be
// interpolated (never extrapolated). It is dropped ("no pose") when
//  - it is older than the oldest pose kept (the poses it needs are gone or never came),
//  - the poses around it are further apart than max_pose_gap_us (a gap in the SLAM output), or
//  - `now` passes frame time + max_latency_us while no newer pose has come.
// `now` is passed in (the newest data time seen, so a log replay decides the same way).
#pragma once

#include <algorithm>
#include <climits>
#include <cstdint>
#include <deque>
#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "omni/common/geometry.h"
#include "omni/common/scan_checks.h"
#include "omni/common/stamp_order.h"

namespace omni::octo {

// Camera optical frame (z forward, x right, y down) on the robot base (x forward, y left,
// z up): position, yaw about the base z axis, tilt downwards about the camera's own y axis
// (positive looks down), roll about the optical axis.
struct CameraMount {
  double x_m = 0;
  double y_m = 0;
  double height_m = 0;
  double yaw_rad = 0;
  double tilt_rad = 0;
  double roll_rad = 0;
};

// Base-to-optical transform: a point in the optical frame maps to the base frame.
Eigen::Isometry3d MountToIsometry(const CameraMount& mount);
// Camera optical frame in the map frame for a robot pose in the map frame.
Eigen::Isometry3d CameraInMap(const Pose2& robot_in_map, const CameraMount& mount);

struct FramePoserOptions {
  int64_t max_latency_us = 2000000;   // how long a frame may wait for a newer pose
  int64_t max_pose_gap_us = 2000000;  // bracketing poses further apart than this: no pose
  size_t max_queued_frames = 90;      // older frames are dropped beyond this
  size_t pose_capacity = 2000;        // poses kept for interpolation
};

struct FramePoserCounters {
  int64_t frames_in = 0;
  int64_t frames_posed = 0;
  int64_t frames_dropped_no_pose = 0;  // older than the poses, gap, or latency expired
  int64_t frames_dropped_queue = 0;    // queue full
  int64_t frames_out_of_order = 0;     // frame older than the previous frame: rejected
  int64_t poses_in = 0;
  int64_t poses_out_of_order = 0;  // pose older than the newest pose: rejected
  // Not finite, or beyond 1000 km / a million radians (PlausibleOdometryPose): rejected.
  int64_t poses_invalid = 0;
  // Poses or frames whose newest stamp was followed by a run of older, in-order ones: it was
  // stamped in the future (or the clock went back); dropped, the run taken (stamp_order.h).
  int64_t time_rebases = 0;
  int64_t frames_dropped_future = 0;  // queued frames dropped by such a re-base
};

// Queues frames (any payload T) until they can be posed.
template <class T>
class FramePoser {
 public:
  struct Posed {
    T frame;
    int64_t utime;
    Pose2 robot_in_map;
  };

  explicit FramePoser(const FramePoserOptions& options)
      : options_(options), poses_(options.pose_capacity) {}

  // Returns false (and counts) for a pose older than the newest one or one no SLAM could give.
  bool AddPose(int64_t utime, const Pose2& pose) {
    ++counters_.poses_in;
    if (!PlausibleOdometryPose(pose)) {
      ++counters_.poses_invalid;
      return false;
    }
    const int64_t rebases = poses_.rebases();
    if (!poses_.Insert(utime, pose)) {
      ++counters_.poses_out_of_order;
      return false;
    }
    counters_.time_rebases += poses_.rebases() - rebases;
    return true;
  }

  // Returns false (and counts) for a frame older than the previous frame.
  bool AddFrame(int64_t utime, T frame) {
    ++counters_.frames_in;
    switch (frame_order_.Check(utime)) {
      case StampOrder::Verdict::kOld:
        ++counters_.frames_out_of_order;
        return false;
      case StampOrder::Verdict::kRebase: {
        // Queued frames newer than this one were stamped in the future: they would wait for a
        // pose that never comes.
        ++counters_.time_rebases;
        const size_t before = frames_.size();
        frames_.erase(std::remove_if(frames_.begin(), frames_.end(),
                                     [&](const Queued& q) { return q.utime > utime; }),
                      frames_.end());
        counters_.frames_dropped_future += static_cast<int64_t>(before - frames_.size());
        trusted_frame_utime_ = utime;
        break;
      }
      case StampOrder::Verdict::kInOrder:
        // A frame long after the one before it (a glitch, or the camera was off) moves the
        // frames' time only once the next frame confirms it.
        if (last_frame_utime_ == INT64_MIN || utime - last_frame_utime_ <= kMaxFrameStepUs)
          trusted_frame_utime_ = utime;
        break;
    }
    last_frame_utime_ = utime;
    frames_.push_back({std::move(frame), utime});
    while (frames_.size() > options_.max_queued_frames) {
      frames_.pop_front();
      ++counters_.frames_dropped_queue;
    }
    return true;
  }

  // Frames that can be posed now, in time order; drops those that never will be.
  std::vector<Posed> Poll(int64_t now_utime) {
    std::vector<Posed> out;
    while (!frames_.empty()) {
      Queued& f = frames_.front();
      const Decision d = Decide(f.utime, now_utime);
      if (d.wait) break;
      if (d.pose) {
        out.push_back({std::move(f.frame), f.utime, *d.pose});
        ++counters_.frames_posed;
      } else {
        ++counters_.frames_dropped_no_pose;
      }
      frames_.pop_front();
    }
    return out;
  }

  // Interpolated robot pose at `utime`, if bracketed by poses no further apart than the gap.
  std::optional<Pose2> PoseAt(int64_t utime) const {
    return poses_.At(utime, 0, options_.max_pose_gap_us);
  }

  const FramePoserCounters& counters() const { return counters_; }
  size_t queued() const { return frames_.size(); }
  int64_t newest_pose_utime() const { return poses_.newest_utime(); }
  // The newest frame's stamp as far as it can be trusted (the pipeline's `now` follows it):
  // one frame stamped far ahead does not expire every waiting frame's latency.
  int64_t newest_frame_utime() const { return trusted_frame_utime_; }
  static constexpr int64_t kMaxFrameStepUs = 10000000;

 private:
  struct Queued {
    T frame;
    int64_t utime;
  };
  struct Decision {
    bool wait = false;
    std::optional<Pose2> pose;
  };
  Decision Decide(int64_t utime, int64_t now) const {
    Decision d;
    if (!poses_.empty() && utime <= poses_.newest_utime()) {
      d.pose = PoseAt(utime);  // nullopt: older than the poses, or a gap
      return d;
    }
    // No pose at or after the frame yet: wait unless the latency has expired.
    d.wait = now - utime <= options_.max_latency_us;
    return d;
  }

  FramePoserOptions options_;
  FramePoserCounters counters_;
  StampedBuffer<Pose2> poses_;
  std::deque<Queued> frames_;
  StampOrder frame_order_;
  int64_t last_frame_utime_ = INT64_MIN;
  int64_t trusted_frame_utime_ = 0;
};

// A recorded trajectory (poses in strictly increasing time) handed to a FramePoser as the frames
// come, instead of live pose messages (`omni octomap build LOG --poses FILE`): before a frame at
// time t, every pose up to t, and the first pose after t unless one at or after t was already
// handed over. So the poses handed over never run more than one ahead of the frames, whatever
// the two rates, and the poser's bounded pose buffer keeps what the waiting frames need.
class PoseFeed {
 public:
  explicit PoseFeed(std::vector<std::pair<int64_t, Pose2>> poses) : poses_(std::move(poses)) {}
  // Calls add(utime, pose) for the poses a frame at `utime` needs; returns how many.
  template <class Add>
  size_t FeedFor(int64_t utime, Add&& add) {
    const size_t before = next_;
    while (next_ < poses_.size() && poses_[next_].first <= utime) Next(add);
    if (next_ < poses_.size() && (next_ == 0 || poses_[next_ - 1].first < utime)) Next(add);
    return next_ - before;
  }
  // Every pose not yet handed over (the end of the frames).
  template <class Add>
  size_t FeedRest(Add&& add) {
    const size_t before = next_;
    while (next_ < poses_.size()) Next(add);
    return next_ - before;
  }
  size_t size() const { return poses_.size(); }
  size_t fed() const { return next_; }

 private:
  template <class Add>
  void Next(Add& add) {
    add(poses_[next_].first, poses_[next_].second);
    ++next_;
  }
  std::vector<std::pair<int64_t, Pose2>> poses_;
  size_t next_ = 0;
};

}  // namespace omni::octo
