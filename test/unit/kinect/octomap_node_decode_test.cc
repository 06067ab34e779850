// The OctoMap builder's bus path takes DELTA_ZLIB depth from the Kinect codec: a message filled
// by FillDepthMessage comes out of FromDepthMessage pixel-exact, and a damaged one is an error.
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "omni/bus/convert.h"
#include "omni/common/geometry.h"
#include "omni/kinect/depth_message.h"
#include "omni/octomap_builder/octomap_node.h"
#include "omni/octomap_builder/repose.h"

namespace omni::kinect {
namespace {

TEST(DepthMessage, OctomapBuilderDecodesDeltaZlibMessages) {
  const int w = 80, h = 60;
  std::vector<uint16_t> px(static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      px[static_cast<size_t>(y) * w + x] = static_cast<uint16_t>(x == y ? 0 : 2000 + x - y);
  omni::depth_image_t msg{};
  msg.utime = 1;
  msg.frame = "depth_optical";
  msg.fx = 518.0;
  msg.fy = 519.0;
  msg.cx = 39.5;
  msg.cy = 29.5;
  msg.depth_scale = 1000;
  ASSERT_TRUE(FillDepthMessage(px.data(), w, h, DepthEncoding::kDeltaZlib, {}, &msg).ok());
  auto im = octo::FromDepthMessage(msg);
  ASSERT_TRUE(im.ok()) << im.error().message;
  EXPECT_EQ(im->width, w);
  EXPECT_EQ(im->height, h);
  EXPECT_EQ(im->data, px);
  msg.data[msg.data.size() / 2] ^= 0x10;
  EXPECT_FALSE(octo::FromDepthMessage(msg).ok());
}

// Found by fuzzing (test/fuzz/bus_messages_fuzz.cc): intrinsics that are finite but absurd (a
// principal point at 1e306 px, a depth scale of 1e-306) made every point infinite; a trajectory
// with a NaN pose was accepted for re-posing.
TEST(DepthMessage, AbsurdIntrinsicsAndNonFiniteTrajectoriesAreRefused) {
  std::vector<uint16_t> px(4 * 3, 1500);
  omni::depth_image_t msg{};
  msg.fx = msg.fy = 5.0;
  msg.cx = 1.5;
  msg.cy = 1.0;
  msg.depth_scale = 1000;
  ASSERT_TRUE(FillDepthMessage(px.data(), 4, 3, DepthEncoding::kRaw, {}, &msg).ok());
  ASSERT_TRUE(octo::FromDepthMessage(msg).ok());
  for (auto damage : std::vector<void (*)(omni::depth_image_t*)>{
           [](omni::depth_image_t* m) { m->cx = -1.36e306; },
           [](omni::depth_image_t* m) { m->depth_scale = 5.6e-306; },
           [](omni::depth_image_t* m) { m->fx = 1e-300; },
           [](omni::depth_image_t* m) { m->fy = 1e9; }}) {
    omni::depth_image_t bad = msg;
    damage(&bad);
    EXPECT_FALSE(octo::FromDepthMessage(bad).ok());
  }
  omni::trajectory_t traj{};
  traj.num_poses = 2;
  traj.pose_utime = {1, 2};
  traj.x_m = {0.0, 1.0};
  traj.y_m = {0.0, 0.0};
  traj.yaw_rad = {0.0, 0.0};
  ASSERT_TRUE(octo::FromTrajectoryMessage(traj, "map").ok());
  traj.y_m[1] = std::nan("");
  auto poses = octo::FromTrajectoryMessage(traj, "map");
  ASSERT_FALSE(poses.ok());
  EXPECT_NE(poses.error().message.find("pose 1 is not finite"), std::string::npos);
  traj.y_m[1] = 0.0;
  traj.x_m[0] = -2e6;  // finite, but 2000 km from the map's origin
  poses = octo::FromTrajectoryMessage(traj, "map");
  ASSERT_FALSE(poses.ok());
  EXPECT_NE(poses.error().message.find("pose 0 is not finite or beyond 1000 km"), std::string::npos)
      << poses.error().message;
}

// A mapper's thinned TRAJECTORY_* message, decoded and looked up as the OctoMap builder re-poses
// its keyframes: every pose of the full path comes back within the thinning's tolerances, also
// where the heading crosses +-pi.
TEST(OctomapNodeDecode, ThinnedTrajectoriesComeBackThroughTheBuildersLookup) {
  struct Stamped {
    int64_t utime;
    Pose2 pose;
  };
  std::vector<Stamped> path;
  int64_t t = 1700000000000000;
  for (int i = 0; i < 300; ++i, t += 100000) {  // 30 s at 10 Hz: a straight run, then an arc
    const double a = i < 100 ? 0 : 0.015 * (i - 100);
    path.push_back({t, Pose2(i < 100 ? 0.04 * i : 4 + std::sin(a), i < 100 ? 0 : 1 - std::cos(a),
                             WrapAngle(3.0 + a))});
  }
  const bus::TrajectoryThinning th;
  const omni::trajectory_t m = bus::ToTrajectoryMessage(path, "map", "rbpf");
  EXPECT_LT(m.num_poses, static_cast<int32_t>(path.size()) / 3);
  auto poses = octo::FromTrajectoryMessage(m, "map");
  ASSERT_TRUE(poses.ok()) << poses.error().message;
  const octo::TrajectoryLookup lookup(std::move(*poses));
  for (const Stamped& s : path) {
    Pose2 p;
    ASSERT_TRUE(lookup.At(s.utime, 2000000, &p)) << s.utime;  // the poser's default 2 s gap
    EXPECT_LE(std::hypot(p.x - s.pose.x, p.y - s.pose.y), th.tolerance_m) << s.utime;
    EXPECT_LE(std::abs(WrapAngle(p.theta - s.pose.theta)), th.tolerance_rad) << s.utime;
  }
}

}  // namespace
}  // namespace omni::kinect
