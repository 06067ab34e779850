#include "omni/common/geometry.h"
#include "omni/common/scan_checks.h"

#include <gtest/gtest.h>

namespace omni {
namespace {

TEST(Geometry, WrapAngle) {
  EXPECT_NEAR(WrapAngle(3 * M_PI), M_PI, 1e-12);
  EXPECT_NEAR(WrapAngle(-M_PI), M_PI, 1e-12);
  EXPECT_NEAR(WrapAngle(0.5), 0.5, 1e-12);
  EXPECT_NEAR(WrapAngle(-7.0), -7.0 + 2 * M_PI, 1e-12);
}

TEST(Geometry, ComposeInverseBetween) {
  const Pose2 a(1, 2, 0.5), b(-0.3, 0.7, -2.0);
  const Pose2 id = a * a.Inverse();
  EXPECT_NEAR(id.x, 0, 1e-12);
  EXPECT_NEAR(id.y, 0, 1e-12);
  EXPECT_NEAR(id.theta, 0, 1e-12);
  const Pose2 c = a * a.Between(b);
  EXPECT_NEAR(c.x, b.x, 1e-12);
  EXPECT_NEAR(c.y, b.y, 1e-12);
  EXPECT_NEAR(c.theta, b.theta, 1e-12);
  // (1,0) seen from a pose at (1,2) heading 90 deg is at (1,3).
  const auto p = Pose2(1, 2, M_PI / 2).Transform({1, 0});
  EXPECT_NEAR(p.x(), 1, 1e-12);
  EXPECT_NEAR(p.y(), 3, 1e-12);
}

TEST(Geometry, InterpolateTakesShortestArc) {
  const Pose2 m = Interpolate(Pose2(0, 0, 3.0), Pose2(2, 4, -3.0), 0.5);
  EXPECT_NEAR(m.x, 1, 1e-12);
  EXPECT_NEAR(m.y, 2, 1e-12);
  EXPECT_NEAR(std::fabs(m.theta), M_PI, 1e-9);
}

TEST(Geometry, StampedBufferInterpolatesAndRejectsOutOfOrder) {
  StampedBuffer<Pose2> buf;
  EXPECT_TRUE(buf.Insert(1000, Pose2(0, 0, 0)));
  EXPECT_TRUE(buf.Insert(2000, Pose2(1, 0, 0.2)));
  EXPECT_FALSE(buf.Insert(1500, Pose2(5, 5, 5)));
  auto p = buf.At(1250);
  ASSERT_TRUE(p);
  EXPECT_NEAR(p->x, 0.25, 1e-12);
  EXPECT_NEAR(p->theta, 0.05, 1e-12);
  EXPECT_FALSE(buf.At(2600, 500));
  EXPECT_TRUE(buf.At(2400, 500));
  EXPECT_FALSE(buf.At(100, 0));
}

// One sample stamped an hour ahead must not shut the stream out: after five in-order samples
// older than it, the buffer drops it and keeps the five (nothing of the real stream is lost).
TEST(Geometry, StampedBufferRecoversFromAFutureStamp) {
  StampedBuffer<Pose2> buf;
  for (int i = 0; i < 10; ++i) EXPECT_TRUE(buf.Insert(i * 1000, Pose2(i, 0, 0)));
  EXPECT_TRUE(buf.Insert(3600000000LL, Pose2(99, 99, 0)));  // the glitch
  for (int i = 10; i < 14; ++i) EXPECT_FALSE(buf.Insert(i * 1000, Pose2(i, 0, 0)));
  EXPECT_EQ(buf.rebases(), 0);
  EXPECT_TRUE(buf.Insert(14000, Pose2(14, 0, 0)));  // fifth in a row: re-based
  EXPECT_EQ(buf.rebases(), 1);
  EXPECT_EQ(buf.dropped_on_rebase(), 1);
  EXPECT_EQ(buf.newest_utime(), 14000);
  EXPECT_EQ(buf.size(), 15u);
  auto p = buf.At(12500);
  ASSERT_TRUE(p);
  EXPECT_NEAR(p->x, 12.5, 1e-12);
  EXPECT_TRUE(buf.Insert(15000, Pose2(15, 0, 0)));
  // A single late sample stays a rejection, and so do runs broken by disorder.
  EXPECT_FALSE(buf.Insert(9500, Pose2(0, 0, 0)));
  for (int i = 0; i < 8; ++i) EXPECT_FALSE(buf.Insert(i % 2 ? 9000 : 8000, Pose2(0, 0, 0)));
  EXPECT_EQ(buf.rebases(), 1);
}

TEST(Geometry, StampedBufferListsTheSamplesStrictlyInsideAnInterval) {
  StampedBuffer<Pose2> buf;
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(buf.Insert(100 * i, Pose2(i, 0, 0)));
  const std::vector<Pose2> in = buf.Inside(100, 400);
  ASSERT_EQ(in.size(), 2u);
  EXPECT_EQ(in[0].x, 2.0);
  EXPECT_EQ(in[1].x, 3.0);
  EXPECT_EQ(buf.Inside(-50, 50).size(), 1u);
  EXPECT_EQ(buf.Inside(350, 1000).size(), 1u);
  EXPECT_TRUE(buf.Inside(400, 100).empty());
  EXPECT_TRUE(buf.Inside(110, 190).empty());
}

TEST(StampOrder, RebasesOnlyOnAConsistentRun) {
  StampOrder o(3);
  EXPECT_EQ(o.Check(100), StampOrder::Verdict::kInOrder);
  EXPECT_EQ(o.Check(100), StampOrder::Verdict::kInOrder);  // equal stamps are in order
  EXPECT_EQ(o.Check(50), StampOrder::Verdict::kOld);
  EXPECT_EQ(o.Check(40), StampOrder::Verdict::kOld);  // goes back within the run: new run
  EXPECT_EQ(o.Check(41), StampOrder::Verdict::kOld);
  EXPECT_EQ(o.run_length(), 2);
  EXPECT_EQ(o.Check(120), StampOrder::Verdict::kInOrder);  // an in-order stamp ends the run
  EXPECT_EQ(o.Check(60), StampOrder::Verdict::kOld);
  EXPECT_EQ(o.Check(61), StampOrder::Verdict::kOld);
  EXPECT_EQ(o.Check(62), StampOrder::Verdict::kRebase);  // the source's clock went back
  EXPECT_EQ(o.run_first(), 60);
  EXPECT_EQ(o.newest(), 62);
  EXPECT_EQ(o.rebases(), 1);
  EXPECT_EQ(o.Check(63), StampOrder::Verdict::kInOrder);
}

TEST(Geometry, Se3InterpolationSlerps) {
  Eigen::Isometry3d a = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d b = Eigen::Isometry3d::Identity();
  b.linear() = Eigen::AngleAxisd(1.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  b.translation() = Eigen::Vector3d(2, 0, 4);
  const auto m = Interpolate(a, b, 0.5);
  EXPECT_NEAR(Eigen::AngleAxisd(m.linear()).angle(), 0.5, 1e-12);
  EXPECT_TRUE(m.translation().isApprox(Eigen::Vector3d(1, 0, 2)));
}

}  // namespace
}  // namespace omni

namespace omni {
namespace {

TEST(ScanChecks, RealLidarsPassAbsurdGeometryDoesNot) {
  const Pose2 mount(0.1, 0.0, 0.0);
  EXPECT_TRUE(PlausibleScanGeometry(-M_PI / 2, M_PI / 180, 181, 81.9, mount));  // CARMEN SICK
  EXPECT_TRUE(PlausibleScanGeometry(0.0, 2 * M_PI / 1600, 1600, 25.0, mount));  // RPLidar
  EXPECT_TRUE(PlausibleScanGeometry(0.0, 0.0, 1, 25.0, mount));       // one beam: no increment
  EXPECT_FALSE(PlausibleScanGeometry(0.0, 0.0, 360, 25.0, mount));    // all beams alike
  EXPECT_FALSE(PlausibleScanGeometry(0.0, 1e30, 360, 25.0, mount));   // many revolutions
  EXPECT_FALSE(PlausibleScanGeometry(3e38, 0.01, 360, 25.0, mount));  // angle_min
  EXPECT_FALSE(PlausibleScanGeometry(0.0, NAN, 360, 25.0, mount));    // NaN increment
  EXPECT_FALSE(PlausibleScanGeometry(0.0, 0.01, 360, 1e5, mount));    // range limit
  EXPECT_FALSE(PlausibleScanGeometry(0.0, 0.01, 360, NAN, mount));    // NaN range limit
  EXPECT_FALSE(PlausibleScanGeometry(0.0, 0.01, 360, 25.0, Pose2(1e300, 0, 0)));  // mount
  EXPECT_FALSE(PlausibleScanGeometry(0.0, 1e-6, kMaxScanBeams + 1, 25.0, mount));
}

// Odometry poses: a base that has driven far or turned often passes; finite but absurd poses,
// at which a centimetre step rounds away, do not (found by the mapper_stream fuzz target: an
// odometry pose at 1e232 m froze the pose graph's odometry and its submap asked for an
// impossible likelihood field).
TEST(ScanChecks, OdometryPosesFarBeyondAnyRobotAreRefused) {
  EXPECT_TRUE(PlausibleOdometryPose(Pose2(0, 0, 0)));
  EXPECT_TRUE(PlausibleOdometryPose(Pose2(-250000.0, 999999.0, -3.1)));
  EXPECT_TRUE(PlausibleOdometryPose(Pose2(1.0, 2.0, 5000.0)));  // unwrapped heading
  EXPECT_FALSE(PlausibleOdometryPose(Pose2(1.7e232, -4.1e232, 0.13)));
  EXPECT_FALSE(PlausibleOdometryPose(Pose2(0, 2e6, 0)));
  EXPECT_FALSE(PlausibleOdometryPose(Pose2(0, 0, 1e300)));
  EXPECT_FALSE(PlausibleOdometryPose(Pose2(NAN, 0, 0)));
  EXPECT_FALSE(PlausibleOdometryPose(Pose2(0, -INFINITY, 0)));
  EXPECT_FALSE(PlausibleOdometryPose(Pose2(0, 0, NAN)));
}

}  // namespace
}  // namespace omni
