#include <cstdint>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "omni/octomap_builder/frame_poser.h"

namespace omni::octo {
namespace {

FramePoserOptions Opts() {
  FramePoserOptions o;
  o.max_latency_us = 100000;    // 0.1 s
  o.max_pose_gap_us = 1000000;  // 1 s
  o.max_queued_frames = 5;
  return o;
}

TEST(FramePoser, InterpolatesBetweenPoses) {
  FramePoser<int> p(Opts());
  ASSERT_TRUE(p.AddPose(1000000, Pose2(0, 0, 0.1)));
  ASSERT_TRUE(p.AddPose(1500000, Pose2(1, 2, 0.3)));
  ASSERT_TRUE(p.AddFrame(1125000, 7));  // a quarter of the way
  const auto out = p.Poll(1500000);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].frame, 7);
  EXPECT_NEAR(out[0].robot_in_map.x, 0.25, 1e-12);
  EXPECT_NEAR(out[0].robot_in_map.y, 0.5, 1e-12);
  EXPECT_NEAR(out[0].robot_in_map.theta, 0.15, 1e-12);
  EXPECT_EQ(p.counters().frames_posed, 1);
}

TEST(FramePoser, InterpolatesHeadingAcrossPi) {
  FramePoser<int> p(Opts());
  ASSERT_TRUE(p.AddPose(0, Pose2(0, 0, 3.0)));
  ASSERT_TRUE(p.AddPose(100, Pose2(0, 0, -3.0)));  // +0.283 rad the short way
  ASSERT_TRUE(p.AddFrame(50, 1));
  const auto out = p.Poll(100);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_NEAR(std::abs(out[0].robot_in_map.theta), M_PI, 1e-9);
}

TEST(FramePoser, WaitsForANewerPoseWithinTheLatency) {
  FramePoser<int> p(Opts());
  ASSERT_TRUE(p.AddPose(1000000, Pose2(0, 0, 0)));
  ASSERT_TRUE(p.AddFrame(1050000, 1));
  // No pose after the frame yet and the latency has not expired: it waits.
  EXPECT_TRUE(p.Poll(1100000).empty());
  EXPECT_EQ(p.queued(), 1u);
  // The pose arrives late but within the latency: the frame is posed by interpolation.
  ASSERT_TRUE(p.AddPose(1100000, Pose2(1, 0, 0)));
  const auto out = p.Poll(1120000);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_NEAR(out[0].robot_in_map.x, 0.5, 1e-12);
}

TEST(FramePoser, DropsWhenTheLatencyExpires) {
  FramePoser<int> p(Opts());
  ASSERT_TRUE(p.AddPose(1000000, Pose2(0, 0, 0)));
  ASSERT_TRUE(p.AddFrame(1050000, 1));
  ASSERT_TRUE(p.AddFrame(1300000, 2));
  // now = 1.2 s: frame 1 waited 0.15 s > 0.1 s and is dropped; frame 2 still waits.
  EXPECT_TRUE(p.Poll(1200000).empty());
  EXPECT_EQ(p.counters().frames_dropped_no_pose, 1);
  EXPECT_EQ(p.queued(), 1u);
  // Frames never extrapolate: a pose at exactly the frame's time poses it.
  ASSERT_TRUE(p.AddPose(1300000, Pose2(2, 0, 0)));
  const auto out = p.Poll(1300000);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].frame, 2);
  EXPECT_NEAR(out[0].robot_in_map.x, 2.0, 1e-12);
}

TEST(FramePoser, DropsFramesOlderThanThePosesOrAcrossAGap) {
  FramePoser<int> p(Opts());
  ASSERT_TRUE(p.AddPose(1000000, Pose2(0, 0, 0)));
  ASSERT_TRUE(p.AddPose(3000000, Pose2(1, 0, 0)));  // a 2 s gap > 1 s
  ASSERT_TRUE(p.AddFrame(900000, 1));               // before the first pose
  ASSERT_TRUE(p.AddFrame(2000000, 2));              // inside the gap
  EXPECT_TRUE(p.Poll(3000000).empty());
  EXPECT_EQ(p.counters().frames_dropped_no_pose, 2);
  EXPECT_EQ(p.counters().frames_posed, 0);
}

TEST(FramePoser, CountsOutOfOrderAndQueueOverflow) {
  FramePoser<int> p(Opts());
  ASSERT_TRUE(p.AddPose(2000, Pose2()));
  EXPECT_FALSE(p.AddPose(1000, Pose2()));
  EXPECT_EQ(p.counters().poses_out_of_order, 1);
  ASSERT_TRUE(p.AddFrame(5000, 1));
  EXPECT_FALSE(p.AddFrame(4000, 2));
  EXPECT_EQ(p.counters().frames_out_of_order, 1);
  for (int i = 0; i < 6; ++i) ASSERT_TRUE(p.AddFrame(6000 + i, 10 + i));
  EXPECT_EQ(p.queued(), 5u);
  EXPECT_EQ(p.counters().frames_dropped_queue, 2);
  EXPECT_EQ(p.counters().frames_in, 8);
}

// One pose and one frame stamped an hour ahead: the five in-order messages after each prove
// it, the stream goes on from them, and the future frame no longer holds the queue.
TEST(FramePoser, RecoversFromAPoseAndAFrameStampedInTheFuture) {
  FramePoser<int> p(Opts());
  constexpr int64_t kHour = 3600000000LL;
  ASSERT_TRUE(p.AddPose(1000000, Pose2(0, 0, 0)));
  ASSERT_TRUE(p.AddPose(1000000 + kHour, Pose2(9, 9, 0)));
  for (int i = 1; i <= 5; ++i) p.AddPose(1000000 + 100000 * i, Pose2(0.1 * i, 0, 0));
  EXPECT_EQ(p.counters().time_rebases, 1);
  EXPECT_EQ(p.counters().poses_out_of_order, 4);  // held, then taken by the re-base
  EXPECT_EQ(p.newest_pose_utime(), 1500000);
  auto pose = p.PoseAt(1250000);
  ASSERT_TRUE(pose);
  EXPECT_NEAR(pose->x, 0.25, 1e-12);

  ASSERT_TRUE(p.AddFrame(1100000 + kHour, 1));  // waits for a pose that never comes
  for (int i = 0; i < 4; ++i) EXPECT_FALSE(p.AddFrame(1100000 + 50000 * i, 10 + i));
  ASSERT_TRUE(p.AddFrame(1300000, 20));  // the fifth: the future frame is dropped
  EXPECT_EQ(p.counters().time_rebases, 2);
  EXPECT_EQ(p.counters().frames_dropped_future, 1);
  const auto out = p.Poll(1500000);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].frame, 20);
  EXPECT_NEAR(out[0].robot_in_map.x, 0.3, 1e-12);
}

TEST(CameraMount, OpticalAxesOnTheBase) {
  CameraMount m;
  m.x_m = 0.1;
  m.height_m = 0.5;
  const Eigen::Isometry3d t = MountToIsometry(m);
  // Optical z (forward) is the base's x; optical x (right) is -y; optical y (down) is -z.
  EXPECT_TRUE((t.linear() * Eigen::Vector3d::UnitZ()).isApprox(Eigen::Vector3d::UnitX()));
  EXPECT_TRUE((t.linear() * Eigen::Vector3d::UnitX()).isApprox(-Eigen::Vector3d::UnitY()));
  EXPECT_TRUE((t.linear() * Eigen::Vector3d::UnitY()).isApprox(-Eigen::Vector3d::UnitZ()));
  EXPECT_TRUE(t.translation().isApprox(Eigen::Vector3d(0.1, 0, 0.5)));
  // Tilted down by 30 degrees: a point 1 m ahead on the optical axis is 0.5 m lower.
  m.tilt_rad = M_PI / 6;
  const Eigen::Vector3d p = MountToIsometry(m) * Eigen::Vector3d(0, 0, 1);
  EXPECT_NEAR(p.x(), 0.1 + std::cos(M_PI / 6), 1e-12);
  EXPECT_NEAR(p.z(), 0.5 - 0.5, 1e-12);
  // On a robot at (1, 2) facing +y, with the camera yawed left by 90 degrees: looking along -x.
  m.tilt_rad = 0;
  m.yaw_rad = M_PI / 2;
  const Eigen::Vector3d q = CameraInMap(Pose2(1, 2, M_PI / 2), m) * Eigen::Vector3d(0, 0, 1);
  EXPECT_NEAR(q.x(), 1 - 1, 1e-12);
  EXPECT_NEAR(q.y(), 2 + 0.1 - 0, 1e-9);
  // Robot heading +y, camera x offset 0.1 along +y, then yaw +90: optical axis along -x.
  const Eigen::Vector3d axis =
      CameraInMap(Pose2(1, 2, M_PI / 2), m).linear() * Eigen::Vector3d::UnitZ();
  EXPECT_TRUE(axis.isApprox(-Eigen::Vector3d::UnitX(), 1e-12));
}

}  // namespace
}  // namespace omni::octo

namespace omni::octo {
namespace {

// A recorded trajectory fed to the poser as the frames come (omni octomap build --poses), with
// the frames three times as fast as the poses for longer than the poser keeps poses (2000):
// the poses handed over stay at most one ahead of the frames, so every frame is posed.
TEST(PoseFeed, FramesFasterThanPosesStayPosedPastThePoseBuffer) {
  FramePoserOptions o;
  o.max_latency_us = 2000000;
  o.max_pose_gap_us = 2000000;
  ASSERT_LT(o.pose_capacity, 2500u);
  FramePoser<int64_t> poser(o);
  std::vector<std::pair<int64_t, Pose2>> poses;
  const int64_t t0 = 1000000;
  for (int i = 0; i < 2500; ++i) poses.emplace_back(t0 + 100000LL * i, Pose2(0.01 * i, 0, 0));
  PoseFeed feed(poses);
  int64_t frames = 0, posed = 0;
  for (int64_t t = t0 - 50000; t < poses.back().first; t += 33333) {
    feed.FeedFor(t, [&](int64_t u, const Pose2& p) { poser.AddPose(u, p); });
    ASSERT_GE(feed.fed(), 1u);
    ASSERT_GE(poses[feed.fed() - 1].first, t);  // the newest handed over is at or after t ...
    if (feed.fed() >= 2) {
      ASSERT_LT(poses[feed.fed() - 2].first, t);  // ... and the first such
    }
    poser.AddFrame(t, t);
    ++frames;
    for (const auto& out : poser.Poll(t)) {
      ++posed;
      EXPECT_NEAR(out.robot_in_map.x, 0.01 * static_cast<double>(out.frame - t0) / 100000.0, 1e-9);
    }
  }
  EXPECT_EQ(posed, frames - 2);  // the two frames before the first pose cannot be posed
  EXPECT_EQ(poser.counters().frames_dropped_no_pose, 2);
  EXPECT_LE(feed.FeedRest([&](int64_t u, const Pose2& p) { poser.AddPose(u, p); }), 1u);
  EXPECT_EQ(feed.fed(), poses.size());
}

}  // namespace
}  // namespace omni::octo
