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
  // A restart near where the source began is a small step: handed on (harmless).
  OdometryRestartBridge near;
  near.Take(100, Pose2(0.05, 0, 0));
  ExpectPose(near.Take(1, Pose2(0, 0, 0)), 0, 0, 0);
  EXPECT_EQ(near.restarts(), 0);
}

}  // namespace
}  // namespace omni
