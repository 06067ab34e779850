// Re-posing the OctoMap after the 2D SLAM corrects its trajectory (repose.h): the helpers, and
// the pipeline rebuilding its tree from keyframes at the corrected poses.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include "omni/octomap_builder/octomap_builder.h"
#include "omni/octomap_builder/tree_compare.h"

namespace omni::octo {
namespace {

TEST(ReposeThinPoints, OneCentroidPerCubeWithTheFirstColourInIt) {
  const std::vector<Eigen::Vector3f> pts = {
      {0.01f, 0.01f, 1.01f},
      {0.03f, 0.01f, 1.01f},  // one 5 cm cube: centroid x 0.02
      {0.30f, 0.0f, 1.0f},    // another
      {NAN, 0.0f, 1.0f}};     // dropped
  const std::vector<uint32_t> colors = {0, PackRgb(1, 2, 3), PackRgb(9, 9, 9), 5};
  std::vector<Eigen::Vector3f> out;
  std::vector<uint32_t> out_colors;
  ThinPoints(pts, &colors, 0.05, &out, &out_colors);
  ASSERT_EQ(out.size(), 2u);
  ASSERT_EQ(out_colors.size(), 2u);
  EXPECT_NEAR(out[0].x(), 0.02f, 1e-6);
  EXPECT_EQ(out_colors[0], PackRgb(1, 2, 3));  // the first non-zero colour of the cube
  EXPECT_NEAR(out[1].x(), 0.30f, 1e-6);
  EXPECT_EQ(out_colors[1], PackRgb(9, 9, 9));
  ThinPoints(pts, nullptr, 0.05, &out, &out_colors);
  EXPECT_EQ(out.size(), 2u);
  EXPECT_TRUE(out_colors.empty());
}

TEST(ReposeKeepPoints, MillimetresWithinHalfAMillimetreAndColoursInStep) {
  std::vector<Eigen::Vector3f> pts;
  std::vector<uint32_t> colors;
  for (int i = 0; i < 2000; ++i) {
    // Spread over ±12 m and across every millimetre fraction.
    pts.emplace_back(-12.0f + 0.0123457f * i, 0.7f - 0.0031f * i, 0.3f + 0.00577f * i);
    colors.push_back(static_cast<uint32_t>(i));
  }
  pts.emplace_back(std::nanf(""), 0.0f, 1.0f);  // not finite: dropped, whatever the ray cut
  colors.push_back(9999);
  pts.emplace_back(1.0f, std::nanf(""), 1.0f);  // on any axis
  colors.push_back(9998);
  pts.emplace_back(1.0f, 0.5f, std::numeric_limits<float>::infinity());
  colors.push_back(9997);
  pts.emplace_back(32.7f, -32.7f, 32.7f);  // just inside the range
  colors.push_back(7);
  std::vector<KeptPoint> kept;
  std::vector<uint32_t> kept_colors;
  EXPECT_EQ(KeepPoints(pts, &colors, 5.0, &kept, &kept_colors), 3);
  ASSERT_EQ(kept.size(), pts.size() - 3);
  ASSERT_EQ(kept_colors.size(), kept.size());
  Keyframe kf;
  kf.points = kept;
  const std::vector<Eigen::Vector3f> back = kf.Points();
  ASSERT_EQ(back.size(), kept.size());
  double worst = 0;
  for (size_t i = 0; i < 2000; ++i) {
    worst = std::max(worst, static_cast<double>((back[i] - pts[i]).cwiseAbs().maxCoeff()));
    EXPECT_EQ(kept_colors[i], i);
  }
  EXPECT_LE(worst, 0.5e-3 + 1e-5);
  EXPECT_GT(worst, 0.4e-3);  // the points do fall between millimetres
  EXPECT_NEAR(back.back().x(), 32.7f, 1e-6);
  EXPECT_EQ(kept_colors.back(), 7u);
  // Without colours nothing is written to them.
  EXPECT_EQ(KeepPoints(pts, nullptr, 5.0, &kept, &kept_colors), 3);
  EXPECT_TRUE(kept_colors.empty());
}

TEST(ReposeKeepPoints, AFarPointKeepsItsRayWhenRaysAreCutAndIsDroppedOtherwise) {
  // Keeping turns the ray by up to 1.5e-5 rad (0.5 mm in 32 m), 0.08 mm at 5 m: the same cells
  // unless the ray passes that close to a cell's edge. From this camera position the ray below
  // stays 1.3 mm clear of every edge it passes within 5 m (checked by a one-off script).
  const std::vector<Eigen::Vector3f> far = {{12.5f, 5.0f, 50.0f}, {0.2f, 0.1f, 2.0f}};
  const std::vector<uint32_t> colors = {1, 2};
  std::vector<KeptPoint> kept;
  std::vector<uint32_t> kept_colors;
  EXPECT_EQ(KeepPoints(far, &colors, 5.0, &kept, &kept_colors), 0);
  ASSERT_EQ(kept.size(), 2u);
  Keyframe kf;
  kf.points = kept;
  const std::vector<Eigen::Vector3f> back = kf.Points();
  EXPECT_NEAR(back[0].z(), 32.767f, 1e-3);  // on the same ray, at the bound
  EXPECT_NEAR(back[0].x() / back[0].z(), 0.25f, 1e-4);
  EXPECT_NEAR(back[0].y() / back[0].z(), 0.1f, 1e-4);
  // The rays it inserts into a tree that cuts them at 5 m are the original's.
  OctomapBuilderOptions o;
  o.max_range_m = 5.0;
  OctomapBuilder original(o), from_kept(o);
  Eigen::Isometry3d cam = Eigen::Isometry3d::Identity();
  cam.translation() = Eigen::Vector3d(0.021, 0.013, 0.017);
  original.InsertPoints(far, cam);
  from_kept.InsertPoints(back, cam);
  EXPECT_TRUE(SameLeaves(original.tree(), from_kept.tree()));
  // Uncut rays: the far point would end in the wrong place, so it is dropped, its colour too.
  EXPECT_EQ(KeepPoints(far, &colors, -1, &kept, &kept_colors), 1);
  ASSERT_EQ(kept.size(), 1u);
  EXPECT_EQ(kept[0].z_mm, 2000);
  EXPECT_EQ(kept_colors, std::vector<uint32_t>{2});
  EXPECT_EQ(KeepPoints(far, &colors, 40.0, &kept, &kept_colors), 1);  // cut beyond the bound
  // A cut near the bound could take the moved point (32.767 m out, less rounding) for a hit.
  EXPECT_EQ(KeepPoints(far, &colors, 32.5, &kept, &kept_colors), 1);
  EXPECT_EQ(KeepPoints(far, &colors, kKeptPointCutM, &kept, &kept_colors), 0);
}

TEST(ReposePoseShift, TranslationPlusTheChordOfTheFarthestPoint) {
  EXPECT_NEAR(PoseShift({0, 0, 0}, {0.3, 0.4, 0}, 5.0), 0.5, 1e-12);
  // A point 4 m out, turned by 0.1 rad about the robot: it moves along the chord.
  const double chord = 2 * std::sin(0.05) * 4.0;
  EXPECT_NEAR(PoseShift({1, 1, 3.1}, {1, 1, 3.1 + 0.1}, 4.0), chord, 1e-12);
  // Across ±π: the short way round.
  EXPECT_NEAR(PoseShift({0, 0, M_PI - 0.05}, {0, 0, -M_PI + 0.05}, 4.0), chord, 1e-9);
  // The exact displacement of that point is the chord.
  const Pose2 a(0, 0, 0.2), b(0, 0, 0.3);
  const Eigen::Vector2d p(4.0, 0.0);
  EXPECT_NEAR((b.Transform(p) - a.Transform(p)).norm(), chord, 1e-12);
}

TEST(ReposeKeyframeRadius, FarthestPointFromTheRobotCappedByTheRange) {
  CameraMount mount;
  mount.x_m = 0.1;
  mount.height_m = 0.45;
  // Optical z forward: a point 2 m ahead of the camera is 2.1 m ahead of the robot.
  const std::vector<Eigen::Vector3f> pts = {{0, 0, 1.0f}, {0, 0, 2.0f}};
  EXPECT_NEAR(KeyframeRadius(pts, mount, -1), 2.1, 1e-6);
  EXPECT_NEAR(KeyframeRadius(pts, mount, 1.5), 1.6, 1e-6);  // the ray stops at 1.5 m
}

TEST(ReposeTrajectoryLookup, InterpolatesInsideAndRefusesOutsideOrAcrossAGap) {
  TrajectoryLookup t({{100, Pose2(0, 0, 0)}, {200, Pose2(1, 2, 0.2)}, {5000, Pose2(5, 5, 0)}});
  Pose2 p;
  ASSERT_TRUE(t.At(150, 1000, &p));
  EXPECT_NEAR(p.x, 0.5, 1e-12);
  EXPECT_NEAR(p.y, 1.0, 1e-12);
  EXPECT_NEAR(p.theta, 0.1, 1e-12);
  ASSERT_TRUE(t.At(200, 1000, &p));  // exactly on a pose: that pose, whatever the gap after it
  EXPECT_EQ(p.x, 1);
  EXPECT_FALSE(t.At(99, 1000, &p));
  EXPECT_FALSE(t.At(5001, 1000, &p));
  EXPECT_FALSE(t.At(300, 1000, &p));  // 200 -> 5000 is wider than the gap
  EXPECT_TRUE(t.At(300, 10000, &p));
}

// A flat wall 3 m ahead of the camera (the shipped mount: 0.1 m ahead of the robot's origin).
DepthImage WallDepth(int64_t utime, double distance_m) {
  DepthImage im;
  im.utime = utime;
  im.width = 40;
  im.height = 30;
  im.intrinsics = {30.0, 30.0, 19.5, 14.5, 1000.0};
  im.data.assign(static_cast<size_t>(im.width) * im.height,
                 static_cast<uint16_t>(std::lround(distance_m * 1000)));
  return im;
}

OctomapBuilderOptions ReposeOptionsForTest() {
  OctomapBuilderOptions o;
  o.resolution_m = 0.05;
  o.max_range_m = 5.0;
  o.depth.min_depth_m = 0.4;
  o.depth.max_depth_m = 6.0;
  o.mount.x_m = 0.1;
  o.mount.height_m = 0.45;
  o.threads = 1;
  o.repose.enabled = true;
  o.repose.keyframe_distance_m = 0.15;  // every frame (0.2 m apart)
  o.repose.min_interval_s = 0;
  return o;
}

constexpr int64_t kT0 = 1700000000000000;

// The robot drives along +x towards a wall; poses at 10 Hz put it at x = 0.1 i, frames at 5 Hz
// between them see the wall at x = 3.0 in those poses.
void FeedDrive(OctomapPipeline* p, int n_poses) {
  for (int i = 0; i < n_poses; ++i) {
    const int64_t t = kT0 + i * 100000;
    p->AddPose(t, Pose2(0.1 * i, 0, 0));
    if (i % 2 == 1) {
      // Frame halfway between poses i-1 and i: robot at 0.1 i - 0.05, wall 3.0 - that - 0.1 away.
      const double x = 0.1 * i - 0.05;
      p->AddDepth(WallDepth(t - 50000, 3.0 - x - 0.1));
    }
    p->Process(p->newest_utime());
  }
}

// The robot stands at `x` from `t0` for `seconds`, poses at 10 Hz, frames at 5 Hz between them,
// facing the wall at x = `wall_x`; each pose processed, or all at the end without `each`.
void FeedStand(OctomapPipeline* p, int64_t t0, double x, double seconds, double wall_x = 3.0,
               bool each = true) {
  for (int i = 0; i <= static_cast<int>(seconds * 10); ++i) {
    const int64_t t = t0 + i * 100000;
    p->AddPose(t, Pose2(x, 0, 0));
    if (i % 2 == 1) p->AddDepth(WallDepth(t - 50000, wall_x - x - 0.1));
    if (each) p->Process(p->newest_utime());
  }
  if (!each) p->Process(p->newest_utime());
}

// The trajectory the SLAM corrected: every pose 0.5 m further along x.
std::vector<std::pair<int64_t, Pose2>> Shifted(int n_poses, double dx) {
  std::vector<std::pair<int64_t, Pose2>> t;
  for (int i = 0; i < n_poses; ++i) t.emplace_back(kT0 + i * 100000, Pose2(0.1 * i + dx, 0, 0));
  return t;
}

bool Occupied(const octomap::OcTree& t, double x) {
  const octomap::OcTreeNode* n = t.search(x, 0.0, 0.45);
  return n && t.isNodeOccupied(n);
}

TEST(ReposePipeline, ACorrectedTrajectoryRebuildsTheTreeAtTheCorrectedPoses) {
  const OctomapBuilderOptions o = ReposeOptionsForTest();
  OctomapPipeline p(o);
  FeedDrive(&p, 21);  // 10 frames over 2 m, each a keyframe
  ASSERT_EQ(p.counters().frames_inserted, 10);
  EXPECT_EQ(p.counters().keyframes, 10);
  EXPECT_GT(p.counters().keyframe_points, 100);
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.01));
  EXPECT_FALSE(Occupied(p.builder().tree(), 3.51));
  const int64_t version = p.tree_version();

  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_started, 1);
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  EXPECT_EQ(p.counters().last_rebuild_shift_mm, 500);
  EXPECT_EQ(p.tree_version(), version + 1);
  EXPECT_FALSE(p.rebuilding());
  // The wall moved with the poses; where it was is free space now.
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.51));
  EXPECT_FALSE(Occupied(p.builder().tree(), 3.01));
  for (const Keyframe& kf : p.keyframes()) {
    const double live_x = static_cast<double>(kf.utime - kT0) / 1e6;  // 1 m/s from x = 0
    EXPECT_NEAR(kf.pose.x, live_x + 0.5, 1e-9);
  }
  // The rebuilt tree is exactly the keyframes inserted at those poses, in time order.
  OctomapBuilder reference(o);
  for (const Keyframe& kf : p.keyframes())
    reference.InsertPoints(kf.Points(), CameraInMap(kf.pose, o.mount));
  EXPECT_TRUE(SameLeaves(reference.tree(), p.builder().tree()));

  // The same trajectory again: nothing moves, no rebuild.
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_started, 1);
}

// With an insert budget, a burst of posed frames goes in over several Process calls (at least
// one a call), in time order, and the end of the input puts in the rest: the node's heartbeat
// beats between them instead of waiting seconds for the whole burst (review finding).
TEST(OctomapPipelineBudget, ABurstOfFramesGoesInOverSeveralCalls) {
  OctomapBuilderOptions o = ReposeOptionsForTest();
  o.repose.enabled = false;
  OctomapPipeline p(o);
  p.set_insert_budget_us(0);                          // one frame a call
  FeedStand(&p, kT0, 0.0, 2.0, 3.0, /*each=*/false);  // 10 frames, posed at once
  EXPECT_EQ(p.counters().frames_inserted, 1);
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().frames_inserted, 2);
  EXPECT_EQ(p.FinishInput(), 8);
  EXPECT_EQ(p.counters().frames_inserted, 10);
  EXPECT_EQ(p.counters().frames_dropped_backlog, 0);
  // Without a budget (the offline tools): all at once.
  OctomapPipeline q(o);
  FeedStand(&q, kT0, 0.0, 2.0, 3.0, /*each=*/false);
  EXPECT_EQ(q.counters().frames_inserted, 10);
  EXPECT_TRUE(SameLeaves(q.builder().tree(), p.builder().tree()));
}

TEST(ReposePipeline, ShiftsBelowTheThresholdLeaveTheTreeAlone) {
  OctomapBuilderOptions o = ReposeOptionsForTest();
  o.repose.min_shift_m = 0.1;
  OctomapPipeline p(o);
  FeedDrive(&p, 21);
  const int64_t version = p.tree_version();
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.09)));  // every point moves 9 cm
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_started, 0);
  EXPECT_EQ(p.tree_version(), version);
  // A turn of 0.02 rad moves the far end of a keyframe (about 3 m out) by 6 cm, 0.04 rad by 12.
  std::vector<std::pair<int64_t, Pose2>> turned = Shifted(21, 0);
  for (auto& [t, pose] : turned) pose.theta = 0.02;
  ASSERT_TRUE(p.AddTrajectory(turned));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_started, 0);
  for (auto& [t, pose] : turned) pose.theta = 0.04;
  ASSERT_TRUE(p.AddTrajectory(turned));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_done, 1);
}

TEST(ReposePipeline, ARebuildInSlicesSwapsTheTreeOnlyWhenComplete) {
  OctomapBuilderOptions o = ReposeOptionsForTest();
  OctomapPipeline p(o);
  FeedDrive(&p, 21);
  p.set_rebuild_budget_us(0);  // one keyframe per Process call
  const int64_t version = p.tree_version();
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));
  int calls = 0;
  do {
    p.Process(p.newest_utime());
    ++calls;
    if (p.rebuilding()) {
      // Meanwhile the old tree is the map: the wall still where it was.
      EXPECT_EQ(p.tree_version(), version);
      EXPECT_TRUE(Occupied(p.builder().tree(), 3.01));
    }
  } while (p.rebuilding() && calls < 100);
  EXPECT_EQ(calls, 10);  // ten keyframes
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.51));
}

TEST(ReposePipeline, RebuildsKeepTheirIntervalUntilTheEnd) {
  OctomapBuilderOptions o = ReposeOptionsForTest();
  o.repose.min_interval_s = 10;
  OctomapPipeline p(o);
  FeedDrive(&p, 21);
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 1.0)));  // within 10 s of data time: waits
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_started, 1);
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.51));
  p.FinishRepose();  // the end of the input: the newest trajectory goes in
  EXPECT_EQ(p.counters().rebuilds_done, 2);
  EXPECT_EQ(p.counters().last_rebuild_shift_mm, 500);
  EXPECT_TRUE(Occupied(p.builder().tree(), 4.01));
  EXPECT_FALSE(Occupied(p.builder().tree(), 3.51));
}

TEST(ReposePipeline, BadTrajectoriesAreCountedAndChangeNothing) {
  OctomapPipeline p(ReposeOptionsForTest());
  FeedDrive(&p, 21);
  auto nan = Shifted(21, 0.5);
  nan[3].second.y = NAN;
  EXPECT_FALSE(p.AddTrajectory(nan));
  auto zero = Shifted(21, 0.5);
  zero[0].first = 0;
  EXPECT_FALSE(p.AddTrajectory(zero));
  EXPECT_FALSE(p.AddTrajectory({}));
  auto far = Shifted(21, 0.5);  // finite, but no keyframe could be re-posed 1e20 m out
  far[7].second.x = 1e20;
  EXPECT_FALSE(p.AddTrajectory(far));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().trajectories_in, 4);
  EXPECT_EQ(p.counters().trajectories_invalid, 4);
  EXPECT_EQ(p.counters().rebuilds_started, 0);
  EXPECT_NE(p.last_error().find("not finite"), std::string::npos) << p.last_error();
  // Without the option, trajectories are not even taken.
  OctomapBuilderOptions off = ReposeOptionsForTest();
  off.repose.enabled = false;
  OctomapPipeline q(off);
  FeedDrive(&q, 5);
  EXPECT_FALSE(q.AddTrajectory(Shifted(5, 0.5)));
  EXPECT_EQ(q.counters().trajectories_in, 0);
  EXPECT_EQ(q.counters().keyframes, 0);
}

TEST(ReposePipeline, AfterAStepBackInTimeOnlyTheNewestRunIsTaken) {
  OctomapPipeline p(ReposeOptionsForTest());
  FeedDrive(&p, 21);
  // A mapper that followed a clock set back: its path starts with poses of the old clock (an
  // hour later, 3 m off), then the run the frames belong to, 0.5 m ahead.
  std::vector<std::pair<int64_t, Pose2>> t;
  for (int i = 0; i < 5; ++i) t.emplace_back(kT0 + 3600000000 + i * 100000, Pose2(3, 0, 0));
  for (const auto& e : Shifted(21, 0.5)) t.push_back(e);
  ASSERT_TRUE(p.AddTrajectory(t));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().trajectories_truncated, 1);
  EXPECT_EQ(p.counters().trajectories_invalid, 0);
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.51));
}

// Two poses on one stamp (an imported log's scans that share a stamp) are not a clock set back:
// every keyframe is re-posed (it used to cut the path there and leave the keyframes before it
// where they were, review 2026-12-06).
TEST(ReposePipeline, APoseRepeatingItsStampDoesNotCutThePath) {
  OctomapPipeline p(ReposeOptionsForTest());
  FeedDrive(&p, 21);
  auto t = Shifted(21, 0.5);
  t.insert(t.begin() + 15, t[15]);
  ASSERT_TRUE(p.AddTrajectory(t));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().trajectories_truncated, 0);
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  for (const Keyframe& kf : p.keyframes()) {
    const double live_x = static_cast<double>(kf.utime - kT0) / 1e6;
    EXPECT_NEAR(kf.pose.x, live_x + 0.5, 1e-9) << "keyframe at " << kf.utime;
  }
}

TEST(ReposePipeline, ANewerTrajectoryThatUndoesTheShiftCancelsTheRequest) {
  OctomapBuilderOptions o = ReposeOptionsForTest();
  o.repose.min_interval_s = 10;
  OctomapPipeline p(o);
  FeedDrive(&p, 21);
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));
  p.Process(p.newest_utime());
  ASSERT_EQ(p.counters().rebuilds_done, 1);
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 1.0)));  // waits for the interval ...
  p.Process(p.newest_utime());
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));  // ... and is taken back: nothing to do
  p.AddPose(kT0 + 13000000, Pose2(2.1, 0, 0));     // the interval has passed
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_started, 1);
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.51));
}

TEST(ReposePipeline, FinishReposeAlsoMovesKeyframesKeptAfterTheNewestTrajectory) {
  OctomapPipeline p(ReposeOptionsForTest());
  FeedDrive(&p, 11);  // five frames, up to x = 0.95
  // The trajectory covers the whole drive but comes before the last frames are inserted.
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.0)));  // no shift for what is mapped so far
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_started, 0);
  for (int i = 11; i < 21; ++i) {  // these frames go in at poses 0.5 m behind the trajectory
    const int64_t t = kT0 + i * 100000;
    p.AddPose(t, Pose2(0.1 * i - 0.5, 0, 0));
    if (i % 2 == 1) p.AddDepth(WallDepth(t - 50000, 3.0 - (0.1 * i - 0.05) - 0.1));
    p.Process(p.newest_utime());
  }
  EXPECT_EQ(p.counters().rebuilds_started, 0);  // no trajectory came since
  p.FinishRepose();
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  EXPECT_EQ(p.counters().last_rebuild_shift_mm, 500);
}

TEST(ReposePipeline, ThePointBudgetHalvesTheKeyframesOverTheWholeRun) {
  OctomapBuilderOptions o = ReposeOptionsForTest();
  OctomapPipeline probe(o);
  FeedDrive(&probe, 3);  // one keyframe
  ASSERT_EQ(probe.counters().keyframes, 1);
  const int64_t per_frame = probe.counters().keyframe_points;
  o.repose.max_points = per_frame * 4 + per_frame / 2;  // room for four
  OctomapPipeline p(o);
  FeedDrive(&p, 21);  // ten frames, each a keyframe
  EXPECT_EQ(p.counters().frames_inserted, 10);
  EXPECT_GE(p.counters().keyframe_thinnings, 1);
  EXPECT_EQ(p.counters().repose_stopped, 0);
  EXPECT_LE(p.counters().keyframe_points, o.repose.max_points);
  ASSERT_GE(p.keyframes().size(), 2u);
  // The first and the newest stay: what is left still spans the whole run.
  EXPECT_EQ(p.keyframes().back().utime, kT0 + 19 * 100000 - 50000);
  EXPECT_EQ(p.keyframes().front().utime, kT0 + 100000 - 50000);
  // Re-posing goes on with the keyframes left.
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.51));
}

TEST(ReposePipeline, RevisitsRetireTheKeyframesTheyStandOn) {
  OctomapBuilderOptions o = ReposeOptionsForTest();
  ASSERT_EQ(o.repose.retire_after_revisits, 2);  // the default
  OctomapPipeline p(o);
  FeedDrive(&p, 21);  // keyframes at x = 0.05, 0.25, ..., 1.85
  ASSERT_EQ(p.counters().keyframes, 10);
  const int64_t fifth_points = static_cast<int64_t>(p.keyframes()[4].points.size());
  const int64_t points_before = p.counters().keyframe_points;
  // Back at x = 0.85, the fifth keyframe's pose, 1 s later, standing there for 5 s: the first
  // frame there is a keyframe (1 m from the newest), and standing makes one every
  // keyframe_interval_s (2 s): three views of the fifth's place. The second retires the fifth,
  // the third the first of them.
  FeedStand(&p, kT0 + 3000000, 0.85, 5.0);
  EXPECT_EQ(p.counters().frames_inserted, 35);
  EXPECT_EQ(p.counters().keyframes_retired, 2);
  EXPECT_EQ(p.counters().keyframes, 11);
  // The same view of the wall as the fifth's: one more keyframe's worth.
  EXPECT_EQ(p.counters().keyframe_points, points_before + fifth_points);
  int64_t live = 0, points = 0;
  for (const Keyframe& kf : p.keyframes()) {
    if (kf.retired) {
      EXPECT_EQ(kf.points.capacity(), 0u);  // freed at once, before the entry goes
      continue;
    }
    ++live;
    points += static_cast<int64_t>(kf.points.size());
    if (kf.utime < kT0 + 3000000) {
      EXPECT_GT(std::abs(kf.pose.x - 0.85), 0.1);
    }
  }
  EXPECT_EQ(live, 11);
  EXPECT_EQ(points, p.counters().keyframe_points);
  EXPECT_LE(p.keyframes().size(), 12u);  // retired entries go when the next keyframe comes

  // A corrected path moves the keyframes that are left, and only they make the rebuilt tree.
  std::vector<std::pair<int64_t, Pose2>> corrected = Shifted(21, 0.5);
  for (int i = 0; i <= 50; ++i)
    corrected.emplace_back(kT0 + 3000000 + i * 100000, Pose2(1.35, 0, 0));
  ASSERT_TRUE(p.AddTrajectory(corrected));
  p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  OctomapBuilder reference(o);
  for (const Keyframe& kf : p.keyframes())
    if (!kf.retired) reference.InsertPoints(kf.Points(), CameraInMap(kf.pose, o.mount));
  EXPECT_TRUE(SameLeaves(reference.tree(), p.builder().tree()));
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.51));

  // The same drive and stay with other settings.
  const auto drive_then_stand = [&o](int retire_after_revisits, double wall_x) {
    o.repose.retire_after_revisits = retire_after_revisits;
    auto q = std::make_unique<OctomapPipeline>(o);
    FeedDrive(q.get(), 21);
    FeedStand(q.get(), kT0 + 3000000, 0.85, 5.0, wall_x);
    return q;
  };
  // One newer view retires a keyframe: the fifth and the first two standing ones go.
  const auto one = drive_then_stand(1, 3.0);
  EXPECT_EQ(one->counters().keyframes_retired, 3);
  EXPECT_EQ(one->counters().keyframes, 10);
  // A view of far fewer points (here none: the wall nearer than min_depth_m) is no revisit.
  const auto blocked = drive_then_stand(1, 1.2);
  EXPECT_EQ(blocked->counters().frames_inserted, 35);
  EXPECT_EQ(blocked->counters().keyframes_retired, 2);  // the two empty stand views only
  EXPECT_EQ(blocked->keyframes()[4].points.size(), static_cast<size_t>(fifth_points));
  // 0: every keyframe stays.
  const auto all = drive_then_stand(0, 3.0);
  EXPECT_EQ(all->counters().keyframes, 13);
  EXPECT_EQ(all->counters().keyframes_retired, 0);
  EXPECT_EQ(all->keyframes().size(), 13u);
}

TEST(ReposePipeline, KeyframesRetiredDuringARebuildInSlicesStayListedUntilItEnds) {
  const OctomapBuilderOptions o = ReposeOptionsForTest();
  OctomapPipeline p(o);
  FeedDrive(&p, 21);
  p.set_rebuild_budget_us(0);  // one keyframe per Process call
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));
  p.Process(p.newest_utime());
  ASSERT_TRUE(p.rebuilding());
  // The three standing views of the fifth keyframe's place come in one call, mid-rebuild.
  FeedStand(&p, kT0 + 3000000, 0.85, 5.0, 3.0, /*each=*/false);
  EXPECT_TRUE(p.rebuilding());
  EXPECT_EQ(p.counters().keyframes_retired, 2);
  EXPECT_EQ(p.counters().keyframes, 11);
  EXPECT_EQ(p.keyframes().size(), 13u);  // the rebuild walks the list by index: entries stay
  EXPECT_TRUE(p.keyframes()[4].retired);
  while (p.rebuilding()) p.Process(p.newest_utime());
  EXPECT_EQ(p.counters().rebuilds_done, 1);
  // The rebuilt tree is the keyframes left, the retired fifth not among them.
  OctomapBuilder reference(o);
  for (const Keyframe& kf : p.keyframes())
    if (!kf.retired) reference.InsertPoints(kf.Points(), CameraInMap(kf.pose, o.mount));
  EXPECT_TRUE(SameLeaves(reference.tree(), p.builder().tree()));
  // The next keyframe, with no rebuild running, clears the retired entries out.
  FeedStand(&p, kT0 + 9000000, 2.5, 0.2, 4.0);
  EXPECT_EQ(p.keyframes().size(), 12u);
  for (const Keyframe& kf : p.keyframes()) EXPECT_FALSE(kf.retired);
}

TEST(ReposePipeline, AKeyframeLargerThanTheBudgetStopsReposing) {
  OctomapBuilderOptions o = ReposeOptionsForTest();
  OctomapPipeline probe(o);
  FeedDrive(&probe, 3);
  o.repose.max_points = probe.counters().keyframe_points - 1;
  OctomapPipeline p(o);
  FeedDrive(&p, 21);
  EXPECT_EQ(p.counters().repose_stopped, 1);
  EXPECT_EQ(p.counters().keyframes, 0);
  EXPECT_TRUE(p.keyframes().empty());
  EXPECT_EQ(p.counters().frames_inserted, 10);  // the map goes on at the published poses
  ASSERT_TRUE(p.AddTrajectory(Shifted(21, 0.5)));
  p.Process(p.newest_utime());
  p.FinishRepose();
  EXPECT_EQ(p.counters().rebuilds_started, 0);
  EXPECT_TRUE(Occupied(p.builder().tree(), 3.01));
}

}  // namespace
}  // namespace omni::octo
