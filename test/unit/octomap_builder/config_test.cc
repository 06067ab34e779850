#include <gtest/gtest.h>

#include "omni/octomap_builder/octomap_builder.h"

namespace omni::octo {
namespace {

TEST(OctomapBuilderConfig, ShippedFileLoads) {
  auto o = OctomapBuilderOptions::LoadFile(std::string(OMNI_SOURCE_DIR) +
                                           "/config/octomap_builder.yaml");
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(o->PoseChannel(), "POSE_RBPF");
  EXPECT_DOUBLE_EQ(o->resolution_m, 0.05);
  EXPECT_FALSE(o->discretize);
  EXPECT_EQ(o->subvoxel, 2);
  EXPECT_EQ(o->poser.max_latency_us, 2000000);
  EXPECT_GT(o->mount.height_m, 0.0);
  EXPECT_LT(o->grid.min_z_m, o->grid.max_z_m);
  EXPECT_TRUE(o->repose.enabled);
  EXPECT_EQ(o->TrajectoryChannel(), "TRAJECTORY_RBPF");
  EXPECT_DOUBLE_EQ(o->repose.rebuild_budget_ms, 20);
}

constexpr const char* kMinimal = R"(
pose_source: pg
tree: {resolution_m: 0.1, max_range_m: 4.0}
depth: {min_depth_m: 0.3, max_depth_m: 5.0}
camera_mount: {height_m: 0.4}
poses: {max_latency_s: 0.2}
grid: {min_z_m: 0.1, max_z_m: 1.5}
)";

TEST(OctomapBuilderConfig, MinimalFileAndDerivedChannel) {
  auto r = ConfigReader::FromString(kMinimal, "minimal.yaml");
  ASSERT_TRUE(r.ok());
  auto o = OctomapBuilderOptions::Load(*r);
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_EQ(o->PoseChannel(), "POSE_PG");
  EXPECT_EQ(o->poser.max_latency_us, 200000);
  // Keys left out take the built-in defaults.
  const FramePoserOptions defaults;
  EXPECT_EQ(o->poser.max_queued_frames, defaults.max_queued_frames);
  EXPECT_EQ(o->poser.max_pose_gap_us, defaults.max_pose_gap_us);
  EXPECT_FALSE(o->repose.enabled);  // off unless asked for
  EXPECT_EQ(o->TrajectoryChannel(), "TRAJECTORY_PG");
}

TEST(OctomapBuilderConfig, ReposeKeysAreCheckedAndNamed) {
  auto r = ConfigReader::FromString(std::string(kMinimal) +
                                        "repose: {enabled: true, trajectory_channel: T2, "
                                        "min_shift_m: 0.2, max_points: 5000}\n",
                                    "repose.yaml");
  ASSERT_TRUE(r.ok());
  auto o = OctomapBuilderOptions::Load(*r);
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_TRUE(o->repose.enabled);
  EXPECT_EQ(o->TrajectoryChannel(), "T2");
  EXPECT_DOUBLE_EQ(o->repose.min_shift_m, 0.2);
  EXPECT_EQ(o->repose.max_points, 5000);
  r = ConfigReader::FromString(std::string(kMinimal) +
                                   "repose: {enabled: true, keyframe_distance: 0.2, "
                                   "rebuild_budget_ms: 0}\n",
                               "repose_bad.yaml");
  ASSERT_TRUE(r.ok());
  o = OctomapBuilderOptions::Load(*r);
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("repose.keyframe_distance"), std::string::npos)
      << o.error().message;
  EXPECT_NE(o.error().message.find("repose.rebuild_budget_ms"), std::string::npos)
      << o.error().message;
}

TEST(OctomapBuilderConfig, UnknownKeysAndBadValuesAreNamed) {
  auto r = ConfigReader::FromString(std::string(kMinimal) + "tree_resolution: 0.1\n", "typo.yaml");
  ASSERT_TRUE(r.ok());
  auto o = OctomapBuilderOptions::Load(*r);
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("tree_resolution"), std::string::npos) << o.error().message;

  std::string bad = kMinimal;
  bad.replace(bad.find("min_z_m: 0.1"), 12, "min_z_m: 2.0");
  bad.replace(bad.find("pose_source: pg"), 15, "pose_source: gps");
  r = ConfigReader::FromString(bad, "bad.yaml");
  ASSERT_TRUE(r.ok());
  o = OctomapBuilderOptions::Load(*r);
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("grid.min_z_m"), std::string::npos) << o.error().message;
  EXPECT_NE(o.error().message.find("pose_source"), std::string::npos) << o.error().message;
}

}  // namespace
}  // namespace omni::octo
