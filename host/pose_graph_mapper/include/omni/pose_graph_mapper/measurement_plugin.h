// Measurement plugins (OmniMapper's "measurement plugins"): sources of relative-pose factors
// between two keyframes, as opposed to the continuous sources of continuous_source.h, which
// link every pair of consecutive poses. A plugin sees the keyframes so far (time order, the last
// one just added), and returns factors between keyframe timestamps; the mapper core turns each
// timestamp into a pose with Trajectory::PoseAt and adds the factor to the graph.
//
// Factor convention (as LinkFactor / RelativeMotion): `delta` is the pose of keyframe `to` in
// the frame of keyframe `from`; `covariance` is over (x_m, y_m, theta_rad) in that frame and the
// information is its inverse.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omni/common/geometry.h"
#include "omni/io/g2o.h"

namespace omni::pgm {

// A laser scan as received (one range per beam, counter-clockwise from angle_min).
struct LaserScan2 {
  int64_t utime = 0;
  float angle_min_rad = 0;
  float angle_increment_rad = 0;
  float min_range_m = 0.05f;
  float max_range_m = 0;  // readings >= max_range are "no return" and skipped
  std::vector<float> ranges_m;
  Pose2 laser_in_base;  // mounting pose of the laser on the robot base
  // First to last beam (a spinning lidar's sweep); > 0: the mapper corrects each end point for
  // the base's motion during the sweep when odometry covers it. 0: every beam at `utime`.
  float scan_time_s = 0;
};

// Why beams were dropped when converting a scan to points.
struct ScanConversionStats {
  int64_t used = 0;
  int64_t not_finite = 0;    // NaN or infinite range
  int64_t out_of_range = 0;  // below min_range or at/after max_range
};

// Beam end points in the robot-base frame at the first beam's time. Non-finite and
// out-of-range beams are skipped and counted in `stats` (accumulated, may be null). `sweep`: the
// base's motion from the first beam to the last (beam i measured at fraction i / (n - 1) of it),
// undone point by point; null: every beam at one instant.
std::vector<Eigen::Vector2d> ScanToPoints(const LaserScan2& scan, ScanConversionStats* stats,
                                          const Pose2* sweep = nullptr);

struct Keyframe {
  int64_t utime = 0;
  Pose2 estimate;                       // current estimate in the map frame
  std::vector<Eigen::Vector2d> points;  // scan end points in the robot-base frame
  // Retired (PoseGraphSlam, `slam.retire`): a revisit of ground older keyframes already map.
  // Its pose stays in the graph; its points are released and it is no loop candidate.
  bool retired = false;
};

struct RelativePoseFactor {
  int64_t from_utime = 0, to_utime = 0;
  Pose2 delta;  // pose of `to` in the frame of `from`
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  std::string plugin;  // name of the plugin that produced it
  double score = 0;    // matcher score in [0, 1] (mean likelihood of the matched points)

  Eigen::Matrix3d Information() const;
  // As a g2o edge between the poses the mapper created for the two timestamps.
  io::Edge2 ToEdge(int from_id, int to_id) const;
};

class MeasurementPlugin {
 public:
  virtual ~MeasurementPlugin() = default;
  virtual std::string name() const = 0;
  // Called after `keyframes.back()` was added. Returns the factors it produced (possibly none);
  // every attempt that produced no factor is counted by reason in counters().
  virtual std::vector<RelativePoseFactor> OnKeyframe(const std::vector<Keyframe>& keyframes) = 0;
  // Counters for the heartbeat: attempts, accepted factors, rejections by reason.
  const std::map<std::string, int64_t>& counters() const { return counters_; }

 protected:
  void Count(const std::string& key, int64_t n = 1) { counters_[key] += n; }

 private:
  std::map<std::string, int64_t> counters_;
};

}  // namespace omni::pgm
