// Re-posing the OctoMap when the 2D SLAM corrects its trajectory (a loop closes, the RBPF's
// reported particle changes lineage): the frames were inserted at the poses published when they
// came, and an occupancy tree cannot move what it has integrated, so the tree is built again.
//
// Keyframes: a frame is kept when the robot has moved keyframe_distance_m or turned
// keyframe_angle_rad since the last keyframe, or keyframe_interval_s has passed; its points (in
// the camera frame, thinned to one per point_spacing_m cube: the centroid, with the first
// non-zero colour seen in it, stored in whole millimetres: 6 bytes a point instead of a float
// triple's 12) and the pose it went in at. When the kept points would pass
// max_points, every other keyframe (not the first nor the newest) is dropped, halving the density
// over the run. With retire_after_revisits N, a keyframe that N newer ones have stood on (same
// place and heading within the keyframe thresholds) is retired: its points are freed at once, the
// entry removed once no rebuild is running.
//
// Rebuild: every keyframe, in time order, goes into a new tree at its pose on the newest
// trajectory (interpolated between the trajectory's poses around its time; a keyframe outside
// the trajectory, or in a gap wider than the poser's max_pose_gap_s, keeps its pose), and the
// new tree replaces the old when it is complete. Frames that are not keyframes are not in it:
// a rebuilt tree holds the keyframes, and the frames inserted after it replaced the old one.
//
// When: a trajectory that moves some keyframe's points by more than min_shift_m (a bound: the
// position change plus the chord the heading change sweeps at the keyframe's farthest point,
// within the range limit) asks for a rebuild; rebuilds start at least min_interval_s of data
// time apart. In the process a rebuild runs in slices of rebuild_budget_ms per tick, so the bus
// keeps being drained; offline (`omni octomap build`) it runs to the end at once, so the result
// does not depend on the machine's speed.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "omni/common/geometry.h"
#include "omni/octomap_builder/frame_poser.h"

namespace omni::octo {

struct ReposeOptions {
  bool enabled = false;
  std::string trajectory_channel;  // node: "" = TRAJECTORY_RBPF or TRAJECTORY_PG by pose_source
  double keyframe_distance_m = 0.1;
  double keyframe_angle_rad = 0.1;
  double keyframe_interval_s = 2.0;
  double point_spacing_m = 0;  // 0: the tree's resolution
  double min_shift_m = 0;      // 0: twice the tree's resolution
  double min_interval_s = 10.0;
  double rebuild_budget_ms = 20;  // node: time spent on a rebuild per tick
  // A keyframe is retired once this many newer keyframes have stood on it (within
  // keyframe_distance_m and keyframe_angle_rad, at the poses they are in the tree at): the newest
  // views of a place replace the older ones, so the store grows with the area covered, not with
  // the time spent there (a patrol, a robot standing). 0: never.
  int retire_after_revisits = 2;
  // Kept keyframe points (6 bytes each, 10 with colour: 180 MB at the default). Reaching it drops
  // every other keyframe (counted); when even that leaves no room for the new keyframe, re-posing
  // stops.
  int64_t max_points = 30000000;
};

// A kept point in the camera's optical frame, in whole millimetres (±32.767 m). Rounding moves a
// point by at most 0.87 mm, well below a depth camera's own noise (Kinect: a few millimetres at
// 1 m, about 4 cm at 5 m, Khoshelham and Elberink 2012) and the tree's centimetre cells.
struct KeptPoint {
  int16_t x_mm = 0, y_mm = 0, z_mm = 0;
};
constexpr double kKeptPointMaxM = 32.767;
constexpr double kKeptPointCutM = 32.0;  // rays cut at most this far: far points are kept

struct Keyframe {
  int64_t utime = 0;
  Pose2 pose;                     // the robot pose its points are in the tree at
  double radius_m = 0;            // farthest point from the robot's origin (xy), capped
  std::vector<KeptPoint> points;  // camera optical frame
  std::vector<uint32_t> colors;   // one per point (PackRgb or 0), or empty
  int revisits = 0;               // newer keyframes that stood on it
  bool retired = false;           // revisited often enough: no points, not rebuilt
  std::vector<Eigen::Vector3f> Points() const;  // the points in metres, for insertion
};

// `points` (camera frame, metres) in millimetres, with their `colors` (one per point) when given.
// A point farther than kKeptPointMaxM on some axis is moved along its ray to that bound when
// `ray_cut_m` (the tree's ray length limit) is in (0, kKeptPointCutM] — the ray it inserts is then
// the same — and dropped otherwise, as is a point that is not finite; returns how many were
// dropped.
int64_t KeepPoints(const std::vector<Eigen::Vector3f>& points, const std::vector<uint32_t>* colors,
                   double ray_cut_m, std::vector<KeptPoint>* out,
                   std::vector<uint32_t>* colors_out);

// One point per `leaf_m` cube at the centroid of the points in it, in order of first appearance;
// with `colors` (one per point) the cube keeps the first non-zero colour in it (`colors_out`).
void ThinPoints(const std::vector<Eigen::Vector3f>& points, const std::vector<uint32_t>* colors,
                double leaf_m, std::vector<Eigen::Vector3f>* points_out,
                std::vector<uint32_t>* colors_out);

// Farthest horizontal distance of `points_camera` from the robot's origin, in the base frame,
// capped at `max_range_m` from the camera when that is > 0 (a longer ray changes nothing beyond).
double KeyframeRadius(const std::vector<Eigen::Vector3f>& points_camera, const CameraMount& mount,
                      double max_range_m);

// How far any point within `radius_m` of the robot moves when the robot's pose changes from `a`
// to `b` (exact for the farthest point at the worst bearing): |t_b - t_a| + 2 sin(|dθ|/2) r.
double PoseShift(const Pose2& a, const Pose2& b, double radius_m);

// A trajectory's poses in strictly increasing time, and the pose at a time between two of them.
class TrajectoryLookup {
 public:
  TrajectoryLookup() = default;
  explicit TrajectoryLookup(std::vector<std::pair<int64_t, Pose2>> poses)
      : poses_(std::move(poses)) {}
  // Interpolated between the poses around `utime` when they are at most `max_gap_us` apart (a
  // pose at exactly `utime` is taken as is); false outside the trajectory or in a wider gap.
  bool At(int64_t utime, int64_t max_gap_us, Pose2* out) const;
  bool empty() const { return poses_.empty(); }
  size_t size() const { return poses_.size(); }

 private:
  std::vector<std::pair<int64_t, Pose2>> poses_;
};

}  // namespace omni::octo
