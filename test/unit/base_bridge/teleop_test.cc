#include "omni/base_bridge/teleop.h"

#include <string>

#include <gtest/gtest.h>

#include "omni/base_bridge/messages.h"

namespace omni::base_bridge {
namespace {

TEST(Teleop, KeysStepTheTwistWithinItsLimitsAndStopOnSpace) {
  const TeleopOptions o;
  TeleopTwist t;
  for (char c : std::string("wwwaq")) EXPECT_EQ(ApplyTeleopKey(c, o, &t), TeleopAction::kTwist);
  EXPECT_NEAR(t.vx_m_s, 0.3, 1e-12);
  EXPECT_NEAR(t.vy_m_s, 0.1, 1e-12);
  EXPECT_NEAR(t.omega_rad_s, 0.2, 1e-12);
  for (char c : std::string("ddee")) ApplyTeleopKey(c, o, &t);
  EXPECT_NEAR(t.vy_m_s, -0.1, 1e-12);
  EXPECT_NEAR(t.omega_rad_s, -0.2, 1e-12);
  for (int i = 0; i < 30; ++i) ApplyTeleopKey('s', o, &t);
  EXPECT_EQ(t.vx_m_s, -o.max_linear_m_s) << "clamped";
  for (int i = 0; i < 30; ++i) ApplyTeleopKey('q', o, &t);
  EXPECT_EQ(t.omega_rad_s, o.max_angular_rad_s);
  EXPECT_EQ(ApplyTeleopKey(' ', o, &t), TeleopAction::kTwist);
  EXPECT_EQ(t.vx_m_s, 0);
  EXPECT_EQ(t.vy_m_s, 0);
  EXPECT_EQ(t.omega_rad_s, 0);
}

TEST(Teleop, EstopZeroesClearFaultsKeepsUnknownKeysDoNothingAndEscQuits) {
  const TeleopOptions o;
  TeleopTwist t;
  ApplyTeleopKey('w', o, &t);
  EXPECT_EQ(ApplyTeleopKey('x', o, &t), TeleopAction::kNone);
  EXPECT_EQ(ApplyTeleopKey('\n', o, &t), TeleopAction::kNone);
  EXPECT_NEAR(t.vx_m_s, 0.1, 1e-12);
  EXPECT_EQ(ApplyTeleopKey('c', o, &t), TeleopAction::kClearFaults);
  EXPECT_NEAR(t.vx_m_s, 0.1, 1e-12);
  EXPECT_EQ(ApplyTeleopKey('!', o, &t), TeleopAction::kEstop);
  EXPECT_EQ(t.vx_m_s, 0);
  ApplyTeleopKey('w', o, &t);
  EXPECT_EQ(ApplyTeleopKey(27, o, &t), TeleopAction::kQuit);
  EXPECT_EQ(t.vx_m_s, 0);
  EXPECT_EQ(ApplyTeleopKey(3, o, &t), TeleopAction::kQuit);
  EXPECT_EQ(ApplyTeleopKey(4, o, &t), TeleopAction::kQuit);
}

// BASE_CMD as the bridge (and the simulator) read it: the three modes, and an unknown one made
// invalid so that the bridge refuses it.
TEST(BaseCmd, FromMessageKeepsTheModesAndMarksUnknownOnes) {
  omni::base_cmd_t m{};
  m.mode = omni::base_cmd_t::MODE_TWIST;
  m.vx_m_s = 0.5;
  m.vy_m_s = -0.25;
  m.omega_rad_s = 1.0;
  Command c = FromMessage(m);
  EXPECT_EQ(c.mode, Command::kTwist);
  EXPECT_EQ(c.vx_m_s, 0.5);
  EXPECT_EQ(c.vy_m_s, -0.25);
  EXPECT_EQ(c.omega_rad_s, 1.0);
  m.mode = omni::base_cmd_t::MODE_ESTOP;
  EXPECT_EQ(FromMessage(m).mode, Command::kEstop);
  m.mode = omni::base_cmd_t::MODE_CLEAR_FAULTS;
  EXPECT_EQ(FromMessage(m).mode, Command::kClearFaults);
  for (int8_t bad : {int8_t{3}, int8_t{-1}, int8_t{100}}) {
    m.mode = bad;
    EXPECT_EQ(FromMessage(m).mode, Command::kInvalid) << int{bad};
  }
}

}  // namespace
}  // namespace omni::base_bridge
