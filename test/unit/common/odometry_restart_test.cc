// OdometryRestartBridge: a restarted odometry source's poses continue from where it stopped.
#include "omni/common/odometry_restart.h"

#include <gtest/gtest.h>

namespace omni {
namespace {

void ExpectPose(const Pose2& p, double x, double y, double theta) {
  EXPECT_NEAR(p.x, x, 1e-9);
  EXPECT_NEAR(p.y, y, 1e-9);
  EXPECT_NEAR(p.theta, theta, 1e-9);
}

TEST(OdometryRestartBridge, ARestartContinuesFromTheLastPose) {
  OdometryRestartBridge b;
  ExpectPose(b.Take(1, Pose2(0, 0, 0)), 0, 0, 0);
  ExpectPose(b.Take(500, Pose2(2.0, 1.0, 0.5)), 2.0, 1.0, 0.5);  // numbers may skip: lost
  // The source restarts: origin, seq 1. Below the mappers' 3 m jump limit, so they would
  // have taken the 2.2 m step back for motion.
  ExpectPose(b.Take(1, Pose2(0, 0, 0)), 2.0, 1.0, 0.5);
  EXPECT_EQ(b.restarts(), 1);
  // 0.1 m ahead in the new source's frame is 0.1 m ahead along the old heading.
  ExpectPose(b.Take(2, Pose2(0.1, 0, 0)), 2.0 + 0.1 * std::cos(0.5), 1.0 + 0.1 * std::sin(0.5),
             0.5);
}

TEST(OdometryRestartBridge, LateSamplesAndUnnumberedOnesAreNotRestarts) {
  OdometryRestartBridge b;
  b.Take(10, Pose2(1.00, 0, 0));
  b.Take(12, Pose2(1.02, 0, 0));
  ExpectPose(b.Take(11, Pose2(1.01, 0, 0)), 1.01, 0, 0);  // reordered on the bus
  EXPECT_EQ(b.restarts(), 0);
  ExpectPose(b.Take(13, Pose2(1.03, 0, 0)), 1.03, 0, 0);
  ExpectPose(b.Take(-1, Pose2(0, 0, 0)), 0, 0, 0);  // unnumbered: handed on as it is
  EXPECT_EQ(b.restarts(), 0);
}

// A restart near where the source began (the base parked at its start point) is a restart too,
// and the samples after it go on from the last pose: classed as late by their nearness, they
// once left the newest number behind, and a later sample 0.11 m on was taken for a restart
// that put every pose after it 0.11 m off (review finding).
TEST(OdometryRestartBridge, ARestartNearTheOldPoseStaysContinuous) {
  OdometryRestartBridge b;
  b.Take(100, Pose2(0.05, 0, 0));
  ExpectPose(b.Take(1, Pose2(0, 0, 0)), 0.05, 0, 0);
  ExpectPose(b.Take(2, Pose2(0.08, 0, 0)), 0.13, 0, 0);
  ExpectPose(b.Take(3, Pose2(0.16, 0, 0)), 0.21, 0, 0);
  ExpectPose(b.Take(4, Pose2(0.30, 0, 0)), 0.35, 0, 0);
  EXPECT_EQ(b.restarts(), 1);
}

// A dying source's last sample was NaN (or absurd), then it restarted: laid on from that
// pose, every pose after the restart was NaN and all odometry was refused until the mapper
// restarted (review finding). The bad sample is handed on for the mapper to refuse.
TEST(OdometryRestartBridge, ABadPoseBeforeARestartDoesNotSpoilThePosesAfterIt) {
  for (const Pose2& bad : {Pose2(NAN, 0, 0), Pose2(1e232, 0, 0)}) {
    OdometryRestartBridge b;
    b.Take(4999, Pose2(2.0, 1.0, 0.5));
    EXPECT_FALSE(PlausibleOdometryPose(b.Take(5000, bad)));
    ExpectPose(b.Take(0, Pose2(0, 0, 0)), 2.0, 1.0, 0.5);
    EXPECT_EQ(b.restarts(), 1);
    ExpectPose(b.Take(1, Pose2(0.1, 0, 0)), 2.0 + 0.1 * std::cos(0.5), 1.0 + 0.1 * std::sin(0.5),
               0.5);
  }
}

}  // namespace
}  // namespace omni
