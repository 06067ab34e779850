// The octomap_builder node: bus I/O around OctomapPipeline. Subscribes to DEPTH and
// POSE_<source> (and the colour channel, RGB, with color.enabled; with repose.enabled the
// source's whole trajectory, TRAJECTORY_RBPF or TRAJECTORY_PG); publishes OCTOMAP and
// GRID_OCTO on their intervals; saves map.bt/.ot (and map_color.ot) at an interval and on exit;
// heartbeat with the frame counters.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/color_image_t.hpp"
#include "omni/common/scan_checks.h"
#include "omni/common/seq_gaps.h"
#include "omni/common/time.h"
#include "omni/depth_image_t.hpp"
#include "omni/octomap_builder/octomap_builder.h"
#include "omni/octomap_t.hpp"
#include "omni/trajectory_t.hpp"

namespace omni::octo {

// Decodes a depth message (RAW, ZLIB and DELTA_ZLIB; see DecodeDepthData).
Result<DepthImage> FromDepthMessage(const omni::depth_image_t& msg);
// Decodes a colour message (RGB8 and JPEG; see DecodeColorData); the size field must match.
Result<ColorImage> FromColorMessage(const omni::color_image_t& msg);
// The poses of a trajectory message (repose); an error when its frame is set and is not
// `map_frame`, or its arrays disagree with num_poses.
Result<std::vector<std::pair<int64_t, Pose2>>> FromTrajectoryMessage(const omni::trajectory_t& msg,
                                                                     const std::string& map_frame);
// An OCTOMAP message holding the tree in binary (.bt) or full (.ot) form.
omni::octomap_t ToOctomapMessage(const octomap::OcTree& tree, int64_t utime,
                                 const std::string& frame, const std::string& source, bool binary);
// The same for the ColorOcTree, always in the full form (.ot; OctoMap's binary form has no
// colour): tree_type "ColorOcTree", read back with ParseColorTree.
omni::octomap_t ToOctomapMessage(const octomap::ColorOcTree& tree, int64_t utime,
                                 const std::string& frame, const std::string& source);

class OctomapNode {
 public:
  // `bus` and `clock` must outlive the node.
  OctomapNode(bus::Bus* bus, const OctomapBuilderOptions& options, const Clock* clock);
  // The bus handlers and heartbeat counters refer to this object: it stays where it was made.
  OctomapNode(const OctomapNode&) = delete;
  OctomapNode& operator=(const OctomapNode&) = delete;

  // Inserts posed frames; publishes, saves and beats when their periods have passed since
  // the last time (`mono_us`: a monotonic time in microseconds).
  void Tick(int64_t mono_us);
  // The tree on octomap_channel and, with colour on, the ColorOcTree on color_octomap_channel;
  // true when every message went out.
  bool PublishOctomap();
  bool PublishGrid();
  // Writes out_dir/map.{bt,ot}, out_dir/grid.{pgm,yaml,png}, out_dir/view.png, with the colour
  // option out_dir/map_color.ot and out_dir/view_color.png, and with keep_cloud out_dir/map.pcd.
  Status SaveOutputs() const { return SaveOutputs(options_.out_dir); }
  // The same files in `dir` (a map save request while mapping).
  // `only_grid_failed`, if given, is set when the error is only that no grid could be made
  // (the tree and the other outputs were written).
  Status SaveOutputs(const std::string& dir, bool* only_grid_failed = nullptr) const;
  // The files SaveOutputs (and the process's map.pcd) write in their folder.
  static const std::vector<std::string>& OutputFiles() {
    static const std::vector<std::string> names = {"map.bt",       "map.ot",         "grid.pgm",
                                                   "grid.yaml",    "grid.png",       "view.png",
                                                   "map_color.ot", "view_color.png", "map.pcd"};
    return names;
  }

  static constexpr int64_t kInsertBudgetUs = 500000;  // insertions per tick (see the .cc)

  OctomapPipeline& pipeline() { return pipeline_; }
  int64_t depth_decode_errors() const { return depth_decode_errors_; }
  // Depth frames missing from the sequence numbers received (lost on the bus or by the driver).
  int64_t depth_frames_lost() const { return depth_seq_.lost(); }
  // The same depth frame (number and stamp) again: dropped.
  int64_t depth_frames_duplicate() const { return depth_frames_duplicate_; }
  // Times the pose source numbered its poses from the start again (a restarted SLAM process).
  int64_t pose_restarts() const { return pose_seq_.restarts(); }
  int64_t color_decode_errors() const { return color_decode_errors_; }
  int64_t trajectories_rejected() const { return trajectories_rejected_; }
  int64_t stamps_invalid() const { return stamps_invalid_; }
  bus::Heartbeat& heartbeat() { return heartbeat_; }

 private:
  bus::Bus* bus_;
  OctomapBuilderOptions options_;
  OctomapPipeline pipeline_;
  bus::Heartbeat heartbeat_;
  int64_t depth_decode_errors_ = 0;
  SeqGaps depth_seq_;  // the depth frames' numbers: lost frames, a restarted driver
  int64_t last_depth_utime_ = 0, depth_frames_duplicate_ = 0;
  // The poses' numbers: a restarted SLAM process. Poses come in order on one host, so a number
  // more than 20 back is a restart (a process that crashed within its first 100 poses, 10 s, was
  // taken for late messages with the default window).
  SeqGaps pose_seq_{20};
  int64_t color_decode_errors_ = 0;
  int64_t trajectories_rejected_ = 0;
  int64_t grid_errors_ = 0;  // grids that could not be made for GRID_OCTO
  int64_t last_save_us_ = -1, last_octomap_us_ = -1, last_grid_us_ = -1;
  int64_t save_errors_ = 0;  // periodic saves that failed
  // Messages stamped at or before the epoch or beyond 2^61 us (corrupt): dropped, since the
  // poser's time arithmetic would overflow on them.
  int64_t stamps_invalid_ = 0;
  bool StampPlausible(int64_t utime) {
    if (utime > 0 && StampInRange(utime)) return true;
    ++stamps_invalid_;
    return false;
  }
  int64_t saved_frames_ = 0, published_octomap_frames_ = 0, published_grid_frames_ = 0;
};

}  // namespace omni::octo
