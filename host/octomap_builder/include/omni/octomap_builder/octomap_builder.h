// The octomap_builder library (no LCM): options, and the builder that turns posed depth frames
// into an OctoMap with the parallel key-set insertion.
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include <octomap/ColorOcTree.h>
#include <octomap/OcTree.h>
#include <Eigen/Geometry>

#include "omni/common/config.h"
#include "omni/common/result.h"
#include "omni/octomap_builder/color_image.h"
#include "omni/octomap_builder/color_octree.h"
#include "omni/octomap_builder/depth_points.h"
#include "omni/octomap_builder/frame_poser.h"
#include "omni/octomap_builder/key_set_inserter.h"
#include "omni/octomap_builder/map_output.h"
#include "omni/octomap_builder/repose.h"

namespace omni::octo {

struct OctomapBuilderOptions {
  // Bus (used by the node only).
  std::string pose_source = "rbpf";  // rbpf | pg: subscribes to POSE_RBPF or POSE_PG
  std::string pose_channel;          // "" = derived from pose_source
  std::string depth_channel = "DEPTH";
  std::string octomap_channel = "OCTOMAP";
  std::string grid_channel = "GRID_OCTO";
  std::string color_channel = "RGB";                    // color_image_t, read when `color` is on
  std::string color_octomap_channel = "OCTOMAP_COLOR";  // the ColorOcTree, when `color` is on
  std::string map_frame = "map";

  // Colour (ColorOcTree beside the OcTree).
  bool color = false;               // also build a ColorOcTree from the colour frames
  int64_t color_max_dt_us = 20000;  // a depth frame pairs with the colour frame nearest in time
                                    // within this; without one it is inserted uncoloured
  size_t color_queue = 30;          // colour frames kept for pairing

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
  ReposeOptions repose;

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
  // repose.trajectory_channel, or TRAJECTORY_RBPF / TRAJECTORY_PG by pose_source.
  std::string TrajectoryChannel() const;
};

struct FrameStats {
  size_t points = 0;  // valid pixels turned into points
  size_t rays = 0;    // after filtering/discretizing
  InsertStats insert;
  size_t colored_points = 0;  // points with a colour (colour insertion)
  size_t colored_keys = 0;    // occupied voxels of the scan that integrated a colour
  int64_t color_us = 0;       // colour part: scan colours + the ColorOcTree update (monotonic)
};

class OctomapBuilder {
 public:
  explicit OctomapBuilder(const OctomapBuilderOptions& options);

  // Eq. (6)-(8), filters, transform by `camera_in_map` (optical frame in the map frame), and
  // insertion with the camera's position as the ray origin. With `kept`, the frame's points
  // (camera frame, before any filter) are copied there.
  Result<FrameStats> InsertDepth(const DepthImage& image, const Eigen::Isometry3d& camera_in_map,
                                 ColoredPoints* kept = nullptr);
  // The same with each point's colour from `color` (registration: color_image.h). Needs the
  // colour option; the OcTree gets exactly what InsertDepth gives it. Fails as InsertDepth, or
  // when the colour image cannot be registered (nothing is inserted then). With `kept`, the
  // points and their colours are copied there.
  Result<FrameStats> InsertDepthColor(const DepthImage& image, const ColorImage& color,
                                      const Eigen::Isometry3d& camera_in_map,
                                      ColoredPoints* kept = nullptr);
  // Points already in the optical frame; `colors` (PackRgb or 0 per point) or null. With the
  // colour option the ColorOcTree gets the same occupancy update (and no colour when null).
  FrameStats InsertPoints(const std::vector<Eigen::Vector3f>& points_camera,
                          const Eigen::Isometry3d& camera_in_map,
                          const std::vector<uint32_t>* colors = nullptr);

  const octomap::OcTree& tree() const { return *tree_; }
  octomap::OcTree& mutable_tree() { return *tree_; }
  // Null unless the colour option is on.
  const octomap::ColorOcTree* color_tree() const { return color_tree_.get(); }
  // Aggregate cloud (voxel centroids at cloud_voxel_m), empty unless keep_cloud.
  std::vector<Eigen::Vector3f> AggregateCloud() const;
  int64_t frames_inserted() const { return frames_inserted_; }
  const OctomapBuilderOptions& options() const { return options_; }

 private:
  OctomapBuilderOptions options_;
  std::unique_ptr<octomap::OcTree> tree_;
  std::unique_ptr<octomap::ColorOcTree> color_tree_;
  ParallelKeySetInserter inserter_;
  struct CloudCell {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    int n = 0;
  };
  std::unordered_map<uint64_t, CloudCell> cloud_;
  int64_t frames_inserted_ = 0;
  // Per-frame working memory kept between frames (a depth frame's clouds and key sets are
  // about 3 MB; allocated anew they would be mapped blocks, page-faulted in every frame).
  std::vector<Eigen::Vector3f> camera_points_, world_;
  KeySets sets_;
};

// The process logic without the bus: depth frames and 2D poses in, posed frames inserted.
// The node feeds it from LCM subscriptions, `omni-octomap build` from a log file.
//
// With the colour option, colour frames come in too (AddColor, in time order) and each posed
// depth frame pairs with the colour frame nearest to it in time within color_max_dt_us. A
// posed frame waits for its partner until a colour frame later than its time + color_max_dt_us
// has arrived (no nearer one can come) or the data time has passed its time + the pose
// latency (poses.max_latency_s); then it is inserted with the best partner found, or
// uncoloured (counted) without one.
//
// With the repose option, whole trajectories of the 2D SLAM come in too (AddTrajectory) and the
// tree is rebuilt from keyframes at their corrected poses (repose.h).
class OctomapPipeline {
 public:
  explicit OctomapPipeline(const OctomapBuilderOptions& options);

  void AddPose(int64_t utime, const Pose2& robot_in_map);
  void AddDepth(DepthImage image);
  // Ignored (not counted as input) unless the colour option is on.
  void AddColor(ColorImage image);
  // The 2D SLAM's whole trajectory as it stands (repose option; ignored without it). Rejected,
  // counted and false when empty, not finite or stamped <= 0; after a step back in time only the
  // poses after it are taken (counted).
  bool AddTrajectory(std::vector<std::pair<int64_t, Pose2>> poses);
  // Time a rebuild may take per Process call (monotonic µs); < 0 (the default): to its end at
  // once. The node sets repose.rebuild_budget_ms.
  void set_rebuild_budget_us(int64_t us) { rebuild_budget_us_ = us; }
  // Time the insertions may take per Process call (monotonic µs; at least one frame is tried);
  // the frames left wait for the next call, at most kMaxBacklog of them (older ones dropped,
  // counted; 3.3 s at 30 Hz, 60 MB of 640x480 frames). < 0 (the default): every posed frame at
  // once. The node sets it so that a burst of frames (poses that came late) cannot hold its
  // heartbeat for seconds.
  void set_insert_budget_us(int64_t us) { insert_budget_us_ = us; }
  static constexpr size_t kMaxBacklog = 100;
  // Runs a started rebuild to its end, then one more if the newest trajectory still moves a
  // keyframe by more than min_shift_m, whatever min_interval_s says (end of a log, exit).
  void FinishRepose();
  // Poses and inserts what can be posed by `now_utime` (the newest data time seen when
  // replaying). Returns the number of frames inserted.
  int Process(int64_t now_utime);
  // Inserts the posed frames still waiting for a colour partner with the best one buffered (or
  // uncoloured), e.g. on exit. Returns the number inserted.
  int FlushAwaitingColor();
  // The end of the input (a log's end, the process's exit): no pose or colour frame will come.
  // Poses what the poses taken can pose, counts the frames still waiting for a newer pose as
  // dropped without pose, and inserts those waiting for a colour partner. Returns the number
  // inserted.
  int FinishInput();
  // Newest time of any pose or depth frame taken so far (the default `now`; not the colour
  // frames', which may run on another clock); it moves back when a
  // stream's future-stamped message is dropped (stamp_order.h), so one such message cannot
  // expire every frame's latency.
  int64_t newest_utime() const;

  struct Counters {
    int64_t frames_inserted = 0;
    int64_t frames_invalid = 0;  // posed but rejected by DepthToPoints (bad intrinsics, size)
    // Points, but not one of them (nor its ray) inside the octree's key range (a pose
    // thousands of km out): nothing was mapped.
    int64_t frames_out_of_range = 0;
    int64_t points_inserted = 0;
    int64_t last_frame_us = 0;           // time the last insertion took (monotonic clock)
    int64_t frames_dropped_backlog = 0;  // posed, but more than kMaxBacklog waited for the budget
    // Colour option only:
    int64_t color_frames_in = 0;
    int64_t color_out_of_order = 0;  // older than the previous colour frame: rejected
    int64_t color_time_rebases = 0;  // a future-stamped colour frame dropped (stamp_order.h)
    int64_t color_dropped = 0;       // discarded without pairing with any depth frame
    int64_t frames_colored = 0;      // inserted with a colour partner
    int64_t frames_uncolored = 0;    // inserted without one (none within color_max_dt_us)
    int64_t color_invalid = 0;       // partner could not be registered (size, bytes): inserted
                                     // uncoloured, message in last_error()
    // Repose option only:
    int64_t trajectories_in = 0;
    int64_t trajectories_invalid = 0;     // empty, not finite, absurd or a stamp <= 0: ignored
    int64_t trajectories_truncated = 0;   // a step back in time: only the poses after it taken
    int64_t keyframes = 0;                // kept now (not retired)
    int64_t keyframe_points = 0;          // their points, after thinning
    int64_t keyframe_points_dropped = 0;  // not finite, or beyond ±32.767 m (KeepPoints)
    int64_t rebuilds_started = 0;
    int64_t rebuilds_done = 0;          // complete rebuilds that replaced the tree
    int64_t last_rebuild_us = 0;        // monotonic time the last complete one took
    int64_t last_rebuild_shift_mm = 0;  // the largest keyframe shift that asked for it
    int64_t keyframe_thinnings = 0;     // max_points reached: every other keyframe dropped
    int64_t keyframes_retired = 0;      // revisited retire_after_revisits times
    int64_t repose_stopped = 0;  // 1 once a keyframe did not fit even after halving: no rebuilds
  };
  const Counters& counters() const { return counters_; }
  const FramePoserCounters& poser_counters() const { return poser_.counters(); }
  OctomapBuilder& builder() { return *builder_; }
  const OctomapBuilder& builder() const { return *builder_; }
  // Changes whenever the tree does: a frame inserted or a rebuild completed.
  int64_t tree_version() const { return counters_.frames_inserted + counters_.rebuilds_done; }
  const std::deque<Keyframe>& keyframes() const { return keyframes_; }
  bool rebuilding() const { return shadow_ != nullptr; }
  int64_t newest_inserted_utime() const { return newest_inserted_utime_; }
  const std::string& last_error() const { return last_error_; }

 private:
  using Posed = FramePoser<DepthImage>::Posed;
  // Inserts one posed frame (with `color` or without) and counts.
  void Insert(const Posed& posed, const ColorImage* color);
  // Pairs and inserts the frames waiting for colour whose partner is decided (all with force).
  int PairAndInsert(int64_t now_utime, bool force, int64_t deadline_us);
  // Index of the colour frame nearest to `utime` within color_max_dt_us, or -1.
  int NearestColor(int64_t utime) const;

  // Re-posing (repose.h).
  bool IsKeyframe(const Posed& posed) const;
  void KeepKeyframe(const Posed& posed, const ColoredPoints& points);
  Pose2 TargetPose(const Keyframe& kf) const;  // on the newest trajectory, else its own pose
  // retire_after_revisits: a new keyframe of `points` points at `pose` revisits older ones.
  void RetireCoveredBy(const Pose2& pose, int64_t points);
  void RemoveRetired();     // their entries (never while a rebuild runs)
  double MaxShift() const;  // over all keyframes, 0 when none passes min_shift_m
  void StepRepose();
  void RunRebuild(int64_t budget_us);

  std::unique_ptr<OctomapBuilder> builder_;
  FramePoser<DepthImage> poser_;
  std::deque<Posed> awaiting_color_;  // posed, waiting for their colour partner
  std::deque<Posed> ready_;           // posed, left for the next Process by the insert budget
  struct BufferedColor {
    ColorImage image;
    bool used = false;  // paired with a depth frame
  };
  std::deque<BufferedColor> colors_;  // recent colour frames, in time order
  Counters counters_;
  StampOrder color_order_;
  int64_t newest_inserted_utime_ = 0;
  std::string last_error_;
  // Re-posing.
  std::deque<Keyframe> keyframes_;
  TrajectoryLookup trajectory_;
  std::unique_ptr<OctomapBuilder> shadow_;  // the tree being rebuilt
  std::vector<Pose2> rebuilt_poses_;        // keyframes_[i]'s pose in shadow_, i < size()
  int64_t rebuild_us_ = 0;                  // time spent on the running rebuild
  double wanted_shift_m_ = 0;               // > 0: a rebuild is asked for
  double running_shift_m_ = 0;              // the shift that started the running rebuild
  int64_t last_rebuild_start_utime_ = INT64_MIN;
  int64_t rebuild_budget_us_ = -1;
  int64_t insert_budget_us_ = -1;
};

}  // namespace omni::octo
