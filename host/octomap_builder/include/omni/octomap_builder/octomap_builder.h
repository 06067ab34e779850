// The octomap_builder library (no LCM): options, and the builder that turns posed depth frames
// into an OctoMap with the parallel key-set insertion.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include <octomap/OcTree.h>
#include <Eigen/Geometry>

#include "omni/common/config.h"
#include "omni/common/result.h"
#include "omni/octomap_builder/depth_points.h"
#include "omni/octomap_builder/frame_poser.h"
#include "omni/octomap_builder/key_set_inserter.h"
#include "omni/octomap_builder/map_output.h"

namespace omni::octo {

struct OctomapBuilderOptions {
  // Bus (used by the node only).
  std::string pose_source = "rbpf";  // rbpf | pg: subscribes to POSE_RBPF or POSE_PG
  std::string pose_channel;          // "" = derived from pose_source
  std::string depth_channel = "DEPTH";
  std::string octomap_channel = "OCTOMAP";
  std::string grid_channel = "GRID_OCTO";
  std::string map_frame = "map";

  // Tree.
  double resolution_m = 0.05;
  double max_range_m = 5.0;  // rays are cut here (free only beyond); < 0: unlimited
  double prob_hit = 0.7;
  double prob_miss = 0.4;
  double clamping_min = 0.1192;
  double clamping_max = 0.971;

  // Depth to points (eq. 6-8) and filtering before ray casting.
  DepthToPointsOptions depth;
  double voxel_filter_m = 0;  // centroid voxel filter; 0: off
  bool discretize = false;    // one ray per tree voxel (octomap's discretize)
  int subvoxel = 2;           // > 1: one ray per (resolution / subvoxel) cell, to its centroid
  int threads = 2;

  CameraMount mount;
  FramePoserOptions poser;
  GridProjectionOptions grid;

  // Outputs (node).
  std::string out_dir = "out/octomap";
  double save_interval_s = 30;
  double octomap_interval_s = 5;
  bool octomap_binary = true;
  double grid_interval_s = 2;
  bool keep_cloud = false;  // aggregate the inserted points for PCD output
  double cloud_voxel_m = 0.02;
  double heartbeat_period_s = 1;

  // Reads every key (unknown keys, bad values: an error naming them).
  static Result<OctomapBuilderOptions> Load(ConfigReader& reader);
  static Result<OctomapBuilderOptions> LoadFile(const std::string& path);
  std::string PoseChannel() const;
};

struct FrameStats {
  size_t points = 0;  // valid pixels turned into points
  size_t rays = 0;    // after filtering/discretizing
  InsertStats insert;
};

class OctomapBuilder {
 public:
  explicit OctomapBuilder(const OctomapBuilderOptions& options);

  // Eq. (6)-(8), filters, transform by `camera_in_map` (optical frame in the map frame), and
  // insertion with the camera's position as the ray origin.
  Result<FrameStats> InsertDepth(const DepthImage& image, const Eigen::Isometry3d& camera_in_map);
  // Points already in the optical frame.
  FrameStats InsertPoints(const std::vector<Eigen::Vector3f>& points_camera,
                          const Eigen::Isometry3d& camera_in_map);

  const octomap::OcTree& tree() const { return *tree_; }
  octomap::OcTree& mutable_tree() { return *tree_; }
  // Aggregate cloud (voxel centroids at cloud_voxel_m), empty unless keep_cloud.
  std::vector<Eigen::Vector3f> AggregateCloud() const;
  int64_t frames_inserted() const { return frames_inserted_; }
  const OctomapBuilderOptions& options() const { return options_; }

 private:
  OctomapBuilderOptions options_;
  std::unique_ptr<octomap::OcTree> tree_;
  ParallelKeySetInserter inserter_;
  struct CloudCell {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    int n = 0;
  };
  std::unordered_map<uint64_t, CloudCell> cloud_;
  int64_t frames_inserted_ = 0;
};

// The process logic without the bus: depth frames and 2D poses in, posed frames inserted.
// The node feeds it from LCM subscriptions, `omni-octomap build` from a log file.
class OctomapPipeline {
 public:
  explicit OctomapPipeline(const OctomapBuilderOptions& options);

  void AddPose(int64_t utime, const Pose2& robot_in_map);
  void AddDepth(DepthImage image);
  // Poses and inserts what can be posed by `now_utime` (the newest data time seen when
  // replaying). Returns the number of frames inserted.
  int Process(int64_t now_utime);
  // Newest time of any pose or frame given so far (the default `now`).
  int64_t newest_utime() const { return newest_utime_; }

  struct Counters {
    int64_t frames_inserted = 0;
    int64_t frames_invalid = 0;  // posed but rejected by DepthToPoints (bad intrinsics, size)
    int64_t points_inserted = 0;
    int64_t last_frame_us = 0;  // time the last insertion took (monotonic clock)
  };
  const Counters& counters() const { return counters_; }
  const FramePoserCounters& poser_counters() const { return poser_.counters(); }
  OctomapBuilder& builder() { return builder_; }
  const OctomapBuilder& builder() const { return builder_; }
  int64_t newest_inserted_utime() const { return newest_inserted_utime_; }
  const std::string& last_error() const { return last_error_; }

 private:
  OctomapBuilder builder_;
  FramePoser<DepthImage> poser_;
  Counters counters_;
  int64_t newest_utime_ = 0;
  int64_t newest_inserted_utime_ = 0;
  std::string last_error_;
};

}  // namespace omni::octo
