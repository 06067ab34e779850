// The mapper core's trajectory: one pose per timestamp, consecutive poses always linked,
// splicing a late pose into a linked interval replaces one factor by two without changing the
// odometry's information, measurement queueing, and the continuous sources.
#include <gtest/gtest.h>

#include <random>

#include <Eigen/LU>

#include "omni/pose_graph_mapper/batch_optimizer.h"
#include "omni/pose_graph_mapper/continuous_source.h"
#include "omni/pose_graph_mapper/gyro_source.h"
#include "omni/pose_graph_mapper/trajectory.h"

namespace omni::pgm {
namespace {

// Odometry at 50 Hz (every 20 ms) along a curving path for 10 s.
OdometrySource MakeOdometry() {
  OdometrySource odo;
  Pose2 p;
  for (int k = 0; k <= 500; ++k) {
    EXPECT_TRUE(odo.AddSample(1'000'000 + 20'000 * k, p));
    p = p * Pose2(0.01, 0.001 * std::sin(0.05 * k), 0.004 + 0.003 * std::cos(0.03 * k));
  }
  return odo;
}

// The link [t0, t2] against the two links [t0, t1], [t1, t2] composed: same relative pose, and
// the composed covariance A S01 A^T + B S12 B^T equals S02 (the information is unchanged).
void ExpectSplitPreservesInformation(const ContinuousPoseSource& src, int64_t t0, int64_t t1,
                                     int64_t t2, double rel_tol) {
  const auto whole = src.Between(t0, t2);
  const auto first = src.Between(t0, t1);
  const auto second = src.Between(t1, t2);
  ASSERT_TRUE(whole && first && second);
  const Pose2 composed = first->delta * second->delta;
  EXPECT_NEAR(composed.x, whole->delta.x, 1e-9);
  EXPECT_NEAR(composed.y, whole->delta.y, 1e-9);
  EXPECT_NEAR(WrapAngle(composed.theta - whole->delta.theta), 0, 1e-9);
  Eigen::Matrix3d a, b;
  ComposeJacobians(first->delta, second->delta, &a, &b);
  const Eigen::Matrix3d cov =
      a * first->covariance * a.transpose() + b * second->covariance * b.transpose();
  const Eigen::Matrix3d info_whole = whole->covariance.inverse();
  const Eigen::Matrix3d info_split = cov.inverse();
  EXPECT_LT((info_split - info_whole).norm(), rel_tol * info_whole.norm())
      << "whole:\n"
      << info_whole << "\nsplit:\n"
      << info_split;
}

TEST(PoseGraphSources, OdometrySplitAtASampleKeepsTheInformationExactly) {
  const OdometrySource odo = MakeOdometry();
  ExpectSplitPreservesInformation(odo, 1'100'000, 1'500'000, 3'000'000, 1e-9);
  ExpectSplitPreservesInformation(odo, 2'000'000, 2'020'000, 9'000'000, 1e-9);
}

TEST(PoseGraphSources, OdometrySplitBetweenSamplesKeepsTheInformationToFirstOrder) {
  const OdometrySource odo = MakeOdometry();
  ExpectSplitPreservesInformation(odo, 1'105'000, 1'517'000, 3'003'000, 1e-3);
}

TEST(PoseGraphSources, NullMotionSplitKeepsTheInformationExactly) {
  const NullMotionSource null_motion(0.01, 0.001);
  ExpectSplitPreservesInformation(null_motion, 0, 300'000, 1'000'000, 1e-12);
  EXPECT_FALSE(null_motion.Between(10, 5));
}

TEST(PoseGraphSources, OdometryOutsideItsDataIsUnavailable) {
  const OdometrySource odo = MakeOdometry();
  EXPECT_FALSE(odo.Between(900'000, 1'100'000));
  EXPECT_FALSE(odo.Between(10'000'000, 11'000'001));
  OdometrySource o2;
  EXPECT_TRUE(o2.AddSample(10, Pose2()));
  EXPECT_FALSE(o2.AddSample(5, Pose2()));  // out of order: rejected, the caller counts it
}

TEST(PoseGraphGyro, IntegratesTheRateLinearBetweenSamples) {
  GyroYawSource gyro;
  // 100 Hz, rate ramping from 0 to 1 rad/s over 2 s: the heading is t^2 / 4 exactly.
  for (int k = 0; k <= 200; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, 0.005 * k));
  const auto whole = gyro.Between(0, 2'000'000);
  ASSERT_TRUE(whole);
  EXPECT_NEAR(whole->delta_rad, 1.0, 1e-12);
  // Between samples (t = 0.5 s to 1.255 s): the rate is interpolated, so still exact.
  const auto part = gyro.Between(500'000, 1'255'000);
  ASSERT_TRUE(part);
  EXPECT_NEAR(part->delta_rad, (1.255 * 1.255 - 0.25) / 4.0, 1e-12);
  EXPECT_GT(part->variance, 0.0);
  EXPECT_LT(part->variance, whole->variance);
  EXPECT_FALSE(gyro.Between(-1, 10));            // before the first sample
  EXPECT_FALSE(gyro.Between(0, 2'000'001));      // after the last
  EXPECT_FALSE(gyro.AddSample(2'000'000, 0.0));  // repeated time
  EXPECT_FALSE(gyro.AddSample(1'000'000, 0.0));  // older
  EXPECT_FALSE(gyro.AddSample(3'000'000, std::nan("")));
  EXPECT_EQ(gyro.size(), 201u);
}

// The IMU away for 2 s while the base turned 60 degrees: the straight line between the rates
// at the gap's ends (both 0) measured no turn, with a variance small enough to outweigh the
// odometry's heading (review finding). A gap inside an interval leaves it uncovered.
TEST(PoseGraphGyro, AGapInTheSamplesIsNotMeasured) {
  GyroYawSource gyro;
  for (int k = 0; k <= 100; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, 0.0));    // 0 to 1 s
  for (int k = 300; k <= 400; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, 0.0));  // 3 to 4 s
  EXPECT_TRUE(gyro.Between(0, 1'000'000));
  EXPECT_TRUE(gyro.Between(3'000'000, 4'000'000));
  EXPECT_FALSE(gyro.Between(500'000, 3'500'000));  // across the gap
  EXPECT_FALSE(gyro.Between(1'000'000, 3'000'000));
  EXPECT_FALSE(gyro.Between(1'500'000, 1'600'000));  // inside it
  // A slow IMU's own spacing is no gap (2 Hz with 30 ms of read-time jitter, 1 Hz); three
  // times its recent spacing is.
  for (const int64_t period : {500'000, 1'000'000}) {
    GyroYawSource slow;
    int64_t end = 0;
    for (int k = 0; k <= 20; ++k) {
      end = k * period + (k % 2 ? 30'000 : -30'000) * (k > 0);
      EXPECT_TRUE(slow.AddSample(end, 1.0));
    }
    ASSERT_TRUE(slow.Between(0, end)) << period;
    EXPECT_NEAR(slow.Between(0, end)->delta_rad, 1e-6 * static_cast<double>(end), 1e-9);
    EXPECT_TRUE(slow.AddSample(end + 4 * period, 1.0));
    EXPECT_FALSE(slow.Between(end - 1, end + 1)) << period;
  }
}

// One sample stamped an hour ahead: the five in-order samples after it re-base the gyro, so
// the heading over later intervals is integrated from real samples, not toward the future one.
TEST(PoseGraphGyro, AFutureStampedSampleIsDroppedAfterFiveInOrder) {
  GyroYawSource gyro;
  for (int k = 0; k <= 100; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, 0.5));
  EXPECT_TRUE(gyro.AddSample(3'600'000'000LL, 50.0));
  for (int k = 101; k <= 104; ++k) EXPECT_FALSE(gyro.AddSample(10'000 * k, 0.5));
  EXPECT_EQ(gyro.rebases(), 0);
  EXPECT_TRUE(gyro.AddSample(1'050'000, 0.5));
  EXPECT_EQ(gyro.rebases(), 1);
  for (int k = 106; k <= 200; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, 0.5));
  const auto y = gyro.Between(0, 2'000'000);
  ASSERT_TRUE(y);
  EXPECT_NEAR(y->delta_rad, 1.0, 1e-9);  // 0.5 rad/s for 2 s (AClockSetBack... below checks
                                         // that the held samples are taken)
}

// The clock set back by 1.5 s (a reboot, an NTP step) while the base turns the other way: once
// five samples re-base the gyro, the history holds only the new time line from the run's first
// sample on — none of the old samples stamped inside the new run stays between them.
TEST(PoseGraphGyro, AClockSetBackKeepsNoOldSampleInsideTheNewRun) {
  GyroYawSource gyro;
  for (int k = 0; k <= 200; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, 0.5));
  for (int k = 50; k <= 53; ++k) EXPECT_FALSE(gyro.AddSample(10'000 * k, -1.0));  // held
  EXPECT_TRUE(gyro.AddSample(540'000, -1.0));
  EXPECT_EQ(gyro.rebases(), 1);
  for (int k = 55; k <= 80; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, -1.0));
  const auto turned = gyro.Between(500'000, 800'000);
  ASSERT_TRUE(turned);
  EXPECT_NEAR(turned->delta_rad, -0.3, 1e-9);  // -1 rad/s for 0.3 s, the held run included
  const auto before = gyro.Between(0, 490'000);
  ASSERT_TRUE(before);
  EXPECT_NEAR(before->delta_rad, 0.245, 1e-9);  // the old line before the run is kept
}

TEST(PoseGraphGyro, BiasIsRemoved) {
  GyroYawSource gyro(GyroNoise{}, 0.02);
  for (int k = 0; k <= 100; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, 0.02));
  EXPECT_NEAR(gyro.Between(0, 1'000'000)->delta_rad, 0.0, 1e-15);
}

// set_bias applies to every interval read afterwards, including those before it was set: the
// samples are kept as measured (what a bias learned standing still needs).
TEST(PoseGraphGyro, ABiasSetLaterAppliesToEveryInterval) {
  GyroYawSource gyro(GyroNoise{}, 0.01);
  for (int k = 0; k <= 100; ++k) EXPECT_TRUE(gyro.AddSample(10'000 * k, 0.004));
  EXPECT_NEAR(*gyro.RawBetween(0, 1'000'000), 0.004, 1e-15);
  EXPECT_NEAR(gyro.Between(0, 1'000'000)->delta_rad, -0.006, 1e-15);
  gyro.set_bias(0.004);
  EXPECT_NEAR(gyro.Between(0, 1'000'000)->delta_rad, 0.0, 1e-15);
  EXPECT_FALSE(gyro.RawBetween(0, 1'000'001));
}

// Odometry whose heading over-reads every turn by 8 % (an omni base's wheels slip when it
// turns), and a gyro that measures the true rate.
struct BiasedOdometryAndGyro {
  OdometrySource odometry;
  GyroYawSource gyro{GyroNoise{1e-7, 1e-6}};
  Pose2 truth_end;
  BiasedOdometryAndGyro() {
    Pose2 truth, odo;
    const double rate = 0.3;  // rad/s, 0.2 m/s forward
    for (int k = 0; k <= 500; ++k) {
      const int64_t t = 20'000 * k;
      EXPECT_TRUE(odometry.AddSample(t, odo));
      for (int j = 0; j < 2; ++j) EXPECT_TRUE(gyro.AddSample(t + 10'000 * j, rate));
      truth_end = truth;  // the pose at the last sample (10 s) in the end
      const Pose2 step(0.2 * 0.02, 0.0, rate * 0.02);
      truth = truth * step;
      odo = odo * Pose2(step.x, step.y, 1.08 * step.theta);
    }
  }
};

TEST(PoseGraphGyro, FusedHeadingFollowsTheGyroAndTheTranslationFollowsIt) {
  const BiasedOdometryAndGyro d;
  const OdometryGyroSource fused(&d.odometry, &d.gyro);
  const auto odo_only = d.odometry.Between(0, 10'000'000);
  const auto both = fused.Between(0, 10'000'000);
  ASSERT_TRUE(odo_only && both);
  // Odometry alone: 3 rad turned reads 3.24 rad, and the end point is off with it.
  EXPECT_NEAR(odo_only->delta.theta, WrapAngle(1.08 * 3.0), 1e-9);
  const double odo_err =
      std::hypot(odo_only->delta.x - d.truth_end.x, odo_only->delta.y - d.truth_end.y);
  const double fused_err = std::hypot(both->delta.x - d.truth_end.x, both->delta.y - d.truth_end.y);
  EXPECT_GT(odo_err, 0.05);
  EXPECT_LT(fused_err, 0.1 * odo_err);
  EXPECT_NEAR(WrapAngle(both->delta.theta - d.truth_end.theta), 0.0, 0.01);
  // The fused heading is more certain than either source alone.
  EXPECT_LT(both->covariance(2, 2), odo_only->covariance(2, 2));
  EXPECT_EQ(fused.gyro_missing_steps(), 0u);
  EXPECT_GT(fused.gyro_fused_steps(), 0u);
}

TEST(PoseGraphGyro, FusedSplitAtASampleKeepsTheInformationExactly) {
  const BiasedOdometryAndGyro d;
  const OdometryGyroSource fused(&d.odometry, &d.gyro);
  ExpectSplitPreservesInformation(fused, 100'000, 500'000, 3'000'000, 1e-9);
}

TEST(PoseGraphGyro, StepsWithoutGyroUseTheOdometryAloneAndAreCounted) {
  OdometrySource odometry = MakeOdometry();  // 1 s .. 11 s
  GyroYawSource gyro;
  for (int k = 0; k <= 100; ++k) EXPECT_TRUE(gyro.AddSample(1'000'000 + 10'000 * k, 0.0));
  const OdometryGyroSource fused(&odometry, &gyro);  // gyro covers 1 s .. 2 s only
  const auto later = fused.Between(3'000'000, 4'000'000);
  const auto plain = odometry.Between(3'000'000, 4'000'000);
  ASSERT_TRUE(later && plain);
  EXPECT_EQ(fused.gyro_missing_steps(), 50u);
  EXPECT_NEAR(later->delta.x, plain->delta.x, 1e-15);
  EXPECT_NEAR(later->delta.theta, plain->delta.theta, 1e-15);
  EXPECT_FALSE(fused.Between(0, 2'000'000));  // the odometry does not cover it
}

TEST(PoseGraphTrajectory, OnePosePerTimestampAndConsecutivePosesLinked) {
  const OdometrySource odo = MakeOdometry();
  Trajectory traj(&odo, /*merge_tolerance_us=*/100);
  std::vector<int64_t> times = {1'000'000, 2'000'000, 3'000'000, 4'500'000};
  std::vector<int> ids;
  for (int64_t t : times) {
    auto id = traj.PoseAt(t);
    ASSERT_TRUE(id.ok()) << id.error().message;
    ids.push_back(*id);
  }
  EXPECT_EQ(*traj.PoseAt(2'000'000), ids[1]);
  EXPECT_EQ(*traj.PoseAt(2'000'050), ids[1]);  // within the merge tolerance
  EXPECT_EQ(traj.size(), 4u);
  const auto links = traj.Links();
  ASSERT_EQ(links.size(), 3u);
  for (size_t i = 0; i < links.size(); ++i) {
    EXPECT_EQ(links[i].from_id, ids[i]);
    EXPECT_EQ(links[i].to_id, ids[i + 1]);
  }
  // Estimates are chained from the odometry.
  const Pose2 rel = traj.Estimate(ids[0])->Between(*traj.Estimate(ids[3]));
  const auto direct = odo.Between(times[0], times[3]);
  EXPECT_NEAR(rel.x, direct->delta.x, 1e-9);
  EXPECT_NEAR(rel.y, direct->delta.y, 1e-9);
}

TEST(PoseGraphTrajectory, SplicingReplacesOneLinkByTwoWithoutDoubleCounting) {
  const OdometrySource odo = MakeOdometry();
  Trajectory traj(&odo);
  const int a = *traj.PoseAt(1'200'000);
  const int c = *traj.PoseAt(4'000'000);
  const LinkFactor old_link = traj.Links().at(0);
  const int b = *traj.PoseAt(2'600'000);  // a late measurement inside [a, c]
  EXPECT_EQ(traj.splices(), 1);
  const auto links = traj.Links();
  ASSERT_EQ(links.size(), 2u);  // the old link is gone, two new ones
  EXPECT_EQ(links[0].from_id, a);
  EXPECT_EQ(links[0].to_id, b);
  EXPECT_EQ(links[1].from_id, b);
  EXPECT_EQ(links[1].to_id, c);
  Eigen::Matrix3d ja, jb;
  ComposeJacobians(links[0].motion.delta, links[1].motion.delta, &ja, &jb);
  const Eigen::Matrix3d cov = ja * links[0].motion.covariance * ja.transpose() +
                              jb * links[1].motion.covariance * jb.transpose();
  EXPECT_LT((cov.inverse() - old_link.motion.covariance.inverse()).norm(),
            1e-9 * old_link.motion.covariance.inverse().norm());
  // A pose before the first one is linked to it, not spliced.
  const int z = *traj.PoseAt(1'050'000);
  EXPECT_EQ(traj.splices(), 1);
  EXPECT_EQ(traj.Links().front().from_id, z);
  EXPECT_EQ(traj.Links().front().to_id, a);
}

TEST(PoseGraphTrajectory, UnavailableSourceLeavesTheTrajectoryUnchanged) {
  const OdometrySource odo = MakeOdometry();
  Trajectory traj(&odo);
  ASSERT_TRUE(traj.PoseAt(2'000'000).ok());
  auto r = traj.PoseAt(20'000'000);  // odometry ends at 11 s
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kUnavailable);
  EXPECT_EQ(traj.size(), 1u);
  EXPECT_TRUE(traj.Links().empty());
}

TEST(PoseGraphTrajectory, ExportedGraphOptimisesToTheOdometryChain) {
  const OdometrySource odo = MakeOdometry();
  Trajectory traj(&odo);
  for (int64_t t = 1'000'000; t <= 10'000'000; t += 500'000) ASSERT_TRUE(traj.PoseAt(t).ok());
  io::PoseGraph g = traj.ToPoseGraph();
  EXPECT_EQ(g.vertices2.size(), traj.size());
  EXPECT_EQ(g.edges2.size(), traj.size() - 1);
  BatchOptions o;
  o.initialization = Initialization::kNone;
  auto r = OptimizeGraph(&g, o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_LT(r->chi2_final, 1e-9);  // a chain has no conflicts
}

TEST(PoseGraphQueue, MeasurementsWaitForTheWindowAndLateOnesAreFlagged) {
  MeasurementQueue<std::string> q(/*window_us=*/100'000);
  q.Push(1'000'000, "scan1");
  q.Push(1'050'000, "scan2");
  int late = -1;
  EXPECT_TRUE(q.PopCommitted(1'080'000, &late).empty());
  auto out = q.PopCommitted(1'120'000, &late);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].second, "scan1");
  EXPECT_EQ(late, 0);
  q.Push(990'000, "very late");  // older than what was already committed
  out = q.PopCommitted(1'200'000, &late);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].second, "very late");  // in time order
  EXPECT_EQ(out[1].second, "scan2");
  EXPECT_EQ(late, 1);
  EXPECT_EQ(q.pending(), 0u);
}

}  // namespace
}  // namespace omni::pgm
