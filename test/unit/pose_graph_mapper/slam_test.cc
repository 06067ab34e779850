// PoseGraphSlam on synthetic scans of a box room: keyframe gating on the odometry motion, a pose
// for every accepted scan (keyframe estimate composed with the odometry since it), and bad input
// rejected and counted.
#include <cmath>
#include <limits>
#include <memory>
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
  o = PoseGraphSlamOptions();
  o.loop_chi2_gate = -1;
  EXPECT_FALSE(o.Validate().ok());
  o = PoseGraphSlamOptions();
  o.global_function_tolerance = 0;
  EXPECT_FALSE(o.Validate().ok());
}

// Back and forth three times along the box room: loops close on the second and third pass. A
// chi^2 gate no residual can pass removes every loop from the graph and counts it; without the
// gate none is removed.
TEST(PoseGraphSlam, Chi2GateRemovesAndCountsLoops) {
  auto run = [](double gate) {
    PoseGraphSlamOptions o;
    o.window_size = 5;
    o.loop.min_index_gap = 10;
    o.loop.max_ambiguity_ratio = 0;  // the bare room looks alike along its length
    o.loop_every_keyframes = 1;
    o.loop_cooldown_keyframes = 0;
    o.global_min_keyframes_between = 0;
    o.loop_chi2_gate = gate;
    auto slam = std::make_unique<PoseGraphSlam>(o, BatchOptions{}, nullptr);
    int i = 0;
    for (int pass = 0; pass < 3; ++pass)
      for (int s = 0; s <= 60; ++s, ++i) {
        const double x = pass % 2 == 0 ? 2 + 0.1 * s : 8 - 0.1 * s;
        const Pose2 p(x, 3 + 0.01 * std::sin(0.2 * i), 0.005 * std::sin(0.1 * i));
        const int64_t t = 1000000 + 100000 * i;
        slam->AddOdometry(t, p);
        slam->AddScan(i, BoxScan(t, p));
      }
    slam->Finish();
    return slam;
  };
  const auto open = run(0);
  EXPECT_GT(open->counters().loops_accepted, 0);
  EXPECT_EQ(open->counters().loops_inconsistent, 0);
  const auto gated = run(1e-12);
  const SlamCounters& c = gated->counters();
  EXPECT_GT(c.loops_inconsistent, 0);
  EXPECT_EQ(c.loops_accepted, 0);
  // Only the odometry and scan-match links between consecutive keyframes remain.
  EXPECT_LE(gated->Graph().edges2.size(), static_cast<size_t>(2 * (c.keyframes - 1)));
  EXPECT_GT(open->Graph().edges2.size(), static_cast<size_t>(2 * (open->counters().keyframes - 1)));
}

}  // namespace
}  // namespace omni::pgm
