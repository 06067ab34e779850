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

#include <cstdint>
#include <deque>
#include <optional>
#include <vector>

#include <Eigen/Geometry>

#include "omni/common/geometry.h"

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

  explicit FramePoser(const FramePoserOptions& options) : options_(options) {}

  // Returns false (and counts) for a pose older than the newest one.
  bool AddPose(int64_t utime, const Pose2& pose) {
    ++counters_.poses_in;
    if (!poses_.empty() && utime < poses_.back().first) {
      ++counters_.poses_out_of_order;
      return false;
    }
    if (!poses_.empty() && utime == poses_.back().first)
      poses_.back().second = pose;
    else
      poses_.emplace_back(utime, pose);
    while (poses_.size() > options_.pose_capacity) poses_.pop_front();
    return true;
  }

  // Returns false (and counts) for a frame older than the previous frame.
  bool AddFrame(int64_t utime, T frame) {
    ++counters_.frames_in;
    if (last_frame_utime_ && utime < *last_frame_utime_) {
      ++counters_.frames_out_of_order;
      return false;
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
    if (poses_.empty() || utime < poses_.front().first || utime > poses_.back().first)
      return std::nullopt;
    size_t lo = 0, hi = poses_.size() - 1;
    if (poses_[hi].first == utime) return poses_[hi].second;
    while (hi - lo > 1) {
      const size_t mid = (lo + hi) / 2;
      if (poses_[mid].first <= utime)
        lo = mid;
      else
        hi = mid;
    }
    const auto& a = poses_[lo];
    const auto& b = poses_[hi];
    if (a.first == utime) return a.second;
    if (b.first - a.first > options_.max_pose_gap_us) return std::nullopt;
    const double f = static_cast<double>(utime - a.first) / static_cast<double>(b.first - a.first);
    return Interpolate(a.second, b.second, f);
  }

  const FramePoserCounters& counters() const { return counters_; }
  size_t queued() const { return frames_.size(); }
  int64_t newest_pose_utime() const { return poses_.empty() ? 0 : poses_.back().first; }

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
    if (!poses_.empty() && utime <= poses_.back().first) {
      d.pose = PoseAt(utime);  // nullopt: older than the poses, or a gap
      return d;
    }
    // No pose at or after the frame yet: wait unless the latency has expired.
    d.wait = now - utime <= options_.max_latency_us;
    return d;
  }

  FramePoserOptions options_;
  FramePoserCounters counters_;
  std::deque<std::pair<int64_t, Pose2>> poses_;
  std::deque<Queued> frames_;
  std::optional<int64_t> last_frame_utime_;
};

}  // namespace omni::octo
