#include "omni/octomap_builder/octomap_node.h"

#include <cmath>
#include <filesystem>

#include "omni/bus/convert.h"
#include "omni/common/log.h"
#include "omni/common/scan_checks.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/grid.h"
#include "omni/octomap_builder/depth_io.h"
#include "omni/pose2d_t.hpp"

namespace omni::octo {

Result<DepthImage> FromDepthMessage(const omni::depth_image_t& m) {
  DepthImage im;
  im.utime = m.utime;
  im.width = m.width;
  im.height = m.height;
  im.intrinsics = {m.fx, m.fy, m.cx, m.cy, m.depth_scale};
  if (m.size != static_cast<int32_t>(m.data.size()))
    return MakeError(ErrorCode::kParse, "depth message: size field disagrees with data");
  Status s = DecodeDepthData(m.encoding, m.data.data(), m.data.size(), m.width, m.height, &im.data);
  if (!s.ok()) return s.error();
  const std::string bad = im.intrinsics.Validate();
  if (!bad.empty()) return MakeError(ErrorCode::kInvalidArgument, "depth message: " + bad);
  return im;
}

Result<ColorImage> FromColorMessage(const omni::color_image_t& m) {
  ColorImage im;
  im.utime = m.utime;
  im.width = m.width;
  im.height = m.height;
  im.intrinsics = {m.fx, m.fy, m.cx, m.cy};
  if (m.size != static_cast<int32_t>(m.data.size()))
    return MakeError(ErrorCode::kParse, "colour message: size field disagrees with data");
  Status s = DecodeColorData(m.encoding, m.data.data(), m.data.size(), m.width, m.height, &im.rgb);
  if (!s.ok()) return s.error();
  if (!im.intrinsics.Unset()) {
    if (const std::string bad = im.intrinsics.Validate(); !bad.empty())
      return MakeError(ErrorCode::kInvalidArgument, "colour message: " + bad);
  }
  return im;
}

Result<std::vector<std::pair<int64_t, Pose2>>> FromTrajectoryMessage(const omni::trajectory_t& m,
                                                                     const std::string& map_frame) {
  const auto n = static_cast<size_t>(std::max(m.num_poses, 0));
  if (m.pose_utime.size() != n || m.x_m.size() != n || m.y_m.size() != n || m.yaw_rad.size() != n)
    return MakeError(ErrorCode::kParse, "trajectory message: arrays disagree with num_poses");
  if (!m.frame.empty() && m.frame != map_frame)
    return MakeError(ErrorCode::kInvalidArgument, "trajectory in frame '" + m.frame +
                                                      "', not the map frame '" + map_frame + "'");
  std::vector<std::pair<int64_t, Pose2>> poses;
  poses.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    // A NaN pose would re-pose keyframes into NaN points: the whole message is refused (and
    // counted as a rejected trajectory), the next one replaces it.
    const Pose2 p(m.x_m[i], m.y_m[i], m.yaw_rad[i]);
    if (!PlausibleOdometryPose(p))
      return MakeError(ErrorCode::kInvalidArgument,
                       "trajectory message: pose " + std::to_string(i) +
                           " is not finite or beyond 1000 km / 1e6 rad");
    poses.emplace_back(m.pose_utime[i], p);
  }
  return poses;
}

namespace {
omni::octomap_t TreeMessage(const octomap::AbstractOcTree& tree, const std::string& bytes,
                            bool binary, int64_t utime, const std::string& frame,
                            const std::string& source) {
  omni::octomap_t msg;
  msg.utime = utime;
  msg.frame = frame;
  msg.source = source;
  msg.tree_type = tree.getTreeType();
  msg.resolution_m = tree.getResolution();
  msg.binary = binary;
  msg.data.assign(bytes.begin(), bytes.end());
  msg.size = static_cast<int32_t>(msg.data.size());
  return msg;
}
}  // namespace

omni::octomap_t ToOctomapMessage(const octomap::OcTree& tree, int64_t utime,
                                 const std::string& frame, const std::string& source, bool binary) {
  return TreeMessage(tree, SerializeTree(tree, binary), binary, utime, frame, source);
}

omni::octomap_t ToOctomapMessage(const octomap::ColorOcTree& tree, int64_t utime,
                                 const std::string& frame, const std::string& source) {
  return TreeMessage(tree, SerializeColorTree(tree), false, utime, frame, source);
}

OctomapNode::OctomapNode(bus::Bus* bus, const OctomapBuilderOptions& options, const Clock* clock)
    : bus_(bus),
      options_(options),
      pipeline_(options),
      heartbeat_(bus, "octomap_builder", clock,
                 static_cast<int64_t>(options.heartbeat_period_s * 1e6)) {
  // A burst of frames (poses that came late) goes in over several ticks, the heartbeat beating
  // between them: at 50-80 ms a 640x480 frame, 60 queued frames held it 3-5 s, about a
  // supervisor's heartbeat timeout.
  pipeline_.set_insert_budget_us(kInsertBudgetUs);
  // A NaN or absurd pose is refused and counted by the poser (poses_invalid).
  bus_->Subscribe<omni::pose2d_t>(options_.PoseChannel(), [this](const omni::pose2d_t& m, int64_t) {
    if (!StampPlausible(m.utime)) return;
    // A SLAM process restarted (by the supervisor after a crash) numbers its poses from 0 again
    // in a new map frame, its origin where the robot stood then: said loudly, since the tree
    // keeps the old frame's frames beside the new ones.
    const int64_t restarts = pose_seq_.restarts();
    pose_seq_.Add(m.seq);
    if (pose_seq_.restarts() > restarts) {
      LOG_WARN << "the pose source on " << options_.PoseChannel()
               << " restarted (its poses numbered again from " << m.seq
               << "): its new map frame is not the tree's; restart octomap_builder for a new map";
    }
    pipeline_.AddPose(m.utime, Pose2(m.x_m, m.y_m, m.yaw_rad));
  });
  bus_->Subscribe<omni::depth_image_t>(
      options_.depth_channel, [this](const omni::depth_image_t& m, int64_t) {
        if (!StampPlausible(m.utime)) return;
        // Gaps in the driver's sequence numbers: frames lost before they reached us (a smaller
        // number is a restarted driver, not a loss; nor is a jump of more than a day of frames
        // at 30 Hz, a corrupt number, which would add ~9e18 to the count).
        // The same frame again (a repeating bridge or driver) would be inserted twice: one
        // sighting read as two.
        if (m.seq >= 0 && m.seq == depth_seq_.newest() && m.utime == last_depth_utime_) {
          ++depth_frames_duplicate_;
          return;
        }
        depth_seq_.Add(m.seq);
        last_depth_utime_ = m.utime;
        auto im = FromDepthMessage(m);
        if (!im.ok()) {
          ++depth_decode_errors_;
          LOG_DEBUG << "depth frame " << m.seq << ": " << im.error().message;
          return;
        }
        pipeline_.AddDepth(std::move(*im));
      });
  if (options_.color) {
    bus_->Subscribe<omni::color_image_t>(
        options_.color_channel, [this](const omni::color_image_t& m, int64_t) {
          if (!StampPlausible(m.utime)) return;
          auto im = FromColorMessage(m);
          if (!im.ok()) {
            ++color_decode_errors_;
            LOG_DEBUG << "colour frame " << m.seq << ": " << im.error().message;
            return;
          }
          pipeline_.AddColor(std::move(*im));
        });
  }
  if (options_.repose.enabled) {
    pipeline_.set_rebuild_budget_us(
        static_cast<int64_t>(std::llround(options_.repose.rebuild_budget_ms * 1000)));
    bus_->Subscribe<omni::trajectory_t>(options_.TrajectoryChannel(),
                                        [this](const omni::trajectory_t& m, int64_t) {
                                          auto poses = FromTrajectoryMessage(m, options_.map_frame);
                                          if (!poses.ok()) {
                                            ++trajectories_rejected_;
                                            LOG_DEBUG << poses.error().message << "; ignored";
                                            return;
                                          }
                                          pipeline_.AddTrajectory(std::move(*poses));
                                        });
  }
  const auto& pc = pipeline_.poser_counters();
  const auto& c = pipeline_.counters();
  heartbeat_.AddCounter("frames_in", [&pc] { return pc.frames_in; });
  heartbeat_.AddCounter("grid_errors", [this] { return grid_errors_; });
  heartbeat_.AddCounter("save_errors", [this] { return save_errors_; });
  heartbeat_.AddCounter("stamps_invalid", [this] { return stamps_invalid_; });
  heartbeat_.AddCounter("frames_lost", [this] { return depth_seq_.lost(); });
  heartbeat_.AddCounter("frames_dropped_backlog", [&c] { return c.frames_dropped_backlog; });
  heartbeat_.AddCounter("frames_duplicate", [this] { return depth_frames_duplicate_; });
  heartbeat_.AddCounter("pose_restarts", [this] { return pose_seq_.restarts(); });
  heartbeat_.AddCounter("frames_posed", [&pc] { return pc.frames_posed; });
  heartbeat_.AddCounter("frames_dropped_no_pose", [&pc] { return pc.frames_dropped_no_pose; });
  heartbeat_.AddCounter("frames_dropped_queue", [&pc] { return pc.frames_dropped_queue; });
  heartbeat_.AddCounter("out_of_order",
                        [&pc] { return pc.frames_out_of_order + pc.poses_out_of_order; });
  heartbeat_.AddCounter("poses_invalid", [&pc] { return pc.poses_invalid; });
  heartbeat_.AddCounter("time_rebases",
                        [&pc, &c] { return pc.time_rebases + c.color_time_rebases; });
  heartbeat_.AddCounter("frames_dropped_future", [&pc] { return pc.frames_dropped_future; });
  heartbeat_.AddCounter("decode_errors", [this] {
    return depth_decode_errors_ + bus_->counters().decode_errors.load();
  });
  heartbeat_.AddCounter("frames_inserted", [&c] { return c.frames_inserted; });
  heartbeat_.AddCounter("frames_invalid", [&c] { return c.frames_invalid; });
  heartbeat_.AddCounter("frames_out_of_range", [&c] { return c.frames_out_of_range; });
  heartbeat_.AddCounter("last_frame_us", [&c] { return c.last_frame_us; });
  if (options_.color) {
    heartbeat_.AddCounter("color_frames_in", [&c] { return c.color_frames_in; });
    heartbeat_.AddCounter("frames_colored", [&c] { return c.frames_colored; });
    heartbeat_.AddCounter("frames_uncolored", [&c] { return c.frames_uncolored; });
    // Colour input that could not be used: undecodable messages (bad byte count, corrupt
    // JPEG, unknown encoding) and partners that could not be registered (size mismatch).
    heartbeat_.AddCounter("color_errors",
                          [this, &c] { return color_decode_errors_ + c.color_invalid; });
    heartbeat_.AddCounter("color_dropped", [&c] { return c.color_dropped + c.color_out_of_order; });
  }
  if (options_.repose.enabled) {
    heartbeat_.AddCounter("trajectories_in",
                          [this, &c] { return c.trajectories_in + trajectories_rejected_; });
    // Another frame, inconsistent sizes, or not finite / not in time order.
    heartbeat_.AddCounter("trajectories_rejected",
                          [this, &c] { return trajectories_rejected_ + c.trajectories_invalid; });
    heartbeat_.AddCounter("keyframes", [&c] { return c.keyframes; });
    heartbeat_.AddCounter("keyframe_points", [&c] { return c.keyframe_points; });
    heartbeat_.AddCounter("keyframe_points_dropped", [&c] { return c.keyframe_points_dropped; });
    heartbeat_.AddCounter("rebuilds_started", [&c] { return c.rebuilds_started; });
    heartbeat_.AddCounter("rebuilds_done", [&c] { return c.rebuilds_done; });
    heartbeat_.AddCounter("last_rebuild_ms", [&c] { return c.last_rebuild_us / 1000; });
    heartbeat_.AddCounter("last_rebuild_shift_mm", [&c] { return c.last_rebuild_shift_mm; });
    heartbeat_.AddCounter("keyframe_thinnings", [&c] { return c.keyframe_thinnings; });
    heartbeat_.AddCounter("keyframes_retired", [&c] { return c.keyframes_retired; });
    heartbeat_.AddCounter("trajectories_truncated", [&c] { return c.trajectories_truncated; });
    heartbeat_.AddCounter("repose_stopped", [&c] { return c.repose_stopped; });
  }
  heartbeat_.SetState(omni::heartbeat_t::STATE_STARTING, "waiting for depth and poses");
}

void OctomapNode::Tick(int64_t mono_us) {
  pipeline_.Process(pipeline_.newest_utime());
  // Changes with every insertion and with a completed rebuild (repose).
  const int64_t inserted = pipeline_.tree_version();
  auto due = [mono_us](int64_t* last, double period_s) {
    if (*last < 0) *last = mono_us;  // periods count from the first tick
    if (mono_us - *last < static_cast<int64_t>(period_s * 1e6)) return false;
    *last = mono_us;
    return true;
  };
  if (due(&last_octomap_us_, options_.octomap_interval_s) && inserted > published_octomap_frames_) {
    PublishOctomap();
    published_octomap_frames_ = inserted;
  }
  if (due(&last_grid_us_, options_.grid_interval_s) && inserted > published_grid_frames_) {
    PublishGrid();
    published_grid_frames_ = inserted;
  }
  if (due(&last_save_us_, options_.save_interval_s) && inserted > saved_frames_) {
    bool only_grid_failed = false;
    Status s = SaveOutputs(options_.out_dir, &only_grid_failed);
    if (s.ok() || only_grid_failed) {  // (a grid that cannot be made is counted in grid_errors)
      saved_frames_ = inserted;
    } else {  // tried again at the next interval
      ++save_errors_;
      LOG_WARN << s.message();
    }
  }
  if (pose_seq_.restarts() > 0) {
    heartbeat_.SetState(omni::heartbeat_t::STATE_DEGRADED,
                        "the pose source restarted: the map holds two frames");
  } else if (inserted > 0) {
    const auto& pc = pipeline_.poser_counters();
    if (pc.frames_dropped_no_pose > pc.frames_posed)
      heartbeat_.SetState(omni::heartbeat_t::STATE_DEGRADED, "most frames have no pose");
    else
      heartbeat_.SetState(
          omni::heartbeat_t::STATE_OK,
          pipeline_.rebuilding() ? "mapping; rebuilding at corrected poses" : "mapping");
  }
  heartbeat_.Tick();
}

bool OctomapNode::PublishOctomap() {
  bool sent = bus_->Publish(
      options_.octomap_channel,
      ToOctomapMessage(pipeline_.builder().tree(), pipeline_.newest_inserted_utime(),
                       options_.map_frame, options_.pose_source, options_.octomap_binary));
  if (const octomap::ColorOcTree* color = pipeline_.builder().color_tree())
    sent = bus_->Publish(options_.color_octomap_channel,
                         ToOctomapMessage(*color, pipeline_.newest_inserted_utime(),
                                          options_.map_frame, options_.pose_source)) &&
           sent;
  return sent;
}

bool OctomapNode::PublishGrid() {
  auto grid = ProjectToGrid(pipeline_.builder().tree(), options_.grid);
  if (!grid.ok()) {  // e.g. a map wider than a grid message carries: counted, and said once
    if (grid_errors_++ == 0) {
      LOG_WARN << "no GRID_OCTO: " << grid.error().message;
    }
    return false;
  }
  if (grid->width == 0) return false;
  return bus::PublishGrid(*bus_, options_.grid_channel, *grid, pipeline_.newest_inserted_utime(),
                          "octomap", options_.map_frame);
}

Status OctomapNode::SaveOutputs(const std::string& dir, bool* only_grid_failed) const {
  if (only_grid_failed != nullptr) *only_grid_failed = false;
  // An empty tree is no map: written, it would stand in for (and on a restart push aside) a
  // real one.
  if (pipeline_.counters().frames_inserted == 0)
    return MakeError(ErrorCode::kNotFound, "no frame was inserted: nothing to write to " + dir);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return MakeError(ErrorCode::kIo, "cannot create " + dir + ": " + ec.message());
  const octomap::OcTree& tree = pipeline_.builder().tree();
  if (Status s = SaveTree(tree, dir + "/map"); !s.ok()) return s;
  // A grid that cannot be made (a map wider than a grid carries) is reported at the end; the
  // other outputs are written all the same.
  auto grid = ProjectToGrid(tree, options_.grid);
  if (grid.ok() && grid->width > 0) {
    if (Status s = io::WriteMapServer(*grid, dir + "/grid"); !s.ok()) return s;
    if (Status s = io::WritePng(dir + "/grid.png", io::RenderGrid(*grid)); !s.ok()) return s;
  }
  if (Status s = io::WritePng(dir + "/view.png", RenderTopView(tree, options_.grid.up)); !s.ok())
    return s;
  if (const octomap::ColorOcTree* color = pipeline_.builder().color_tree()) {
    if (Status s = SaveColorTree(*color, dir + "/map_color.ot"); !s.ok()) return s;
    if (Status s =
            io::WritePng(dir + "/view_color.png", RenderTopViewColor(*color, options_.grid.up));
        !s.ok())
      return s;
  }
  if (options_.keep_cloud) {
    if (Status s = WritePcd(dir + "/map.pcd", pipeline_.builder().AggregateCloud(), true); !s.ok())
      return s;
  }
  if (!grid.ok() && only_grid_failed != nullptr) *only_grid_failed = true;
  if (!grid.ok())
    return MakeError(grid.error().code, "no grid written (" + grid.error().message +
                                            "); the tree and the other outputs are in " + dir);
  return Status::Ok();
}

}  // namespace omni::octo
