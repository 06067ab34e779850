// PoseGraphSlam on synthetic scans of a box room: keyframe gating on the odometry motion, a pose
// for every accepted scan (keyframe estimate composed with the odometry since it), and bad input
// rejected and counted.
#include <cmath>
#include <limits>
#include <vector>

#include <gtest/gtest.h>

#include "omni/pose_graph_mapper/pose_graph_slam.h"

namespace omni::pgm {
namespace {

// Scan of the walls of [0, 10] x [0, 6] from `p` (laser at the base), 360 beams over 360 deg.
LaserScan2 BoxScan(int64_t utime, const Pose2& p) {
  LaserScan2 s;
  s.utime = utime;
  s.angle_min_rad = static_cast<float>(-M_PI);
  s.angle_increment_rad = static_cast<float>(2 * M_PI / 360);
  s.max_range_m = 30;
  for (int i = 0; i < 360; ++i) {
    const double a = p.theta + s.angle_min_rad + i * s.angle_increment_rad;
    const double c = std::cos(a), sn = std::sin(a);
    double t = 1e9;
    if (c > 1e-9) t = std::min(t, (10 - p.x) / c);
    if (c < -1e-9) t = std::min(t, -p.x / c);
    if (sn > 1e-9) t = std::min(t, (6 - p.y) / sn);
    if (sn < -1e-9) t = std::min(t, -p.y / sn);
    s.ranges_m.push_back(static_cast<float>(t));
  }
  return s;
}

TEST(PoseGraphSlam, KeyframeGatingAndPosePerScan) {
  PoseGraphSlamOptions o;
  o.keyframe_distance_m = 0.5;
  PoseGraphSlam slam(o, BatchOptions{}, nullptr);
  std::vector<Pose2> truth;
  for (int i = 0; i <= 40; ++i) {
    const Pose2 p(2 + 0.1 * i, 3 + 0.02 * std::sin(0.3 * i), 0.01 * i);
    truth.push_back(p);
    const int64_t t = 1000000 + 100000 * i;
    slam.AddOdometry(t, p);
    EXPECT_TRUE(slam.AddScan(i, BoxScan(t, p))) << i;
  }
  const auto& c = slam.counters();
  EXPECT_EQ(c.scans_used, 41);
  // 4 m at >= 0.5 m per keyframe: a keyframe every 5 or 6 scans.
  EXPECT_GE(c.keyframes, 7);
  EXPECT_LE(c.keyframes, 9);
  EXPECT_EQ(c.scan_match_failures, 0);
  const auto traj = slam.Trajectory();
  ASSERT_EQ(traj.size(), 41u);
  for (size_t i = 0; i < traj.size(); ++i) {
    // The map frame is the first pose's.
    const Pose2 expected = truth[0].Between(truth[i]);
    EXPECT_EQ(traj[i].scan_index, static_cast<int64_t>(i));
    EXPECT_NEAR(traj[i].pose.x, expected.x, 0.03) << i;
    EXPECT_NEAR(traj[i].pose.y, expected.y, 0.03) << i;
    EXPECT_NEAR(traj[i].pose.theta, expected.theta, 0.01) << i;
  }
  EXPECT_EQ(slam.Graph().vertices2.size(), static_cast<size_t>(c.keyframes));
}

TEST(PoseGraphSlam, BadInputIsCounted) {
  PoseGraphSlam slam(PoseGraphSlamOptions{}, BatchOptions{}, nullptr);
  const Pose2 p(2, 3, 0);
  EXPECT_FALSE(slam.AddScan(0, BoxScan(1000000, p)));  // no odometry yet
  slam.AddOdometry(1000000, p);
  slam.AddOdometry(900000, p);  // out of order
  slam.AddOdometry(1100000, Pose2(std::numeric_limits<double>::quiet_NaN(), 0, 0));
  EXPECT_TRUE(slam.AddScan(1, BoxScan(1000000, p)));
  LaserScan2 nan_scan = BoxScan(1050000, p);
  for (auto& r : nan_scan.ranges_m) r = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(slam.AddScan(2, nan_scan));
  EXPECT_FALSE(slam.AddScan(3, BoxScan(900000, p)));  // time backwards
  slam.AddOdometry(1200000, Pose2(20, 3, 0));         // a 18 m jump
  EXPECT_TRUE(slam.AddScan(4, BoxScan(1200000, p)));
  const auto& c = slam.counters();
  EXPECT_EQ(c.scans_no_odom, 1);
  EXPECT_EQ(c.odom_out_of_order, 1);
  EXPECT_EQ(c.odom_invalid, 1);
  EXPECT_EQ(c.scans_too_few_beams, 1);
  EXPECT_EQ(c.scans_time_backwards, 1);
  EXPECT_EQ(c.odom_jumps, 1);
  EXPECT_EQ(c.keyframes, 1);  // the jump was bridged as no motion
  EXPECT_EQ(slam.Trajectory().size(), 2u);
}

TEST(PoseGraphSlam, OptionsAreChecked) {
  PoseGraphSlamOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.loop.min_index_gap = 10;  // inside the window
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace omni::pgm
