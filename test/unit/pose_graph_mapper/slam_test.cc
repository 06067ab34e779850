// PoseGraphSlam on synthetic scans of a box room: keyframe gating on the odometry motion, a pose
// for every accepted scan (keyframe estimate composed with the odometry since it), and bad input
// rejected and counted. Absolute poses: attached at a node's time, spliced in between two
// keyframes without changing the odometry's information, queued when newer than the newest
// pose, rejected when older than the window.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/LU>

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

// Returns below min_range (a mast 0.10 m from an RPLidar whose range_min is 0.15 m) are left
// out of matching and were painted as walls along the whole path in map.pgm; a scan whose
// max_range is 0 (no limit, as matching reads it) gave an empty map (review findings).
TEST(PoseGraphSlam, TheMapLeavesOutWhatMatchingLeftOut) {
  for (const float max_range : {30.f, 0.f}) {
    SCOPED_TRACE(max_range);
    PoseGraphSlamOptions o;
    o.keyframe_distance_m = 0.5;
    PoseGraphSlam slam(o, BatchOptions{}, nullptr);
    for (int i = 0; i <= 40; ++i) {
      const Pose2 p(2 + 0.1 * i, 3, 0);
      const int64_t t = 1000000 + 100000 * i;
      slam.AddOdometry(t, p);
      LaserScan2 scan = BoxScan(t, p);
      scan.min_range_m = 0.15f;
      scan.max_range_m = max_range;
      for (int b = 100; b < 110; ++b) scan.ranges_m[b] = 0.10f;  // the mast
      ASSERT_TRUE(slam.AddScan(i, scan)) << i;
    }
    io::LogOddsOptions lo;
    lo.resolution_m = 0.05;
    const io::GridMap m = slam.RenderMap(lo);
    int walls = 0, near_path = 0;
    for (int y = 0; y < m.height; ++y)
      for (int x = 0; x < m.width; ++x) {
        if (m.at(x, y) <= 50) continue;
        ++walls;
        // The map frame is the first pose's: the path runs along y = 0 from x = 0 to 4.
        const double cx = m.origin_x_m + (x + 0.5) * lo.resolution_m;
        const double cy = m.origin_y_m + (y + 0.5) * lo.resolution_m;
        if (cx > -0.3 && cx < 4.3 && std::abs(cy) < 0.3) ++near_path;
      }
    EXPECT_GT(walls, 300);  // the room's 32 m of walls at 5 cm
    EXPECT_EQ(near_path, 0);
  }
}

// The stamp tests below: odometry at 50 Hz, a keyframe every 0.2 m, a glitch an hour off.
constexpr int64_t kHour = 3600000000LL;
int64_t At50Hz(int i) { return 1000000 + int64_t{20000} * i; }
std::unique_ptr<PoseGraphSlam> FineKeyframeSlam(bool use_gyro = false) {
  PoseGraphSlamOptions o;
  o.keyframe_distance_m = 0.2;
  o.use_gyro = use_gyro;
  return std::make_unique<PoseGraphSlam>(o, BatchOptions{}, nullptr);
}

// Scan i of a drive back and forth along the box room's length at y ~ 3, 61 scans a pass
// (0.1 m apart, x from 2 to 8 and back), heading near 0.
Pose2 BackAndForth(int i) {
  const int s = i % 61, pass = i / 61;
  const double x = pass % 2 == 0 ? 2 + 0.1 * s : 8 - 0.1 * s;
  return Pose2(x, 3 + 0.01 * std::sin(0.2 * i), 0.005 * std::sin(0.1 * i));
}

// A small window and loops tried on every keyframe a few keyframes back, with a global
// optimisation as soon as one is accepted: BackAndForth's passes close loops within seconds.
PoseGraphSlamOptions LoopingOptions() {
  PoseGraphSlamOptions o;
  o.window_size = 5;
  o.loop.min_index_gap = 10;
  o.loop.max_ambiguity_ratio = 0;  // the bare room looks alike along its length
  o.loop_every_keyframes = 1;
  o.global_min_keyframes_between = 0;
  return o;
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

// Odometry and then a scan stamped an hour ahead (a clock glitch), with in-order odometry in
// between: the scan gets no odometry from the doubtful sample (else it would become a keyframe
// every later scan is older than), the odometry re-bases after five samples, mapping goes on.
TEST(PoseGraphSlam, AFutureOdometrySampleMakesNoFutureKeyframe) {
  auto at = [](int i) { return Pose2(2 + 0.05 * i, 3, 0); };
  const auto t = At50Hz;
  auto run = [&](bool glitch, int* used) {
    auto slam = FineKeyframeSlam();
    *used = 0;
    for (int i = 0; i <= 80; ++i) {
      slam->AddOdometry(t(i), at(i));
      if (glitch && i == 40) slam->AddOdometry(t(i) + kHour, Pose2(500, -80, 2.5));  // and corrupt
      if (glitch && i == 42) {
        EXPECT_FALSE(slam->AddScan(1000, BoxScan(t(i) + kHour, at(i))));
      }
      if (i % 5 == 0) *used += slam->AddScan(i, BoxScan(t(i), at(i))) ? 1 : 0;
    }
    return slam;
  };
  int used_clean = 0, used = 0;
  const auto clean = run(false, &used_clean);
  const auto slam = run(true, &used);
  const auto& c = slam->counters();
  EXPECT_EQ(c.time_rebases, 1);
  EXPECT_EQ(c.clock_steps_back, 0);
  EXPECT_EQ(c.odom_out_of_order, 4);
  EXPECT_EQ(used, 17);  // every in-order scan
  EXPECT_EQ(used_clean, 17);
  EXPECT_EQ(c.scans_no_odom, 1);
  EXPECT_EQ(c.odom_jumps, 1);  // the corrupt sample's; its bridge went with it
  const auto traj = slam->Trajectory(), traj_clean = clean->Trajectory();
  ASSERT_FALSE(traj.empty());
  EXPECT_EQ(traj.back().utime, t(80));
  EXPECT_NEAR(traj.back().pose.x, traj_clean.back().pose.x, 0.01);
  EXPECT_NEAR(traj.back().pose.y, traj_clean.back().pose.y, 0.01);
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
  // Retiring must wait until the keyframe has left the keyframe matcher's submap.
  o = PoseGraphSlamOptions();
  o.retire.delay_keyframes = o.match.submap_keyframes;
  EXPECT_FALSE(o.Validate().ok());
  o.retire.enabled = false;
  EXPECT_TRUE(o.Validate().ok());
}

// Back and forth three times along the box room: loops close on the second and third pass. A
// chi^2 gate no residual can pass removes every loop from the graph and counts it; without the
// gate none is removed.
// A global optimisation in the background (the default) is taken in when the next keyframe
// comes: until then the scans are accepted and posed on the estimates before it, and nothing is
// counted. The final graph and trajectory are those of solving in line, where the mapper's thread
// waits for every solve.
TEST(PoseGraphSlam, GlobalSolveInTheBackgroundIsTakenInAtTheNextKeyframe) {
  auto run = [](bool background, int* scans_in_flight) {
    PoseGraphSlamOptions o = LoopingOptions();
    o.global_in_background = background;
    o.retire.delay_keyframes = 5;  // retiring and removal take part too
    auto slam = std::make_unique<PoseGraphSlam>(o, BatchOptions{}, nullptr);
    *scans_in_flight = 0;
    for (int i = 0; i < 3 * 61; ++i) {
      const Pose2 p = BackAndForth(i);
      const int64_t t = 1000000 + 100000 * i;
      slam->AddOdometry(t, p);
      const size_t keyframes = slam->keyframes().size();
      const bool was_in_flight = slam->global_in_flight();
      const int64_t solves = slam->counters().global_optimizations;
      EXPECT_TRUE(slam->AddScan(i, BoxScan(t, p))) << i;
      ScanPose last;
      EXPECT_TRUE(slam->LastScanPose(&last));
      EXPECT_EQ(last.scan_index, i);
      if (was_in_flight && slam->keyframes().size() == keyframes) {
        // A scan between keyframes while the solve runs: it waits for nothing.
        ++*scans_in_flight;
        EXPECT_TRUE(slam->global_in_flight());
        EXPECT_EQ(slam->counters().global_optimizations, solves);
      }
      if (was_in_flight && slam->keyframes().size() > keyframes) {
        EXPECT_GT(slam->counters().global_optimizations, solves);  // taken in
      }
      if (!background) {
        EXPECT_FALSE(slam->global_in_flight());
      }
    }
    slam->Finish();
    EXPECT_FALSE(slam->global_in_flight());
    return slam;
  };
  int in_flight = 0, in_line = 0;
  const auto bg = run(true, &in_flight);
  const auto inline_ = run(false, &in_line);
  EXPECT_GT(in_flight, 10);
  EXPECT_EQ(in_line, 0);
  const SlamCounters &a = bg->counters(), &b = inline_->counters();
  EXPECT_GT(b.loops_accepted, 0);
  EXPECT_GT(b.global_optimizations, 5);
  EXPECT_GT(b.keyframes_retired, 0);
  EXPECT_EQ(a.global_optimizations, b.global_optimizations);
  EXPECT_EQ(a.loops_accepted, b.loops_accepted);
  EXPECT_EQ(a.keyframes_retired, b.keyframes_retired);
  EXPECT_EQ(a.keyframes_removed, b.keyframes_removed);
  EXPECT_EQ(bg->Graph().edges2.size(), inline_->Graph().edges2.size());
  const auto ta = bg->Trajectory(), tb = inline_->Trajectory();
  ASSERT_EQ(ta.size(), tb.size());
  for (size_t i = 0; i < ta.size(); ++i) {
    EXPECT_NEAR(ta[i].pose.x, tb[i].pose.x, 1e-9) << i;
    EXPECT_NEAR(ta[i].pose.y, tb[i].pose.y, 1e-9) << i;
    EXPECT_NEAR(ta[i].pose.theta, tb[i].pose.theta, 1e-9) << i;
  }
}

TEST(PoseGraphSlam, Chi2GateRemovesAndCountsLoops) {
  auto run = [](double gate) {
    PoseGraphSlamOptions o = LoopingOptions();
    o.loop_cooldown_keyframes = 0;
    o.loop_chi2_gate = gate;
    o.retire.delay_keyframes = 5;  // three short passes: decide early enough to retire some
    auto slam = std::make_unique<PoseGraphSlam>(o, BatchOptions{}, nullptr);
    for (int i = 0; i < 3 * 61; ++i) {
      const Pose2 p = BackAndForth(i);
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
  // Removed loops vouch for no keyframe: nothing is retired, where the open run retires some.
  EXPECT_GT(open->counters().keyframes_retired, 0);
  EXPECT_EQ(c.keyframes_retired, 0);
  // Only the odometry and scan-match links between consecutive keyframes remain.
  EXPECT_LE(gated->Graph().edges2.size(), static_cast<size_t>(2 * (c.keyframes - 1)));
  EXPECT_GT(open->Graph().edges2.size(), static_cast<size_t>(2 * (open->counters().keyframes - 1)));
}
// The odometry's and the lidar's clock set back an hour at sample 40 (an NTP step): the scan
// that comes with the new clock before five samples prove the step is held and replayed, every
// scan is mapped, and the trajectory keeps each scan's own stamp and matches the clean run's.
// (Before, the keyframes kept the old clock and every later scan was refused as older.)
TEST(PoseGraphSlam, FollowsAClockSetBack) {
  auto at = [](int i) { return Pose2(2 + 0.05 * i, 3 + 0.01 * i, 0.004 * i); };
  for (const bool gyro : {false, true}) {
    SCOPED_TRACE(gyro ? "with the gyro" : "odometry only");
    auto run = [&](int64_t back) {
      auto t = [&](int i) { return 1000000 + int64_t{20000} * i - (i >= 40 ? back : 0); };
      auto slam = FineKeyframeSlam(gyro);
      for (int i = 0; i <= 100; ++i) {
        if (gyro) {  // 0.2 rad/s at twice the odometry's rate, ahead of it
          (void)slam->AddImuYawRate(t(i), 0.2);
          (void)slam->AddImuYawRate(t(i) + 10000, 0.2);
        }
        slam->AddOdometry(t(i), at(i));
        if (i % 5 == 0) (void)slam->AddScan(i, BoxScan(t(i), at(i)));
      }
      return slam;
    };
    const auto clean = run(0), slam = run(kHour);
    const auto& c = slam->counters();
    EXPECT_EQ(c.clock_steps_back, 1);
    EXPECT_EQ(c.time_rebases, gyro ? 2 : 1);  // the gyro's own, then the odometry's
    EXPECT_EQ(c.scans_time_backwards, 1);     // scan 40, then replayed
    EXPECT_EQ(c.scans_replayed, 1);
    EXPECT_EQ(c.scans_used, 21);
    // The gyro refuses the new clock's first samples until they re-base it; then the step
    // restarts it on the mapper's time line.
    EXPECT_LE(c.imu_rejected, gyro ? 5 : 0);
    EXPECT_EQ(clean->counters().scans_used, 21);
    const auto traj = slam->Trajectory(), traj_clean = clean->Trajectory();
    ASSERT_EQ(traj.size(), traj_clean.size());
    for (size_t k = 0; k < traj.size(); ++k) {
      EXPECT_EQ(traj[k].scan_index, traj_clean[k].scan_index);
      EXPECT_EQ(traj[k].utime, traj_clean[k].utime - (traj[k].scan_index >= 40 ? kHour : 0));
      EXPECT_LT(
          std::hypot(traj[k].pose.x - traj_clean[k].pose.x, traj[k].pose.y - traj_clean[k].pose.y),
          0.01)
          << k;
    }
    // The keyframes' time line goes on after the step instead of going back.
    const auto& kf = slam->keyframes();
    for (size_t k = 1; k < kf.size(); ++k) EXPECT_GT(kf[k].utime, kf[k - 1].utime);
  }
}

// One odometry sample stamped an hour ahead, then a scan inside the in-order run that proves
// it: the scan is posed towards the doubtful sample but is older than it, so the sample is
// dropped as a glitch, not taken for the clock going back (which would shift the rest of the
// run an hour along the time line).
TEST(PoseGraphSlam, AScanInsideTheProvingRunIsNoClockStep) {
  auto at = [](int i) { return Pose2(2 + 0.05 * i, 3, 0); };
  const auto t = At50Hz;
  const auto owned = FineKeyframeSlam();
  PoseGraphSlam& slam = *owned;
  for (int i = 0; i <= 60; ++i) {
    slam.AddOdometry(t(i), at(i));
    if (i == 38) slam.AddOdometry(t(i) + kHour, at(i));
    if (i % 5 == 0 || i == 41) {
      EXPECT_TRUE(slam.AddScan(i, BoxScan(t(i), at(i)))) << i;
    }
  }
  const auto& c = slam.counters();
  EXPECT_EQ(c.time_rebases, 1);
  EXPECT_EQ(c.clock_steps_back, 0);
  const auto& kf = slam.keyframes();
  ASSERT_FALSE(kf.empty());
  EXPECT_LE(kf.back().utime, t(60));  // no keyframe shifted along the time line
}

// A scan that came late before a short clock step is not replayed with the new clock's scans
// (it would land out of place and push later scans out as older): late by 3 samples before a
// 0.3 s step, and late by 5, arriving just before the new clock's first sample, with a 0.6 s one.
TEST(PoseGraphSlam, OnlyTheNewClocksScansAreReplayedAfterAStep) {
  auto at = [](int i) { return Pose2(2 + 0.05 * i, 3, 0); };
  struct Case {
    int step_at;
    int64_t back_us;
    int late_scan, late_after;
  };
  for (const Case k : {Case{40, 300000, 33, 36}, Case{50, 600000, 44, 49}}) {
    SCOPED_TRACE(k.back_us);
    auto run = [&](int64_t back) {
      auto t = [&](int i) { return At50Hz(i) - (i >= k.step_at ? back : 0); };
      auto slam = FineKeyframeSlam();
      for (int i = 0; i <= 80; ++i) {
        slam->AddOdometry(t(i), at(i));
        if (i % 5 == 0) (void)slam->AddScan(i, BoxScan(t(i), at(i)));
        if (i == k.late_after) {
          EXPECT_FALSE(slam->AddScan(k.late_scan, BoxScan(t(k.late_scan), at(k.late_scan))));
        }
      }
      return slam;
    };
    const auto clean = run(0), slam = run(k.back_us);
    const auto& c = slam->counters();
    EXPECT_EQ(c.clock_steps_back, 1);
    // The late one, and the new clock's first scan before the step was proven.
    EXPECT_EQ(c.scans_time_backwards, 2);
    EXPECT_EQ(c.scans_replayed, 1);
    const auto traj = slam->Trajectory(), traj_clean = clean->Trajectory();
    ASSERT_EQ(traj.size(), 17u);
    ASSERT_EQ(traj_clean.size(), 17u);
    for (size_t n = 0; n < traj.size(); ++n) {
      EXPECT_EQ(traj[n].scan_index, traj_clean[n].scan_index);
      EXPECT_LT(
          std::hypot(traj[n].pose.x - traj_clean[n].pose.x, traj[n].pose.y - traj_clean[n].pose.y),
          0.01)
          << traj[n].scan_index;
    }
  }
}

// A fix stamped on the new clock that comes while the odometry is proving a clock step back
// waits for the decision, then lands where its stamp belongs on the new clock (by the old
// clock it would be an hour before the first pose, and rejected).
TEST(PoseGraphSlam, AFixDuringAClockStepWaitsForTheDecision) {
  auto at = [](int i) { return Pose2(2 + 0.05 * i, 3, 0); };
  auto t = [](int i) { return 1000000 + int64_t{20000} * i - (i >= 40 ? kHour : 0); };
  const auto owned = FineKeyframeSlam();
  PoseGraphSlam& slam = *owned;
  const Eigen::Matrix3d info = Eigen::Vector3d(1e4, 1e4, 1e4).asDiagonal();
  for (int i = 0; i <= 80; ++i) {
    slam.AddOdometry(t(i), at(i));
    if (i % 5 == 0) (void)slam.AddScan(i, BoxScan(t(i), at(i)));
    if (i == 42) {
      EXPECT_EQ(slam.AddAbsolutePose(t(41), at(41) * at(0).Inverse(), info),
                AbsoluteOutcome::kQueued);
    }
  }
  const auto& c = slam.counters();
  EXPECT_EQ(c.clock_steps_back, 1);
  EXPECT_EQ(c.absolute_rejected, 0);
  EXPECT_EQ(c.absolute_attached + c.absolute_spliced, 1);
  EXPECT_EQ(c.absolute_queued, 1);
}

// Corner cases of telling a clock step from a glitch (a review's findings): a step after a
// lidar gap longer than the odometry history; a new-clock scan that comes before the new
// clock's first odometry; two future odometry samples with a scan stamped like them; a fix
// still waiting when the run never decides.
TEST(PoseGraphSlam, ClockStepCornerCases) {
  auto at = [](int i) { return Pose2(2 + 0.01 * i, 3, 0); };
  {  // no scan for 300 samples (6 s) before the step: the history holds 256
    auto t = [](int i) { return 1000000 + int64_t{20000} * i - (i >= 340 ? kHour : 0); };
    const auto owned = FineKeyframeSlam();
    PoseGraphSlam& slam = *owned;
    int used_after = 0;
    for (int i = 0; i <= 400; ++i) {
      slam.AddOdometry(t(i), at(i));
      if (i % 5 == 0 && (i <= 40 || i >= 340)) {
        const bool ok = slam.AddScan(i, BoxScan(t(i), at(i)));
        if (i > 340) used_after += ok ? 1 : 0;
      }
    }
    EXPECT_EQ(slam.counters().clock_steps_back, 1);
    EXPECT_EQ(used_after, 12);
    EXPECT_EQ(slam.counters().scans_replayed, 1);
  }
  {  // each scan before its odometry sample: scan 40 comes before the new clock's odometry
    auto t = [](int i) { return 1000000 + int64_t{20000} * i - (i >= 40 ? kHour : 0); };
    const auto owned = FineKeyframeSlam();
    PoseGraphSlam& slam = *owned;
    for (int i = 0; i <= 80; ++i) {
      if (i % 5 == 0) (void)slam.AddScan(i, BoxScan(t(i), at(i)));
      slam.AddOdometry(t(i), at(i));
    }
    EXPECT_EQ(slam.counters().clock_steps_back, 1);
    EXPECT_EQ(slam.counters().scans_replayed, 1);
    EXPECT_EQ(slam.counters().scans_used, 16);  // all but scan 0, which came before odometry
  }
  {  // two odometry samples an hour ahead and a scan stamped as the second: refused, no step
    const auto t = At50Hz;
    const auto owned = FineKeyframeSlam();
    PoseGraphSlam& slam = *owned;
    for (int i = 0; i <= 60; ++i) {
      slam.AddOdometry(t(i), at(i));
      if (i == 30) {
        slam.AddOdometry(t(i) + kHour, at(i));
        slam.AddOdometry(t(i) + kHour + 20000, at(i));
      }
      if (i == 32) {
        EXPECT_FALSE(slam.AddScan(1000, BoxScan(t(i) + kHour + 20000, at(i))));
      }
      if (i % 5 == 0) (void)slam.AddScan(i, BoxScan(t(i), at(i)));
    }
    EXPECT_EQ(slam.counters().clock_steps_back, 0);
    EXPECT_EQ(slam.counters().time_rebases, 1);
    EXPECT_EQ(slam.counters().scans_used, 13);
  }
  {  // a fix that waits for a run that never decides is placed at the end
    const auto t = At50Hz;
    const auto owned = FineKeyframeSlam();
    PoseGraphSlam& slam = *owned;
    for (int i = 0; i <= 40; ++i) {
      slam.AddOdometry(t(i), at(i));
      if (i % 5 == 0) (void)slam.AddScan(i, BoxScan(t(i), at(i)));
    }
    slam.AddOdometry(t(41) + kHour, at(41));
    slam.AddOdometry(t(41), at(41));
    const Eigen::Matrix3d info = Eigen::Vector3d(1e4, 1e4, 1e4).asDiagonal();
    EXPECT_EQ(slam.AddAbsolutePose(t(10), at(10) * at(0).Inverse(), info),
              AbsoluteOutcome::kQueued);
    EXPECT_EQ(slam.absolute_pending(), 1u);
    slam.Finish();
    const auto& c = slam.counters();
    EXPECT_EQ(c.absolute_attached + c.absolute_spliced + c.absolute_rejected, 1);
    EXPECT_EQ(slam.absolute_pending(), 0u);
  }
}

// Odometry and a scan both stamped an hour ahead with nothing between them (offline, where the
// log is read in order): the scan is mapped on that sample, so when the in-order odometry
// re-bases the stream the sample stays and the clock is taken as stepped back; mapping goes on
// with every later scan (before, each one was refused as older than the future scan).
TEST(PoseGraphSlam, AFutureOdometryAndScanPairDoesNotStopMapping) {
  auto at = [](int i) { return Pose2(2 + 0.05 * i, 3, 0); };
  const auto t = At50Hz;
  auto run = [&](bool glitch, int* used) {
    auto slam = FineKeyframeSlam();
    *used = 0;
    for (int i = 0; i <= 80; ++i) {
      slam->AddOdometry(t(i), at(i));
      if (i % 5 == 0) *used += slam->AddScan(i, BoxScan(t(i), at(i))) ? 1 : 0;
      if (glitch && i == 42) {
        slam->AddOdometry(t(i) + kHour, at(i));
        *used += slam->AddScan(1000, BoxScan(t(i) + kHour, at(i))) ? 1 : 0;
      }
    }
    return slam;
  };
  int used_clean = 0, used = 0;
  const auto clean = run(false, &used_clean);
  const auto slam = run(true, &used);
  const auto& c = slam->counters();
  EXPECT_EQ(c.clock_steps_back, 1);
  EXPECT_EQ(used_clean, 17);
  EXPECT_EQ(used, 17);             // the in-order ones but scan 45, and the future one
  EXPECT_EQ(c.scans_replayed, 1);  // scan 45, which came before the run proved the step
  const auto traj = slam->Trajectory(), traj_clean = clean->Trajectory();
  ASSERT_EQ(traj.size(), 18u);
  EXPECT_EQ(traj.back().utime, t(80));
  EXPECT_NEAR(traj.back().pose.x, traj_clean.back().pose.x, 0.02);
  EXPECT_NEAR(traj.back().pose.y, traj_clean.back().pose.y, 0.02);
}

// The straight drive of KeyframeGatingAndPosePerScan: scan i at 1 s + 0.1 s * i.
Pose2 DriveTruth(int i) { return Pose2(2 + 0.1 * i, 3 + 0.02 * std::sin(0.3 * i), 0.01 * i); }
int64_t DriveTime(int i) { return 1000000 + 100000 * int64_t{i}; }

void Drive(PoseGraphSlam* slam, int from, int to) {
  for (int i = from; i <= to; ++i) {
    slam->AddOdometry(DriveTime(i), DriveTruth(i));
    slam->AddScan(i, BoxScan(DriveTime(i), DriveTruth(i)));
  }
}

// The index of a scan strictly between the first two keyframes after the first.
int ScanBetweenKeyframes(const PoseGraphSlam& slam) {
  const auto& kf = slam.keyframes();
  for (int i = 0;; ++i)
    if (DriveTime(i) > kf.at(1).utime && DriveTime(i) < kf.at(2).utime) return i;
}

double Distance(const Pose2& a, const Pose2& b) { return std::hypot(a.x - b.x, a.y - b.y); }

// (a) + (d): an absolute pose between two keyframes creates one pose node; the odometry factor
// of that interval becomes two whose composition has the old relative pose and information;
// the scan-match factors stay; the node is pulled toward the measurement; the g2o export has
// the node and both halves.
TEST(PoseGraphSlam, AbsolutePoseBetweenKeyframesIsSplicedWithoutDoubleCounting) {
  PoseGraphSlam plain(PoseGraphSlamOptions{}, BatchOptions{}, nullptr);
  PoseGraphSlam spliced(PoseGraphSlamOptions{}, BatchOptions{}, nullptr);
  Drive(&plain, 0, 40);
  Drive(&spliced, 0, 40);
  const int i = ScanBetweenKeyframes(spliced);
  const io::PoseGraph before = plain.Graph();
  // Where the mapper puts the robot at that time now: the scan's pose.
  Pose2 guess;
  for (const auto& sp : spliced.Trajectory())
    if (sp.scan_index == i) guess = sp.pose;
  // The truth in the map frame (the first pose's), moved sideways by 0.3 m.
  const Pose2 truth = DriveTruth(0).Between(DriveTruth(i));
  const Pose2 z(truth.x, truth.y + 0.3, truth.theta);
  const Eigen::Matrix3d info = 1e4 * Eigen::Matrix3d::Identity();
  EXPECT_EQ(spliced.AddAbsolutePose(DriveTime(i), z, info), AbsoluteOutcome::kSpliced);

  const SlamCounters& c = spliced.counters();
  EXPECT_EQ(c.absolute_in, 1);
  EXPECT_EQ(c.absolute_spliced, 1);
  EXPECT_EQ(c.absolute_attached + c.absolute_queued + c.absolute_rejected, 0);
  EXPECT_EQ(spliced.num_pose_nodes(), 1u);
  EXPECT_EQ(spliced.keyframes().size(), plain.keyframes().size());
  EXPECT_EQ(spliced.Trajectory().size(), 41u);  // still one pose per scan
  ASSERT_EQ(spliced.absolute_priors().size(), 1u);

  const io::PoseGraph after = spliced.Graph();
  const int node = static_cast<int>(spliced.num_nodes()) - 1;
  ASSERT_EQ(after.vertices2.size(), before.vertices2.size() + 1);
  EXPECT_EQ(after.vertices2.back().id, node);
  EXPECT_EQ(spliced.absolute_priors()[0].id, node);
  ASSERT_EQ(after.edges2.size(), before.edges2.size() + 1);
  // Keyframes 1 and 2 are nodes 1 and 2. The first half took the old odometry edge's place,
  // the second half is the newest edge; every other edge is unchanged.
  size_t half = before.edges2.size();
  for (size_t e = 0; e < before.edges2.size(); ++e)
    if (after.edges2[e].from == 1 && after.edges2[e].to == node) half = e;
  ASSERT_LT(half, before.edges2.size());
  const io::Edge2& old_link = before.edges2[half];
  EXPECT_EQ(old_link.from, 1);
  EXPECT_EQ(old_link.to, 2);
  const io::Edge2& first = after.edges2[half];
  const io::Edge2& second = after.edges2.back();
  EXPECT_EQ(second.from, node);
  EXPECT_EQ(second.to, 2);
  int scan_edges_1_2 = 0;
  for (size_t e = 0; e < before.edges2.size(); ++e) {
    if (e == half) continue;
    EXPECT_EQ(after.edges2[e].from, before.edges2[e].from);
    EXPECT_EQ(after.edges2[e].to, before.edges2[e].to);
    if (after.edges2[e].from == 1 && after.edges2[e].to == 2) ++scan_edges_1_2;
  }
  EXPECT_EQ(scan_edges_1_2, 1);  // the scan match between the keyframes stays
  const Pose2 composed = first.measurement * second.measurement;
  EXPECT_NEAR(composed.x, old_link.measurement.x, 1e-9);
  EXPECT_NEAR(composed.y, old_link.measurement.y, 1e-9);
  EXPECT_NEAR(WrapAngle(composed.theta - old_link.measurement.theta), 0, 1e-9);
  // An edge's information is over its error in the later pose's frame (RelativeInformation);
  // back to the covariance over the measurement's coordinates: Sigma = T^T Omega^-1 T.
  auto covariance_of = [](const io::Edge2& e) {
    Eigen::Matrix3d t = Eigen::Matrix3d::Identity();
    const double c = std::cos(e.measurement.theta), s = std::sin(e.measurement.theta);
    t.topLeftCorner<2, 2>() << c, s, -s, c;
    return Eigen::Matrix3d(t.transpose() * e.information.inverse() * t);
  };
  Eigen::Matrix3d ja, jb;
  ComposeJacobians(first.measurement, second.measurement, &ja, &jb);
  const Eigen::Matrix3d cov =
      ja * covariance_of(first) * ja.transpose() + jb * covariance_of(second) * jb.transpose();
  const Eigen::Matrix3d old_cov = covariance_of(old_link);
  EXPECT_LT((cov.inverse() - old_cov.inverse()).norm(), 1e-4 * old_cov.inverse().norm())
      << "old:\n"
      << old_cov.inverse() << "\nspliced:\n"
      << cov.inverse();

  const Pose2 estimate = after.vertices2.back().pose;
  std::printf("measurement %.3f m from the scan's pose, %.3f m from the spliced node\n",
              Distance(guess, z), Distance(estimate, z));
  EXPECT_LT(Distance(estimate, z), 0.5 * Distance(guess, z))
      << "guess (" << guess.x << ", " << guess.y << ") estimate (" << estimate.x << ", "
      << estimate.y << ")";
}

// (b) Odometry that overstates every step by 10 %, with the scan matches made negligible: a
// few absolute poses pull the trajectory back to the truth.
TEST(PoseGraphSlam, AbsolutePosesCorrectBiasedOdometry) {
  auto run = [](bool with_absolute) {
    PoseGraphSlamOptions o;
    o.scan_match_information_scale = 1e-6;
    PoseGraphSlam slam(o, BatchOptions{}, nullptr);
    Eigen::Matrix3d info = Eigen::Matrix3d::Identity();
    info.diagonal() << 400, 400, 400;  // 5 cm, 0.05 rad
    for (int i = 0; i <= 60; ++i) {
      const Pose2 t = DriveTruth(i);
      slam.AddOdometry(DriveTime(i), Pose2(2 + 1.1 * (t.x - 2), 3 + 1.1 * (t.y - 3), t.theta));
      slam.AddScan(i, BoxScan(DriveTime(i), t));
      // Every 10th scan, a fix for a time 0.35 s back (between scans, usually between keyframes).
      if (with_absolute && i > 0 && i % 10 == 0) {
        const int64_t when = DriveTime(i) - 350000;
        const Pose2 a =
            DriveTruth(0).Between(Interpolate(DriveTruth(i - 4), DriveTruth(i - 3), 0.5));
        slam.AddAbsolutePose(when, a, info);
      }
    }
    double sum = 0;
    const auto traj = slam.Trajectory();
    for (const auto& sp : traj) {
      const Pose2 truth = DriveTruth(0).Between(DriveTruth(static_cast<int>(sp.scan_index)));
      sum += std::pow(Distance(sp.pose, truth), 2);
    }
    EXPECT_EQ(traj.size(), 61u);
    if (with_absolute) {
      EXPECT_EQ(slam.counters().absolute_in, 6);
      EXPECT_EQ(slam.counters().absolute_rejected + slam.counters().absolute_invalid, 0);
      EXPECT_EQ(slam.counters().absolute_spliced + slam.counters().absolute_attached, 6);
    }
    return std::sqrt(sum / static_cast<double>(traj.size()));
  };
  const double without = run(false), with = run(true);
  std::printf("trajectory RMS error: %.3f m without absolute poses, %.3f m with\n", without, with);
  EXPECT_GT(without, 0.15);  // the bias is real: 10 % of up to 6 m
  EXPECT_LT(with, 0.5 * without) << "without " << without << " m, with " << with << " m";
}

// The gyro's bias learned standing still: 5 s parked (the odometry jitters by an encoder tick),
// 5 s driving, 5 s parked while someone turns the base by hand (the wheels do not move: those
// samples are refused), 5 s parked again. A gyro with a 0.003 rad/s bias and 0.005 rad/s noise
// at 100 Hz; odometry at 50 Hz.
TEST(PoseGraphSlam, LearnsTheGyroBiasWhileTheOdometryStandsStill) {
  auto run = [](bool estimate) {
    PoseGraphSlamOptions o;
    o.use_gyro = true;
    o.gyro_bias.estimate = estimate;
    PoseGraphSlam slam(o, BatchOptions{}, nullptr);
    std::mt19937 rng(7);
    std::normal_distribution<double> noise(0.0, 0.005);
    Pose2 pose(1, 1, 0);
    for (int k = 0; k <= 2000; ++k) {  // 20 s at 100 Hz
      const int64_t t = 1'000'000 + 10'000 * int64_t{k};
      const bool driving = k > 500 && k <= 1000;
      const bool hand_turned = k > 1000 && k <= 1500;
      const double rate = driving ? 0.2 : hand_turned ? 0.1 : 0.0;
      EXPECT_TRUE(slam.AddImuYawRate(t, rate + 0.003 + noise(rng)));
      if (driving) pose = pose * Pose2(0.003, 0, 0.002);
      if (k % 2 == 0) {
        const double tick = (k / 2) % 7 == 0 ? 2e-4 : 0.0;  // one encoder tick of jitter
        slam.AddOdometry(t, Pose2(pose.x + tick, pose.y, pose.theta + tick));
      }
    }
    return std::make_pair(slam.gyro_bias_rad_s(), slam.counters());
  };
  const auto [bias, c] = run(true);
  // The wheels stand still from 0 to 5 s and from 10 to 20 s; after 0.2 s each stretch gives
  // a sample per whole second that ends 0.2 s before the latest odometry: 4 + 9 chunks, of
  // which the five that hold hand-turned time are refused (0.08-0.1 rad/s > 0.03).
  EXPECT_EQ(c.gyro_bias_samples, 8);
  EXPECT_EQ(c.gyro_bias_refused, 5);
  EXPECT_NEAR(bias, 0.003, 0.0005);  // the mean of 800 samples: sigma 0.18 mrad/s
  const auto [fixed, c0] = run(false);
  EXPECT_EQ(fixed, 0.0);
  EXPECT_EQ(c0.gyro_bias_samples, 0);
}

// The IMU as a continuous source: odometry that over-reads every turn by 10 % bends a circular
// drive; with the gyro's heading fused into every odometry factor the path stays on the circle.
// Scan matches are given almost no weight, so the odometry factors decide the trajectory.
TEST(PoseGraphSlam, GyroHeadingCorrectsOdometryThatOverReadsTurns) {
  const double rate = 0.25;  // rad/s on a 2 m circle around (5, 3) at 0.5 m/s
  auto truth_at = [&](int64_t t_us) {
    const double a = -M_PI / 2 + rate * 1e-6 * static_cast<double>(t_us);
    return Pose2(5 + 2 * std::cos(a), 3 + 2 * std::sin(a), WrapAngle(a + M_PI / 2));
  };
  auto run = [&](bool gyro) {
    PoseGraphSlamOptions o;
    o.scan_match_information_scale = 1e-6;
    o.use_gyro = gyro;
    o.odometry_calibration.enabled = false;  // this test is about the gyro alone
    PoseGraphSlam slam(o, BatchOptions{}, nullptr);
    Pose2 odo = truth_at(0);
    for (int k = 0; k <= 1200; ++k) {  // 12 s: gyro at 100 Hz, odometry at 50 Hz, scans at 10 Hz
      const int64_t t = 10'000 * int64_t{k};
      if (gyro) {
        EXPECT_TRUE(slam.AddImuYawRate(t, rate));
      }
      if (k % 2 == 0) {
        if (k > 0) {
          const Pose2 step = truth_at(t - 20'000).Between(truth_at(t));
          odo = odo * Pose2(step.x, step.y, 1.1 * step.theta);
        }
        slam.AddOdometry(t, odo);
      }
      if (k % 10 == 0) slam.AddScan(k / 10, BoxScan(t, truth_at(t)));
    }
    if (gyro) {
      EXPECT_FALSE(slam.AddImuYawRate(12'000'000, 0.0));  // not newer than the last sample
      EXPECT_FALSE(slam.AddImuYawRate(13'000'000, std::nan("")));
      EXPECT_EQ(slam.counters().imu_in, 1203);
      EXPECT_EQ(slam.counters().imu_rejected, 2);
      EXPECT_EQ(slam.gyro_missing_steps(), 0u);
      EXPECT_EQ(slam.PluginCounters().at("gyro.missing_steps"), 0);
    }
    double sum = 0;
    const auto traj = slam.Trajectory();
    EXPECT_EQ(traj.size(), 121u);
    for (const auto& sp : traj) {
      const Pose2 truth = truth_at(0).Between(truth_at(sp.utime));
      sum += std::pow(Distance(sp.pose, truth), 2);
    }
    return std::sqrt(sum / static_cast<double>(traj.size()));
  };
  const double without = run(false), with = run(true);
  std::printf("trajectory RMS error: %.3f m odometry only, %.3f m with the gyro\n", without, with);
  EXPECT_GT(without, 0.2);
  EXPECT_LT(with, 0.2 * without) << "without " << without << " m, with " << with << " m";
}

// Odometry with a 3 % scale error and a heading error of 2 % of the turn plus 0.015 rad per metre
// on two laps of a 2 m circle in the box: the keyframe matches feed the calibration, which finds
// the scale and the heading error per metre (on a circle the turn is proportional to the
// distance, so only their sum is observable), and the odometry factors use it.
TEST(PoseGraphSlam, OdometryCalibrationFindsASystematicError) {
  const double rate = 0.25;  // rad/s, 0.5 m/s: 0.5 rad per metre
  auto truth_at = [&](int64_t t_us) {
    const double a = -M_PI / 2 + rate * 1e-6 * static_cast<double>(t_us);
    return Pose2(5 + 2 * std::cos(a), 3 + 2 * std::sin(a), WrapAngle(a + M_PI / 2));
  };
  OdometryCalibration err;
  err.x_scale = 0.03;
  err.theta_scale = 0.02;
  err.theta_per_x = 0.015;
  PoseGraphSlamOptions o;
  ASSERT_TRUE(o.odometry_calibration.enabled);  // the default
  PoseGraphSlam slam(o, BatchOptions{}, nullptr);
  Pose2 odo = truth_at(0);
  for (int k = 0; k <= 2500; ++k) {  // 50 s: odometry at 50 Hz, scans at 10 Hz
    const int64_t t = 20'000 * int64_t{k};
    if (k > 0) odo = odo * err.Distort(truth_at(t - 20'000).Between(truth_at(t)));
    slam.AddOdometry(t, odo);
    if (k % 5 == 0) slam.AddScan(k / 5, BoxScan(t, truth_at(t)));
  }
  const OdometryCalibrator& cal = slam.odometry_calibrator();
  ASSERT_TRUE(cal.active());
  EXPECT_GT(cal.pairs_used(), 40);
  EXPECT_EQ(cal.pairs_gated(), 0);
  const OdometryCalibration& c = cal.calibration();
  EXPECT_NEAR(c.x_scale, 0.03, 0.005);
  EXPECT_NEAR(0.5 * c.theta_scale + c.theta_per_x, 0.5 * 0.02 + 0.015, 0.004);
  // The odometry factor of the last keyframe pair is the calibrated motion: close to the truth.
  const auto& kf = slam.keyframes();
  const auto motion = [&] {
    io::PoseGraph g = slam.Graph();
    const int a = static_cast<int>(kf.size()) - 2;
    for (const auto& e : g.edges2)
      if (e.from == a && e.to == a + 1) return e.measurement;  // the odometry edge comes first
    return Pose2();
  }();
  const Pose2 want = truth_at(kf[kf.size() - 2].utime).Between(truth_at(kf.back().utime));
  const Pose2 raw = err.Distort(want);
  EXPECT_LT(std::hypot(motion.x - want.x, motion.y - want.y),
            0.5 * std::hypot(raw.x - want.x, raw.y - want.y));
  EXPECT_LT(std::abs(WrapAngle(motion.theta - want.theta)),
            0.5 * std::abs(WrapAngle(raw.theta - want.theta)));
}

// The measurement queue's time window: a fix taken while the base stands still waits for a
// keyframe that motion would never bring; once it has waited absolute_max_wait_s, the next scan
// becomes a keyframe and the fix is placed. Without the window (a long wait) it stays queued.
TEST(PoseGraphSlam, AParkedRobotsFixIsPlacedAfterItsTimeWindow) {
  for (const double wait_s : {1.0, 1000.0}) {
    PoseGraphSlamOptions o;
    o.absolute_max_wait_s = wait_s;
    PoseGraphSlam slam(o, BatchOptions{}, nullptr);
    Drive(&slam, 0, 20);
    const int64_t keyframes = slam.counters().keyframes;
    // Parked at scan 20's pose for 3 s, scans and odometry still coming at 10 Hz.
    const Pose2 parked = DriveTruth(20);
    const int64_t fix_at = DriveTime(25) + 30000;
    for (int i = 21; i <= 50; ++i) {
      slam.AddOdometry(DriveTime(i), parked);
      if (i == 26) {
        EXPECT_EQ(slam.AddAbsolutePose(fix_at, DriveTruth(0).Between(parked),
                                       100 * Eigen::Matrix3d::Identity()),
                  AbsoluteOutcome::kQueued);
      }
      EXPECT_TRUE(slam.AddScan(i, BoxScan(DriveTime(i), parked)));
    }
    const SlamCounters& c = slam.counters();
    if (wait_s == 1.0) {
      // The scan 1 s after the fix (index 36) is made a keyframe; the fix is spliced into the
      // interval before it; nothing else changes while the base stands still.
      EXPECT_EQ(c.keyframes, keyframes + 1);
      EXPECT_EQ(c.keyframes_for_absolute, 1);
      EXPECT_EQ(slam.keyframes().back().utime, DriveTime(36));
      EXPECT_EQ(slam.absolute_pending(), 0u);
      EXPECT_EQ(c.absolute_spliced, 1);
      EXPECT_EQ(slam.absolute_priors().size(), 1u);
    } else {
      EXPECT_EQ(c.keyframes, keyframes);
      EXPECT_EQ(c.keyframes_for_absolute, 0);
      EXPECT_EQ(slam.absolute_pending(), 1u);
      EXPECT_EQ(c.absolute_spliced + c.absolute_attached, 0);
    }
    EXPECT_EQ(slam.Trajectory().size(), 51u);
    EXPECT_EQ(c.window_failures, 0);
  }
}

// A base that stands in one place for a long time: with its odometry exactly still, the buffer
// does not grow; with the odometry jittering by a tick, the buffer would drop the last keyframe's
// time (at 100 Hz after ~1000 s by default; 500 samples here), after which no scan could be
// mapped again, even after the base drives off. A keyframe is made before that happens.
TEST(PoseGraphSlam, ALongStayInOnePlaceDoesNotRunTheOdometryOut) {
  for (const bool jitter : {false, true}) {
    PoseGraphSlamOptions o;
    o.odometry_buffer_samples = 500;
    PoseGraphSlam slam(o, BatchOptions{}, nullptr);
    Drive(&slam, 0, 20);
    const Pose2 parked = DriveTruth(20);
    // 60 s parked: odometry at 100 Hz, scans at 10 Hz.
    int scan = 21;
    int64_t t = DriveTime(20);
    for (int k = 1; k <= 6000; ++k) {
      t += 10000;
      Pose2 odom = parked;
      if (jitter && k % 2 == 1) odom.x += 1e-5;  // an encoder tick back and forth
      slam.AddOdometry(t, odom);
      if (k % 10 == 0) {
        EXPECT_TRUE(slam.AddScan(scan++, BoxScan(t, parked))) << k;
      }
    }
    // Then it drives off, 1 m along x.
    for (int k = 1; k <= 20; ++k) {
      t += 100000;
      const Pose2 p(parked.x + 0.05 * k, parked.y, parked.theta);
      slam.AddOdometry(t, p);
      EXPECT_TRUE(slam.AddScan(scan++, BoxScan(t, p))) << "driving " << k;
    }
    const SlamCounters& c = slam.counters();
    EXPECT_EQ(c.scans_no_odom, 0) << "jitter " << jitter;
    EXPECT_EQ(c.scans_used, scan);
    if (jitter) {
      EXPECT_GE(c.keyframes_for_odometry, 10);  // one per ~450 samples of 6000
    } else {
      EXPECT_EQ(c.keyframes_for_odometry, 0);
    }
    const auto traj = slam.Trajectory();
    ASSERT_EQ(traj.size(), static_cast<size_t>(scan));
    const Pose2 end = DriveTruth(0).Between(Pose2(parked.x + 1.0, parked.y, parked.theta));
    EXPECT_NEAR(traj.back().pose.x, end.x, 0.05);
    EXPECT_NEAR(traj.back().pose.y, end.y, 0.05);
  }
}

// (c) Each way an absolute pose can go is counted once: at a keyframe's time (attached), newer
// than the newest pose (queued, then spliced when the next keyframe covers it), older than the
// window (rejected), a bad information matrix (invalid).
TEST(PoseGraphSlam, AbsolutePoseOutcomesAreCounted) {
  PoseGraphSlamOptions o;
  o.window_size = 3;
  PoseGraphSlam slam(o, BatchOptions{}, nullptr);
  Drive(&slam, 0, 30);
  const Eigen::Matrix3d info = 100 * Eigen::Matrix3d::Identity();
  const int64_t newest = slam.keyframes().back().utime;
  auto truth_at = [](int64_t utime) {
    const double f = static_cast<double>(utime - 1000000) / 100000.0;
    const int i = static_cast<int>(std::floor(f));
    return DriveTruth(0).Between(Interpolate(DriveTruth(i), DriveTruth(i + 1), f - i));
  };
  EXPECT_EQ(slam.AddAbsolutePose(newest, truth_at(newest), info), AbsoluteOutcome::kAttached);
  const int64_t future = DriveTime(33) + 50000;
  EXPECT_EQ(slam.AddAbsolutePose(future, truth_at(future), info), AbsoluteOutcome::kQueued);
  EXPECT_EQ(slam.absolute_pending(), 1u);
  EXPECT_EQ(slam.AddAbsolutePose(DriveTime(2) + 50000, truth_at(DriveTime(2) + 50000), info),
            AbsoluteOutcome::kRejected);  // its keyframes left the window of 3
  EXPECT_EQ(slam.AddAbsolutePose(500000, Pose2(), info),
            AbsoluteOutcome::kRejected);  // before the first pose: not queued either
  Eigen::Matrix3d bad = info;
  bad(2, 2) = -1;
  EXPECT_EQ(slam.AddAbsolutePose(DriveTime(20), Pose2(), bad), AbsoluteOutcome::kInvalid);
  const SlamCounters& c = slam.counters();
  EXPECT_EQ(c.absolute_in, 5);
  EXPECT_EQ(c.absolute_attached, 1);
  EXPECT_EQ(c.absolute_queued, 1);
  EXPECT_EQ(c.absolute_rejected, 2);
  EXPECT_EQ(c.absolute_invalid, 1);
  EXPECT_EQ(c.absolute_spliced, 0);
  EXPECT_EQ(slam.num_pose_nodes(), 0u);
  Drive(&slam, 31, 45);  // the next keyframes cover the queued one
  EXPECT_EQ(slam.absolute_pending(), 0u);
  EXPECT_EQ(c.absolute_spliced, 1);
  EXPECT_EQ(c.absolute_rejected, 2);
  EXPECT_EQ(slam.num_pose_nodes(), 1u);
  EXPECT_EQ(slam.absolute_priors().size(), 2u);
  EXPECT_EQ(slam.Trajectory().size(), 46u);
  EXPECT_EQ(c.window_failures, 0);
}

// Back and forth along the room with loops closing (global optimisations, the window rebuilt
// from their result) while fixes keep being spliced in: nothing fails, the spliced nodes stay in
// the graph through the rebuilds, and the result stays on the truth.
TEST(PoseGraphSlam, SplicedPosesSurviveGlobalOptimisationsAndWindowRebuilds) {
  PoseGraphSlamOptions o = LoopingOptions();
  o.loop_cooldown_keyframes = 0;
  PoseGraphSlam slam(o, BatchOptions{}, nullptr);
  const auto truth = BackAndForth;
  const Eigen::Matrix3d info = 400 * Eigen::Matrix3d::Identity();
  for (int i = 0; i < 3 * 61; ++i) {
    const int64_t t = 1000000 + 100000 * int64_t{i};
    slam.AddOdometry(t, truth(i));
    slam.AddScan(i, BoxScan(t, truth(i)));
    if (i >= 4 && i % 7 == 0)  // a fix halfway between scans i - 4 and i - 3
      slam.AddAbsolutePose(t - 350000,
                           truth(0).Between(Interpolate(truth(i - 4), truth(i - 3), 0.5)), info);
  }
  slam.Finish();
  const SlamCounters& c = slam.counters();
  EXPECT_GT(c.loops_accepted, 0);
  EXPECT_GT(c.global_optimizations, 0);
  EXPECT_EQ(c.global_failures, 0);
  EXPECT_EQ(c.window_failures, 0);
  EXPECT_GT(c.absolute_spliced, 10);
  EXPECT_EQ(c.absolute_in, c.absolute_spliced + c.absolute_attached + c.absolute_rejected);
  EXPECT_EQ(slam.num_nodes(), static_cast<size_t>(c.keyframes) + slam.num_pose_nodes());
  EXPECT_EQ(slam.num_pose_nodes(), static_cast<size_t>(c.absolute_spliced));
  EXPECT_EQ(slam.Graph().vertices2.size(), slam.num_nodes());
  const auto traj = slam.Trajectory();
  ASSERT_EQ(traj.size(), 183u);
  double worst = 0;
  for (const auto& sp : traj) {
    const Pose2 want = truth(0).Between(truth(static_cast<int>(sp.scan_index)));
    EXPECT_LT(Distance(sp.pose, want), 0.05) << sp.scan_index;
    worst = std::max(worst, Distance(sp.pose, want));
  }
  std::printf(
      "%lld fixes: %lld spliced, %lld attached, %lld rejected; %lld loops, %lld global "
      "solves; worst scan error %.3f m\n",
      static_cast<long long>(c.absolute_in), static_cast<long long>(c.absolute_spliced),
      static_cast<long long>(c.absolute_attached), static_cast<long long>(c.absolute_rejected),
      static_cast<long long>(c.loops_accepted), static_cast<long long>(c.global_optimizations),
      worst);
}

// A global optimisation's time limit (global_max_time_s) stops the solves while mapping (here
// before their first step: the limit is checked once the problem is set up); the last one, at
// Finish, has none and runs because the one before was cut, even with the final optimisation
// off. Odometry over-reading by 4 % makes the solves matter: the run still ends as close to the
// truth as the unlimited one; the cut solves are counted, and no keyframe is retired on
// estimates no solve has converged on.
TEST(PoseGraphSlam, TimeLimitedGlobalSolvesEndAsCloseAsUnlimitedOnes) {
  auto run = [](double max_time_s) {
    PoseGraphSlamOptions o = LoopingOptions();
    o.global_max_time_s = max_time_s;
    o.final_global_optimization = false;
    o.retire.delay_keyframes = 5;  // so that the unlimited run retires some
    auto slam = std::make_unique<PoseGraphSlam>(o, BatchOptions{}, nullptr);
    Pose2 odom;
    for (int i = 0; i < 3 * 61; ++i) {
      const Pose2 p = BackAndForth(i);
      if (i > 0) {
        Pose2 d = BackAndForth(i - 1).Between(p);
        d.x *= 1.04;
        d.y *= 1.04;
        odom = odom * d;
      }
      const int64_t t = 1000000 + 100000 * int64_t{i};
      slam->AddOdometry(t, odom);
      slam->AddScan(i, BoxScan(t, p));
    }
    slam->Finish();
    return slam;
  };
  const auto free_run = run(0);
  const auto limited = run(1e-9);  // every solve while mapping stops at its first check
  EXPECT_EQ(free_run->counters().global_time_limited, 0);
  const SlamCounters& c = limited->counters();
  EXPECT_GT(c.loops_accepted, 0);
  EXPECT_EQ(c.global_failures, 0);
  EXPECT_EQ(c.global_time_limited, c.global_optimizations - 1);  // all but Finish's
  EXPECT_GT(free_run->counters().keyframes_retired, 0);
  EXPECT_EQ(c.keyframes_retired, 0);
  EXPECT_GT(c.global_time_limited, 3);
  // The estimates differ while mapping, so the two runs may accept different loops: both are
  // held to the truth.
  auto worst_error = [](const PoseGraphSlam& slam) {
    double worst = 0;
    for (const auto& sp : slam.Trajectory()) {
      const Pose2 want = BackAndForth(0).Between(BackAndForth(static_cast<int>(sp.scan_index)));
      worst = std::max(worst, Distance(sp.pose, want));
    }
    return worst;
  };
  const double e_free = worst_error(*free_run), e_limited = worst_error(*limited);
  EXPECT_LT(e_limited, 0.05);
  EXPECT_LT(e_limited, e_free + 0.02);
  std::printf("%lld of %lld global solves cut short; worst error %.4f m (unlimited %.4f m)\n",
              static_cast<long long>(c.global_time_limited),
              static_cast<long long>(c.global_optimizations), e_limited, e_free);
}

// Five passes along the box room, back and forth on one line: once loops tie a pass to the
// first, its keyframes are retired (scan released, pose kept) where a kept keyframe at least
// min_index_gap older lies within retire.distance_m and retire.angle_rad. The first pass and the
// newest delay_keyframes are never retired; the map and the trajectory stay those of the run
// that keeps every scan. Removing the retired poses from the graph (on by default; the window
// here is 5 keyframes, so they go soon after) keeps the trajectory as close to the truth.
TEST(PoseGraphSlam, RevisitsAreRetiredWithTheirScansReleased) {
  auto run = [](bool retire, bool remove = false) {
    PoseGraphSlamOptions o = LoopingOptions();
    o.retire.enabled = retire;
    o.retire.remove_poses = remove;
    auto slam = std::make_unique<PoseGraphSlam>(o, BatchOptions{}, nullptr);
    for (int i = 0; i < 5 * 61; ++i) {
      const Pose2 p = BackAndForth(i);
      const int64_t t = 1000000 + 100000 * int64_t{i};
      slam->AddOdometry(t, p);
      slam->AddScan(i, BoxScan(t, p));
    }
    slam->Finish();
    return slam;
  };
  const auto kept = run(false);
  const auto slam = run(true);
  const auto removed = run(true, true);
  EXPECT_EQ(kept->counters().keyframes_retired, 0);
  EXPECT_EQ(slam->counters().keyframes_removed, 0);
  const SlamCounters& c = slam->counters();
  const auto& kfs = slam->keyframes();
  ASSERT_EQ(static_cast<size_t>(c.keyframes), kfs.size());
  ASSERT_EQ(kfs.size(), kept->keyframes().size());
  const PoseGraphSlamOptions o;
  int retired = 0, first_pass = 0;
  for (size_t k = 0; k < kfs.size(); ++k) {
    if (kfs[k].utime <= 1000000 + 100000 * 60) ++first_pass;
    if (!kfs[k].retired) continue;
    ++retired;
    EXPECT_TRUE(kfs[k].points.empty()) << k;
    EXPECT_EQ(kfs[k].points.capacity(), 0u) << k;  // released, not only cleared
    EXPECT_GT(kfs[k].utime, 1000000 + 100000 * 60) << "first pass retired: " << k;
    EXPECT_LT(k + static_cast<size_t>(o.retire.delay_keyframes), kfs.size()) << k;
    bool covered = false;
    for (size_t j = 0; j + 10 <= k; ++j) {
      const Pose2 d = kfs[j].estimate.Between(kfs[k].estimate);
      covered |= !kfs[j].retired && !kfs[j].points.empty() &&
                 std::hypot(d.x, d.y) <= o.retire.distance_m &&
                 std::abs(d.theta) <= o.retire.angle_rad;
    }
    EXPECT_TRUE(covered) << k;
  }
  EXPECT_EQ(retired, c.keyframes_retired);
  // Most keyframes after the first pass lie on it: at least half of them go.
  EXPECT_GT(retired, (static_cast<int>(kfs.size()) - first_pass) / 2);
  for (size_t k = 0; k < kfs.size(); ++k) {
    EXPECT_TRUE(kfs[k].retired || !kfs[k].points.empty()) << k;
  }
  // Same poses (to the matcher's precision) and the same walls.
  const auto a = slam->Trajectory(), b = kept->Trajectory();
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) EXPECT_LT(Distance(a[i].pose, b[i].pose), 0.02) << i;
  // Without the removed poses: each scan within 3 cm of the worst error of the run that keeps
  // them all (the bare room's matches are good to a few cm), the graph holding only kept nodes.
  const SlamCounters& rc = removed->counters();
  EXPECT_EQ(rc.keyframes_retired, c.keyframes_retired);
  EXPECT_GT(rc.keyframes_removed, c.keyframes_retired / 2);
  const io::PoseGraph graph = removed->Graph();
  EXPECT_EQ(graph.vertices2.size(), removed->num_live_nodes());
  EXPECT_EQ(graph.vertices2.size() + static_cast<size_t>(rc.keyframes_removed),
            removed->num_nodes());
  EXPECT_LT(graph.edges2.size(), slam->Graph().edges2.size());
  const auto r = removed->Trajectory();
  ASSERT_EQ(r.size(), b.size());
  double worst_kept = 0, worst_removed = 0;
  for (size_t i = 0; i < r.size(); ++i) {
    const Pose2 t = BackAndForth(0).Inverse() * BackAndForth(static_cast<int>(i));
    worst_kept = std::max(worst_kept, Distance(b[i].pose, t));
    worst_removed = std::max(worst_removed, Distance(r[i].pose, t));
  }
  EXPECT_LT(worst_removed, worst_kept + 0.03);
  io::LogOddsOptions lo;
  lo.resolution_m = 0.1;
  const io::GridMap ma = slam->RenderMap(lo), mb = kept->RenderMap(lo);
  auto occupied = [](const io::GridMap& m) {
    int n = 0;
    for (int8_t v : m.cells) n += v > 50;
    return n;
  };
  const io::GridMap mr = removed->RenderMap(lo);
  EXPECT_GT(occupied(ma), 0.9 * occupied(mb));
  EXPECT_LT(occupied(ma), 1.1 * occupied(mb));
  // The same kept scans at slightly different poses: a wall drawn twice would add cells
  // (measured: 452 against 520, thinner walls).
  EXPECT_GT(occupied(mr), 0.8 * occupied(mb));
  EXPECT_LT(occupied(mr), 1.1 * occupied(mb));
  std::printf(
      "%lld keyframes, %d on the first pass, %d retired, %lld removed; occupied cells %d / %d / "
      "%d; worst error to the truth %.3f m (%.3f m with every pose)\n",
      static_cast<long long>(c.keyframes), first_pass, retired,
      static_cast<long long>(rc.keyframes_removed), occupied(ma), occupied(mr), occupied(mb),
      worst_removed, worst_kept);
}

// The global optimisation sees the pose nodes and the absolute factors: a prior on the last
// vertex of a chain moves it (OptimizeGraph with priors).
TEST(PoseGraphSlam, BatchOptimizerTakesAbsolutePriors) {
  io::PoseGraph g;
  for (int i = 0; i < 3; ++i) g.vertices2.push_back({i, Pose2(i, 0, 0)});
  for (int i = 0; i < 2; ++i) {
    io::Edge2 e;
    e.from = i;
    e.to = i + 1;
    e.measurement = Pose2(1, 0, 0);
    g.edges2.push_back(e);
  }
  std::vector<VertexPrior2> priors{{2, Pose2(2, 1, 0), 100 * Eigen::Matrix3d::Identity()}};
  BatchOptions b;
  b.initialization = Initialization::kNone;
  ASSERT_TRUE(OptimizeGraph(&g, b, &priors).ok());
  EXPECT_GT(g.vertices2[2].pose.y, 0.5);
  priors[0].id = 7;
  EXPECT_FALSE(OptimizeGraph(&g, b, &priors).ok());
}

}  // namespace
}  // namespace omni::pgm
