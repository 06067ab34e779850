#include "omni/common/kinematics.h"

#include <random>

#include <gtest/gtest.h>

namespace omni::kinematics {
namespace {

const auto kGeom = SymmetricGeometry<double>(0.2, 0.05);

TEST(Kinematics, HandWorkedCaseEq1) {
  // alpha = 120 deg: sin(60) = 0.8660, cos(60) = 0.5, L = 0.2.
  WheelSpeeds<double> w = BodyToWheels(kGeom, BodyTwist<double>{1.0, 0.0, 0.0});
  EXPECT_NEAR(w.v_m_s[0], 0.8660254, 1e-6);
  EXPECT_NEAR(w.v_m_s[1], -0.8660254, 1e-6);
  EXPECT_NEAR(w.v_m_s[2], 0.0, 1e-12);
  w = BodyToWheels(kGeom, BodyTwist<double>{0.0, 1.0, 0.0});
  EXPECT_NEAR(w.v_m_s[0], 0.5, 1e-12);
  EXPECT_NEAR(w.v_m_s[1], 0.5, 1e-12);
  EXPECT_NEAR(w.v_m_s[2], -1.0, 1e-12);
  w = BodyToWheels(kGeom, BodyTwist<double>{0.0, 0.0, 2.0});
  for (double v : w.v_m_s) EXPECT_NEAR(v, 0.4, 1e-12);
  // A combined case: (0.3, -0.2, 0.5) -> v1 = 0.3*0.8660 - 0.2*0.5 + 0.1 = 0.2598
  w = BodyToWheels(kGeom, BodyTwist<double>{0.3, -0.2, 0.5});
  EXPECT_NEAR(w.v_m_s[0], 0.3 * 0.8660254038 - 0.1 + 0.1, 1e-9);
  EXPECT_NEAR(w.v_m_s[1], -0.3 * 0.8660254038 - 0.1 + 0.1, 1e-9);
  EXPECT_NEAR(w.v_m_s[2], 0.2 + 0.1, 1e-9);
}

TEST(Kinematics, Eq3IsEq1RotatedByTheta) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-2.0, 2.0), th(-M_PI, M_PI);
  for (int i = 0; i < 1000; ++i) {
    const double theta = th(rng);
    const WorldVelocity<double> world{u(rng), u(rng), u(rng)};
    const WheelSpeeds<double> via3 = WorldToWheels(kGeom, theta, world);
    const WheelSpeeds<double> via1 = BodyToWheels(kGeom, WorldToBody(theta, world));
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(via3.v_m_s[k], via1.v_m_s[k], 1e-12);
  }
}

TEST(Kinematics, InverseThenForwardIsIdentity) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-3.0, 3.0), th(-M_PI, M_PI);
  for (int i = 0; i < 1000; ++i) {
    const double theta = th(rng);
    const WorldVelocity<double> world{u(rng), u(rng), u(rng)};
    const WheelSpeeds<double> w = WorldToWheels(kGeom, theta, world);
    BodyTwist<double> body;
    ASSERT_TRUE(WheelsToBody(kGeom, w, &body));
    const WorldVelocity<double> back = BodyToWorld(theta, body);
    EXPECT_NEAR(back.xdot_m_s, world.xdot_m_s, 1e-9);
    EXPECT_NEAR(back.ydot_m_s, world.ydot_m_s, 1e-9);
    EXPECT_NEAR(back.thetadot_rad_s, world.thetadot_rad_s, 1e-9);
  }
}

TEST(Kinematics, FloatInstantiationForFirmware) {
  const auto g = SymmetricGeometry<float>(0.2f, 0.05f);
  const WheelSpeeds<float> w = BodyToWheels(g, BodyTwist<float>{0.5f, 0.25f, -1.0f});
  BodyTwist<float> b;
  ASSERT_TRUE(WheelsToBody(g, w, &b));
  EXPECT_NEAR(b.vx_m_s, 0.5f, 1e-5f);
  EXPECT_NEAR(b.vy_m_s, 0.25f, 1e-5f);
  EXPECT_NEAR(b.omega_rad_s, -1.0f, 1e-5f);
}

TEST(Kinematics, DegenerateGeometryIsRejected) {
  OmniGeometry<double> g{0.0, 0.2, 0.05};  // wheels 1 and 2 coincide
  BodyTwist<double> b{9, 9, 9};
  EXPECT_FALSE(WheelsToBody(g, WheelSpeeds<double>{{1, 1, 1}}, &b));
  EXPECT_EQ(b.vx_m_s, 9);
}

}  // namespace
}  // namespace omni::kinematics
