#include "omni/octomap_builder/octomap_builder.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "omni/common/log.h"

namespace omni::octo {
namespace {

KeySetOptions ToKeySetOptions(const OctomapBuilderOptions& o) {
  KeySetOptions k;
  k.num_threads = o.threads;
  k.max_range_m = o.max_range_m;
  k.discretize = o.discretize;
  k.subvoxel = o.subvoxel;
  return k;
}

template <typename T>
Rule<T> Probability() {
  return [](const T& v) -> std::string { return v > 0 && v < 1 ? "" : "must be in (0, 1)"; };
}

}  // namespace

Result<OctomapBuilderOptions> OctomapBuilderOptions::Load(ConfigReader& r) {
  OctomapBuilderOptions o;
  r.Get("pose_source", &o.pose_source, Required(), OneOf({"rbpf", "pg"}));
  r.Get("pose_channel", &o.pose_channel, Optional());
  r.Get("depth_channel", &o.depth_channel, Optional(), NonEmpty());
  r.Get("octomap_channel", &o.octomap_channel, Optional(), NonEmpty());
  r.Get("grid_channel", &o.grid_channel, Optional(), NonEmpty());
  r.Get("color_channel", &o.color_channel, Optional(), NonEmpty());
  r.Get("color_octomap_channel", &o.color_octomap_channel, Optional(), NonEmpty());
  r.Get("map_frame", &o.map_frame, Optional(), NonEmpty());

  auto color = r.Section("color");
  double pair_dt_s = 0.02;
  int color_queue = 30;
  color.Get("enabled", &o.color, Optional());
  color.Get("max_pair_dt_s", &pair_dt_s, Optional(), InRange(0.0, 1.0));
  color.Get("max_queued_frames", &color_queue, Optional(), InRange(1, 1000));
  o.color_max_dt_us = static_cast<int64_t>(std::llround(pair_dt_s * 1e6));
  o.color_queue = static_cast<size_t>(color_queue);

  auto tree = r.Section("tree");
  tree.Get("resolution_m", &o.resolution_m, Required(), InRange(0.005, 1.0));
  tree.Get("max_range_m", &o.max_range_m, Required());
  tree.Get("prob_hit", &o.prob_hit, Optional(), Probability<double>());
  tree.Get("prob_miss", &o.prob_miss, Optional(), Probability<double>());
  tree.Get("clamping_min", &o.clamping_min, Optional(), Probability<double>());
  tree.Get("clamping_max", &o.clamping_max, Optional(), Probability<double>());
  if (o.max_range_m == 0) tree.AddError("max_range_m", "must be > 0 (or < 0 for unlimited)");
  if (o.prob_hit <= 0.5) tree.AddError("prob_hit", "must be > 0.5 (a hit raises occupancy)");
  if (o.prob_miss >= 0.5) tree.AddError("prob_miss", "must be < 0.5 (a miss lowers occupancy)");
  if (o.clamping_min >= o.clamping_max) tree.AddError("clamping_min", "must be < clamping_max");

  auto depth = r.Section("depth");
  depth.Get("min_depth_m", &o.depth.min_depth_m, Required(), NonNegative<double>());
  depth.Get("max_depth_m", &o.depth.max_depth_m, Required(), Positive<double>());
  depth.Get("pixel_stride", &o.depth.pixel_stride, Optional(), InRange(1, 64));
  depth.Get("voxel_filter_m", &o.voxel_filter_m, Optional(), InRange(0.0, 10.0));
  // 0 is off; a cube below 1 mm would overflow the filter's integer keys for far points.
  if (o.voxel_filter_m > 0 && o.voxel_filter_m < 0.001)
    depth.AddError("voxel_filter_m", "must be 0 (off) or at least 0.001 m");
  depth.Get("discretize", &o.discretize, Optional());
  depth.Get("subvoxel", &o.subvoxel, Optional(), InRange(0, 16));
  if (o.discretize && o.subvoxel > 1)
    depth.AddError("discretize", "discretize and subvoxel > 1 exclude each other");
  if (o.depth.min_depth_m >= o.depth.max_depth_m)
    depth.AddError("min_depth_m", "must be < max_depth_m");
  r.Get("threads", &o.threads, Optional(), InRange(1, 64));

  auto mount = r.Section("camera_mount");
  mount.Get("x_m", &o.mount.x_m, Optional(), InRange(-10.0, 10.0));
  mount.Get("y_m", &o.mount.y_m, Optional(), InRange(-10.0, 10.0));
  mount.Get("height_m", &o.mount.height_m, Required(), InRange(-1.0, 3.0));
  mount.Get("yaw_rad", &o.mount.yaw_rad, Optional(), InRange(-M_PI, M_PI));
  mount.Get("tilt_rad", &o.mount.tilt_rad, Optional(), InRange(-M_PI / 2, M_PI / 2));
  mount.Get("roll_rad", &o.mount.roll_rad, Optional(), InRange(-M_PI, M_PI));

  auto poses = r.Section("poses");
  // Optional keys fall back to the built-in defaults (FramePoserOptions).
  double latency_s = static_cast<double>(o.poser.max_latency_us) * 1e-6;
  double gap_s = static_cast<double>(o.poser.max_pose_gap_us) * 1e-6;
  int queue = static_cast<int>(o.poser.max_queued_frames);
  poses.Get("max_latency_s", &latency_s, Required(), InRange(0.0, 60.0));
  poses.Get("max_pose_gap_s", &gap_s, Optional(), Positive<double>());
  poses.Get("max_queued_frames", &queue, Optional(), InRange(1, 10000));
  o.poser.max_latency_us = static_cast<int64_t>(latency_s * 1e6);
  o.poser.max_pose_gap_us = static_cast<int64_t>(gap_s * 1e6);
  o.poser.max_queued_frames = static_cast<size_t>(queue);

  auto grid = r.Section("grid");
  grid.Get("min_z_m", &o.grid.min_z_m, Required());
  grid.Get("max_z_m", &o.grid.max_z_m, Required());
  grid.Get("resolution_m", &o.grid.resolution_m, Optional(), InRange(0.0, 10.0));
  std::string up = "z";
  grid.Get("up_axis", &up, Optional(), OneOf({"x", "y", "z", "-x", "-y", "-z"}));
  UpAxis::Parse(up, &o.grid.up);
  if (o.grid.min_z_m >= o.grid.max_z_m) grid.AddError("min_z_m", "must be < max_z_m");

  auto out = r.Section("output");
  out.Get("dir", &o.out_dir, Optional(), NonEmpty());
  out.Get("save_interval_s", &o.save_interval_s, Optional(), InRange(0.01, 86400.0));
  out.Get("octomap_interval_s", &o.octomap_interval_s, Optional(), InRange(0.01, 86400.0));
  out.Get("octomap_binary", &o.octomap_binary, Optional());
  out.Get("grid_interval_s", &o.grid_interval_s, Optional(), InRange(0.01, 86400.0));
  out.Get("keep_cloud", &o.keep_cloud, Optional());
  out.Get("cloud_voxel_m", &o.cloud_voxel_m, Optional(), Positive<double>());
  r.Get("heartbeat_period_s", &o.heartbeat_period_s, Optional(), InRange(0.05, 60.0));

  auto rp = r.Section("repose");
  ReposeOptions& ro = o.repose;
  rp.Get("enabled", &ro.enabled, Optional());
  rp.Get("trajectory_channel", &ro.trajectory_channel, Optional());
  rp.Get("keyframe_distance_m", &ro.keyframe_distance_m, Optional(), Positive<double>());
  rp.Get("keyframe_angle_rad", &ro.keyframe_angle_rad, Optional(), Positive<double>());
  rp.Get("keyframe_interval_s", &ro.keyframe_interval_s, Optional(), Positive<double>());
  rp.Get("point_spacing_m", &ro.point_spacing_m, Optional(), InRange(0.0, 1.0));
  rp.Get("min_shift_m", &ro.min_shift_m, Optional(), InRange(0.0, 10.0));
  rp.Get("min_interval_s", &ro.min_interval_s, Optional(), InRange(0.0, 3600.0));
  rp.Get("rebuild_budget_ms", &ro.rebuild_budget_ms, Optional(), InRange(1.0, 10000.0));
  rp.Get("max_points", &ro.max_points, Optional(), InRange<int64_t>(1000, int64_t{1} << 32));
  rp.Get("retire_after_revisits", &ro.retire_after_revisits, Optional(), InRange(0, 1000));

  if (Status s = r.Finish(); !s.ok()) return s.error();
  return o;
}

Result<OctomapBuilderOptions> OctomapBuilderOptions::LoadFile(const std::string& path) {
  auto reader = ConfigReader::FromFile(path);
  if (!reader.ok()) return reader.error();
  return Load(*reader);
}

std::string OctomapBuilderOptions::PoseChannel() const {
  if (!pose_channel.empty()) return pose_channel;
  return pose_source == "pg" ? "POSE_PG" : "POSE_RBPF";
}

std::string OctomapBuilderOptions::TrajectoryChannel() const {
  if (!repose.trajectory_channel.empty()) return repose.trajectory_channel;
  return pose_source == "pg" ? "TRAJECTORY_PG" : "TRAJECTORY_RBPF";
}

OctomapBuilder::OctomapBuilder(const OctomapBuilderOptions& options)
    : options_(options),
      tree_(std::make_unique<octomap::OcTree>(options.resolution_m)),
      inserter_(options.resolution_m, ToKeySetOptions(options)) {
  tree_->setProbHit(options.prob_hit);
  tree_->setProbMiss(options.prob_miss);
  tree_->setClampingThresMin(options.clamping_min);
  tree_->setClampingThresMax(options.clamping_max);
  if (options.color) {
    color_tree_ = std::make_unique<octomap::ColorOcTree>(options.resolution_m);
    color_tree_->setProbHit(options.prob_hit);
    color_tree_->setProbMiss(options.prob_miss);
    color_tree_->setClampingThresMin(options.clamping_min);
    color_tree_->setClampingThresMax(options.clamping_max);
  }
}

Result<FrameStats> OctomapBuilder::InsertDepth(const DepthImage& image,
                                               const Eigen::Isometry3d& camera_in_map,
                                               ColoredPoints* kept) {
  if (Status s = DepthToPoints(image, options_.depth, &camera_points_); !s.ok()) return s.error();
  if (kept) {
    kept->points = camera_points_;
    kept->colors.clear();
  }
  return InsertPoints(camera_points_, camera_in_map);
}

Result<FrameStats> OctomapBuilder::InsertDepthColor(const DepthImage& image,
                                                    const ColorImage& color,
                                                    const Eigen::Isometry3d& camera_in_map,
                                                    ColoredPoints* kept) {
  if (!color_tree_)
    return MakeError(ErrorCode::kInvalidArgument, "colour insertion needs the colour option");
  const int64_t t0 = ParallelKeySetInserter::NowMicros();
  auto pts = DepthToColoredPoints(image, color, options_.depth);
  if (!pts.ok()) return pts.error();
  const int64_t registration_us = ParallelKeySetInserter::NowMicros() - t0;
  if (kept) {
    kept->points = pts->points;
    kept->colors = pts->colors;
  }
  FrameStats st = InsertPoints(pts->points, camera_in_map, &pts->colors);
  st.colored_points = pts->colored;
  st.color_us += registration_us;
  return st;
}

FrameStats OctomapBuilder::InsertPoints(const std::vector<Eigen::Vector3f>& points_camera,
                                        const Eigen::Isometry3d& camera_in_map,
                                        const std::vector<uint32_t>* colors) {
  FrameStats st;
  st.points = points_camera.size();
  // OctoMap keys a coordinate with a plain cast to int, undefined beyond the int range (1e8 m at
  // 5 cm). A camera outside the tree's key range (about +-1638 m at 5 cm) cannot map anything,
  // and its points could be that far out: such a frame is returned with no keys (the pipeline
  // counts it as out of range). Points within max range of a camera inside stay far from it.
  const double half_extent = tree_->getResolution() * (1 << (tree_->getTreeDepth() - 1));
  if (!camera_in_map.matrix().allFinite() ||
      camera_in_map.translation().cwiseAbs().maxCoeff() >= half_extent)
    return st;
  const Eigen::Isometry3f t = camera_in_map.cast<float>();
  std::vector<Eigen::Vector3f>& world = world_;
  world.clear();
  world.reserve(points_camera.size());
  for (const auto& p : points_camera) world.push_back(t * p);
  // The colours belong to the points before filtering: keep those for the colour scan.
  std::vector<Eigen::Vector3f> world_unfiltered;
  const bool colored = color_tree_ && colors && colors->size() == world.size();
  if (colored && options_.voxel_filter_m > 0) world_unfiltered = world;
  if (options_.voxel_filter_m > 0) world = VoxelDownsample(world, options_.voxel_filter_m);
  if (options_.keep_cloud) {
    const double inv = 1.0 / options_.cloud_voxel_m;
    constexpr double kHalfSpan = 1 << 20;  // cloud cells per axis each side (21-bit keys)
    octomap::OcTreeKey key;
    for (const auto& p : world) {
      // Only points the octree can hold (a pose far out of the map puts a frame outside its key
      // range), and inside the cloud's own key span (no wrapping, no undefined cast).
      if (!(std::abs(p.x() * inv) < kHalfSpan && std::abs(p.y() * inv) < kHalfSpan &&
            std::abs(p.z() * inv) < kHalfSpan) ||
          !tree_->coordToKeyChecked(p.x(), p.y(), p.z(), key))
        continue;
      const auto ix =
          static_cast<uint64_t>(static_cast<int64_t>(std::floor(p.x() * inv)) + (1 << 20));
      const auto iy =
          static_cast<uint64_t>(static_cast<int64_t>(std::floor(p.y() * inv)) + (1 << 20));
      const auto iz =
          static_cast<uint64_t>(static_cast<int64_t>(std::floor(p.z() * inv)) + (1 << 20));
      CloudCell& c = cloud_[(ix & 0x1fffff) | ((iy & 0x1fffff) << 21) | ((iz & 0x1fffff) << 42)];
      c.sum += p.cast<double>();
      ++c.n;
    }
  }
  inserter_.ComputeKeySets(world, t.translation(), &sets_, &st.insert);
  const KeySets& sets = sets_;
  const int64_t t0 = ParallelKeySetInserter::NowMicros();
  ParallelKeySetInserter::Apply(tree_.get(), sets);
  const int64_t t1 = ParallelKeySetInserter::NowMicros();
  st.insert.update_us = t1 - t0;
  st.rays = st.insert.rays;
  if (color_tree_) {
    ScanColors scan;
    if (colored) {
      scan = ComputeScanColors(*color_tree_, sets,
                               options_.voxel_filter_m > 0 ? world_unfiltered : world, *colors,
                               t.translation(), options_.max_range_m);
    } else {
      scan.of_update.assign(sets.updates.size(), 0);
    }
    ApplyColored(color_tree_.get(), sets, scan);
    st.colored_keys = scan.colored_keys;
    st.color_us = ParallelKeySetInserter::NowMicros() - t1;
  }
  ++frames_inserted_;
  return st;
}

std::vector<Eigen::Vector3f> OctomapBuilder::AggregateCloud() const {
  std::vector<Eigen::Vector3f> out;
  out.reserve(cloud_.size());
  for (const auto& [key, c] : cloud_) out.push_back((c.sum / c.n).cast<float>());
  return out;
}

OctomapPipeline::OctomapPipeline(const OctomapBuilderOptions& options)
    : builder_(std::make_unique<OctomapBuilder>(options)), poser_(options.poser) {}

void OctomapPipeline::AddPose(int64_t utime, const Pose2& robot_in_map) {
  poser_.AddPose(utime, robot_in_map);
}

void OctomapPipeline::AddDepth(DepthImage image) {
  const int64_t t = image.utime;
  poser_.AddFrame(t, std::move(image));
}

int64_t OctomapPipeline::newest_utime() const {
  // Not the colour frames' time: colour stamped ahead of depth (another clock, or one frame
  // stamped in the future) expired every depth frame still waiting for its pose. A colour frame
  // later than a depth frame's window already lets that frame go (PairAndInsert).
  return std::max(poser_.newest_pose_utime(), poser_.newest_frame_utime());
}

void OctomapPipeline::AddColor(ColorImage image) {
  const OctomapBuilderOptions& o = builder_->options();
  if (!o.color) return;
  ++counters_.color_frames_in;
  switch (color_order_.Check(image.utime)) {
    case StampOrder::Verdict::kOld:
      ++counters_.color_out_of_order;
      return;
    case StampOrder::Verdict::kRebase:  // the newest colour frames were stamped in the future
      ++counters_.color_time_rebases;
      while (!colors_.empty() && colors_.back().image.utime > image.utime) {
        counters_.color_dropped += !colors_.back().used;
        colors_.pop_back();
      }
      break;
    case StampOrder::Verdict::kInOrder:
      break;
  }
  colors_.push_back({std::move(image), false});
  while (colors_.size() > o.color_queue) {
    counters_.color_dropped += !colors_.front().used;
    colors_.pop_front();
  }
}

int OctomapPipeline::NearestColor(int64_t utime) const {
  int best = -1;
  int64_t best_dt = builder_->options().color_max_dt_us;
  for (size_t i = 0; i < colors_.size(); ++i) {
    const int64_t dt = std::abs(colors_[i].image.utime - utime);
    if (dt <= best_dt) {  // ties: the later frame
      best_dt = dt;
      best = static_cast<int>(i);
    }
  }
  return best;
}

void OctomapPipeline::Insert(const Posed& posed, const ColorImage* color) {
  const int64_t t0 = ParallelKeySetInserter::NowMicros();
  const Eigen::Isometry3d cam = CameraInMap(posed.robot_in_map, builder_->options().mount);
  Result<FrameStats> st = MakeError(ErrorCode::kInternal, "not inserted");
  ColoredPoints kept_points;
  ColoredPoints* kept = IsKeyframe(posed) ? &kept_points : nullptr;
  if (color) {
    st = builder_->InsertDepthColor(posed.frame, *color, cam, kept);
    if (st.ok()) {
      ++counters_.frames_colored;
    } else if (CheckDepthFrame(posed.frame, builder_->options().depth).ok()) {
      // The depth frame is fine: the colour frame is what cannot be used.
      ++counters_.color_invalid;
      last_error_ = "colour frame " + std::to_string(color->utime) + ": " + st.error().message;
      color = nullptr;
    }
  }
  if (!color) {
    st = builder_->InsertDepth(posed.frame, cam, kept);
    if (st.ok() && builder_->options().color) ++counters_.frames_uncolored;
  }
  if (!st.ok()) {
    ++counters_.frames_invalid;
    last_error_ = st.error().message;
    return;
  }
  if (st->points > 0 && st->insert.free_keys + st->insert.occupied_keys == 0) {
    ++counters_.frames_out_of_range;
    last_error_ = "depth frame " + std::to_string(posed.utime) +
                  ": no point inside the octree's key range (pose far out of the map)";
    return;
  }
  ++counters_.frames_inserted;
  counters_.points_inserted += static_cast<int64_t>(st->points);
  counters_.last_frame_us = ParallelKeySetInserter::NowMicros() - t0;
  if (kept) KeepKeyframe(posed, kept_points);
  newest_inserted_utime_ = std::max(newest_inserted_utime_, posed.utime);
}

int OctomapPipeline::Process(int64_t now_utime) {
  const OctomapBuilderOptions& o = builder_->options();
  int n = 0;
  std::deque<Posed>& waiting = o.color ? awaiting_color_ : ready_;
  for (auto& posed : poser_.Poll(now_utime)) waiting.push_back(std::move(posed));
  // With a budget frames can wait past this call: at most kMaxBacklog (the oldest dropped).
  if (insert_budget_us_ >= 0)
    for (; waiting.size() > kMaxBacklog; waiting.pop_front()) ++counters_.frames_dropped_backlog;
  const int64_t deadline = insert_budget_us_ < 0
                               ? std::numeric_limits<int64_t>::max()
                               : ParallelKeySetInserter::NowMicros() + insert_budget_us_;
  // At least one frame is tried a call (inserted or not: a frame out of range takes its time).
  for (int tried = 0;
       !ready_.empty() && (tried == 0 || ParallelKeySetInserter::NowMicros() < deadline); ++tried) {
    Posed posed = std::move(ready_.front());
    ready_.pop_front();
    const int64_t before = counters_.frames_inserted;
    Insert(posed, nullptr);
    n += static_cast<int>(counters_.frames_inserted - before);
  }
  n += PairAndInsert(now_utime, false, deadline);
  StepRepose();
  return n;
}

int OctomapPipeline::FlushAwaitingColor() {
  return PairAndInsert(newest_utime(), true, std::numeric_limits<int64_t>::max());
}

int OctomapPipeline::FinishInput() {
  const int64_t budget = insert_budget_us_;
  insert_budget_us_ = -1;  // the end: everything goes in
  int n = Process(newest_utime());
  n += Process(std::numeric_limits<int64_t>::max() / 2);  // every wait has expired
  n += FlushAwaitingColor();
  insert_budget_us_ = budget;
  return n;
}

int OctomapPipeline::PairAndInsert(int64_t now_utime, bool force, int64_t deadline_us) {
  const OctomapBuilderOptions& o = builder_->options();
  int n = 0;
  for (int tried = 0; !awaiting_color_.empty(); ++tried) {
    if (tried > 0 && ParallelKeySetInserter::NowMicros() >= deadline_us) break;  // the next call
    const Posed& f = awaiting_color_.front();
    const bool later_color_seen =
        !colors_.empty() && colors_.back().image.utime > f.utime + o.color_max_dt_us;
    const bool expired = now_utime - f.utime > o.poser.max_latency_us;
    if (!later_color_seen && !expired && !force) break;  // a nearer colour frame may come
    const int best = NearestColor(f.utime);
    const int64_t before = counters_.frames_inserted;
    ColorImage* partner = nullptr;
    if (best >= 0) {
      colors_[static_cast<size_t>(best)].used = true;
      partner = &colors_[static_cast<size_t>(best)].image;
    }
    Insert(f, partner);
    n += static_cast<int>(counters_.frames_inserted - before);
    // Later depth frames are later in time: colour frames too old for this one are too old
    // for them.
    const int64_t oldest_useful = f.utime - o.color_max_dt_us;
    awaiting_color_.pop_front();
    while (!colors_.empty() && colors_.front().image.utime < oldest_useful) {
      counters_.color_dropped += !colors_.front().used;
      colors_.pop_front();
    }
  }
  return n;
}

// ---- Re-posing (repose.h) ----

bool OctomapPipeline::IsKeyframe(const Posed& posed) const {
  const ReposeOptions& r = builder_->options().repose;
  if (!r.enabled || counters_.repose_stopped) return false;
  if (keyframes_.empty()) return true;
  const Keyframe& last = keyframes_.back();
  return std::hypot(posed.robot_in_map.x - last.pose.x, posed.robot_in_map.y - last.pose.y) >=
             r.keyframe_distance_m ||
         std::abs(WrapAngle(posed.robot_in_map.theta - last.pose.theta)) >= r.keyframe_angle_rad ||
         static_cast<double>(posed.utime - last.utime) >= r.keyframe_interval_s * 1e6;
}

void OctomapPipeline::KeepKeyframe(const Posed& posed, const ColoredPoints& points) {
  const OctomapBuilderOptions& o = builder_->options();
  Keyframe kf;
  kf.utime = posed.utime;
  kf.pose = posed.robot_in_map;
  const double spacing = o.repose.point_spacing_m > 0 ? o.repose.point_spacing_m : o.resolution_m;
  std::vector<Eigen::Vector3f> thinned;
  std::vector<uint32_t> thinned_colors;
  ThinPoints(points.points, points.colors.empty() ? nullptr : &points.colors, spacing, &thinned,
             &thinned_colors);
  kf.radius_m = KeyframeRadius(thinned, o.mount, o.max_range_m);
  counters_.keyframe_points_dropped +=
      KeepPoints(thinned, thinned_colors.empty() ? nullptr : &thinned_colors, o.max_range_m,
                 &kf.points, &kf.colors);
  const auto n = static_cast<int64_t>(kf.points.size());
  if (o.repose.retire_after_revisits > 0) RetireCoveredBy(kf.pose, n);
  if (counters_.keyframe_points + n > o.repose.max_points && keyframes_.size() >= 2) {
    // Every other keyframe goes, but the first and the newest stay: the whole run stays covered,
    // at half the density. A running rebuild started from the old list: it starts again (the
    // tree keeps the old map meanwhile).
    const bool was_rebuilding = shadow_ != nullptr;
    shadow_.reset();  // before the retired entries go: it walks the list by index
    rebuilt_poses_.clear();
    RemoveRetired();
    std::deque<Keyframe> kept;
    for (size_t i = 0; i < keyframes_.size(); ++i)
      if (i % 2 == 0 || i + 1 == keyframes_.size()) kept.push_back(std::move(keyframes_[i]));
    keyframes_ = std::move(kept);
    counters_.keyframe_points = 0;
    for (const Keyframe& k : keyframes_)
      counters_.keyframe_points += static_cast<int64_t>(k.points.size());
    counters_.keyframes = static_cast<int64_t>(keyframes_.size());
    ++counters_.keyframe_thinnings;
    if (was_rebuilding) {
      wanted_shift_m_ = MaxShift();
      last_rebuild_start_utime_ = INT64_MIN;  // not a new request: start again at once
    }
    LOG_INFO << "octomap repose: repose.max_points " << o.repose.max_points
             << " reached; every other keyframe dropped (" << keyframes_.size() << " kept, "
             << counters_.keyframe_points << " points)";
  }
  if (counters_.keyframe_points + n > o.repose.max_points) {
    // A rebuild without every keyframe would lose what the others saw: stop re-posing instead.
    LOG_WARN << "octomap repose: a keyframe of " << n << " points does not fit in "
             << "repose.max_points " << o.repose.max_points
             << "; re-posing stops here (the tree keeps growing at the published poses)";
    counters_.repose_stopped = 1;
    keyframes_.clear();
    shadow_.reset();
    rebuilt_poses_.clear();
    wanted_shift_m_ = 0;
    counters_.keyframes = 0;
    counters_.keyframe_points = 0;
    return;
  }
  keyframes_.push_back(std::move(kf));
  ++counters_.keyframes;
  counters_.keyframe_points += n;
}

void OctomapPipeline::RetireCoveredBy(const Pose2& pose, int64_t points) {
  const ReposeOptions& r = builder_->options().repose;
  if (!shadow_) RemoveRetired();  // a running rebuild walks the list by index: not now
  for (Keyframe& old : keyframes_) {
    // A view with less than half the points (the camera blocked, a blank frame) is no revisit.
    if (old.retired || 2 * points < static_cast<int64_t>(old.points.size()) ||
        std::hypot(old.pose.x - pose.x, old.pose.y - pose.y) >= r.keyframe_distance_m ||
        std::abs(WrapAngle(old.pose.theta - pose.theta)) >= r.keyframe_angle_rad ||
        ++old.revisits < r.retire_after_revisits)
      continue;
    counters_.keyframe_points -= static_cast<int64_t>(old.points.size());
    --counters_.keyframes;
    ++counters_.keyframes_retired;
    old.retired = true;
    std::vector<KeptPoint>().swap(old.points);  // freed now, not at the next removal
    std::vector<uint32_t>().swap(old.colors);
  }
}

void OctomapPipeline::RemoveRetired() {
  keyframes_.erase(std::remove_if(keyframes_.begin(), keyframes_.end(),
                                  [](const Keyframe& k) { return k.retired; }),
                   keyframes_.end());
}

bool OctomapPipeline::AddTrajectory(std::vector<std::pair<int64_t, Pose2>> poses) {
  const OctomapBuilderOptions& o = builder_->options();
  if (!o.repose.enabled) return false;
  ++counters_.trajectories_in;
  bool ok = !poses.empty();
  size_t first = 0;  // the poses after the last step back in time
  for (size_t i = 0; ok && i < poses.size(); ++i) {
    const Pose2& p = poses[i].second;
    ok = PlausibleOdometryPose(p) && poses[i].first > 0;
    // A stamp equal to the one before (two scans of a log on one stamp) is not a clock set
    // back: it is dropped below, not a cut of everything before it.
    if (i > 0 && poses[i].first < poses[i - 1].first) first = i;
  }
  if (!ok) {
    ++counters_.trajectories_invalid;
    last_error_ = "trajectory of " + std::to_string(poses.size()) +
                  " poses: empty, not finite, beyond 1000 km or a stamp not after 1970; ignored";
    return false;
  }
  if (first > 0) {
    // The mapper followed a clock set back: its path holds the old clock's poses before the new
    // ones. Only the newest run in time order is comparable with the frames' stamps now.
    ++counters_.trajectories_truncated;
    poses.erase(poses.begin(), poses.begin() + static_cast<std::ptrdiff_t>(first));
  }
  // Of poses on one stamp, the first is kept (as `--poses` files are read).
  poses.erase(std::unique(poses.begin(), poses.end(),
                          [](const auto& a, const auto& b) { return a.first == b.first; }),
              poses.end());
  trajectory_ = TrajectoryLookup(std::move(poses));
  // The newest trajectory is the whole path: what it asks for replaces any earlier request. While
  // a rebuild runs, the keyframes it has not reached take the newest poses; whether the ones it
  // has passed need another is decided when it completes.
  if (!shadow_) wanted_shift_m_ = MaxShift();
  return true;
}

Pose2 OctomapPipeline::TargetPose(const Keyframe& kf) const {
  Pose2 p;
  if (trajectory_.At(kf.utime, builder_->options().poser.max_pose_gap_us, &p)) return p;
  return kf.pose;
}

double OctomapPipeline::MaxShift() const {
  const ReposeOptions& r = builder_->options().repose;
  const double threshold = r.min_shift_m > 0 ? r.min_shift_m : 2 * builder_->options().resolution_m;
  double worst = 0;
  for (const Keyframe& kf : keyframes_)
    if (!kf.retired) worst = std::max(worst, PoseShift(kf.pose, TargetPose(kf), kf.radius_m));
  return worst > threshold ? worst : 0;
}

void OctomapPipeline::StepRepose() {
  const ReposeOptions r = builder_->options().repose;  // a copy: RunRebuild replaces builder_
  if (!r.enabled || counters_.repose_stopped) return;
  if (!shadow_ && wanted_shift_m_ > 0 && !keyframes_.empty()) {
    const int64_t now = newest_utime();
    // A clock set back (now before the last start) does not hold rebuilds off until it catches up.
    if (last_rebuild_start_utime_ == INT64_MIN || now < last_rebuild_start_utime_ ||
        static_cast<double>(now - last_rebuild_start_utime_) >= r.min_interval_s * 1e6) {
      shadow_ = std::make_unique<OctomapBuilder>(builder_->options());
      rebuilt_poses_.clear();
      rebuild_us_ = 0;
      running_shift_m_ = wanted_shift_m_;
      wanted_shift_m_ = 0;
      last_rebuild_start_utime_ = now;
      ++counters_.rebuilds_started;
    }
  }
  if (shadow_) RunRebuild(rebuild_budget_us_);
}

void OctomapPipeline::RunRebuild(int64_t budget_us) {
  // Copies: builder_ (which owns the options) is replaced below.
  const CameraMount mount = builder_->options().mount;
  const bool color = builder_->options().color;
  const int64_t t0 = ParallelKeySetInserter::NowMicros();
  while (rebuilt_poses_.size() < keyframes_.size()) {
    const Keyframe& kf = keyframes_[rebuilt_poses_.size()];
    const Pose2 pose = TargetPose(kf);
    if (!kf.retired)
      shadow_->InsertPoints(kf.Points(), CameraInMap(pose, mount),
                            color && !kf.colors.empty() ? &kf.colors : nullptr);
    rebuilt_poses_.push_back(pose);
    if (budget_us >= 0 && ParallelKeySetInserter::NowMicros() - t0 >= budget_us) break;
  }
  rebuild_us_ += ParallelKeySetInserter::NowMicros() - t0;
  if (rebuilt_poses_.size() < keyframes_.size()) return;
  builder_ = std::move(shadow_);
  for (size_t i = 0; i < keyframes_.size(); ++i) keyframes_[i].pose = rebuilt_poses_[i];
  rebuilt_poses_.clear();
  ++counters_.rebuilds_done;
  counters_.last_rebuild_us = rebuild_us_;
  counters_.last_rebuild_shift_mm = std::llround(running_shift_m_ * 1000);
  // The trajectory may have moved on while this ran.
  wanted_shift_m_ = MaxShift();
}

void OctomapPipeline::FinishRepose() {
  if (!builder_->options().repose.enabled) return;
  if (shadow_) RunRebuild(-1);
  // Keyframes kept since the newest trajectory came are checked against it too.
  if (!counters_.repose_stopped) wanted_shift_m_ = MaxShift();
  if (wanted_shift_m_ > 0 && !counters_.repose_stopped) {
    last_rebuild_start_utime_ = INT64_MIN;  // now, whatever the interval
    const int64_t budget = rebuild_budget_us_;
    rebuild_budget_us_ = -1;
    StepRepose();
    rebuild_budget_us_ = budget;
  }
}

}  // namespace omni::octo
