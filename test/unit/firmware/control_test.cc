// Speed loop on the plant: step response, tracking of twist commands, watchdog, e-stop, faults.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "firmware_harness.h"

namespace omni::firmware {
namespace {

using testing::Harness;

// The PID step response on the plant (acceleration ramp out of the way, so the loop itself is
// measured), settling into a 2 % band:
//   0 -> 20 rad/s (1 m/s at the rim; saturates the output: exercises the anti-windup)
//       within 160 ms, overshoot at most 2 %;
//   0 -> 5 rad/s (linear range) within 120 ms, overshoot at most 5 %.
struct StepCase {
  float target;
  int settle_ms;
  double max_overshoot;
};

class StepResponseTest : public ::testing::TestWithParam<StepCase> {};

TEST_P(StepResponseTest, SettlesWithoutOvershoot) {
  const StepCase c = GetParam();
  Params p;
  p.max_wheel_accel_rad_s2 = 10000.f;  // no ramp: raw PID step
  p.current_limit_a = 10.f;            // a saturated step draws ~6 A for a moment
  Harness h(p);
  ASSERT_TRUE(h.ok);
  double peak = 0.0;
  int settled_at = -1;
  for (int ms = 0; ms < 600; ++ms) {
    if (ms % 50 == 0) h.SendWheelSpeeds(c.target, -c.target, c.target);  // feed the watchdog
    h.Run(1);
    for (int w = 0; w < 3; ++w) {
      const double sign = w == 1 ? -1.0 : 1.0;
      peak = std::max(peak, sign * h.plant.WheelSpeed(w));
    }
    bool inside = true;
    for (int w = 0; w < 3; ++w) {
      const double sign = w == 1 ? -1.0 : 1.0;
      inside = inside && std::fabs(sign * h.plant.WheelSpeed(w) - c.target) < 0.02 * c.target;
    }
    if (inside && settled_at < 0) settled_at = ms;
    if (!inside) settled_at = -1;
  }
  EXPECT_EQ(h.fw.state(), State::kRunning);
  ASSERT_GE(settled_at, 0) << "never settled within 2 %";
  EXPECT_LE(settled_at, c.settle_ms) << "settling time (2 % band), ms";
  EXPECT_LE(peak, c.target * (1.0 + c.max_overshoot)) << "overshoot";
  std::printf(
      "step 0->%.0f rad/s: settled (2%%) after %d ms, peak %.3f rad/s (%.2f %% overshoot)\n",
      c.target, settled_at, peak, 100.0 * (peak / c.target - 1.0));
}
INSTANTIATE_TEST_SUITE_P(Steps, StepResponseTest,
                         ::testing::Values(StepCase{20.f, 160, 0.02}, StepCase{5.f, 120, 0.05}));

TEST(ControlTest, RampLimitsAcceleration) {
  Params p;  // 40 rad/s^2 default
  Harness h(p);
  h.SendWheelSpeeds(20.f, 20.f, 20.f);
  h.Run(100);
  EXPECT_NEAR(h.fw.wheel(0).setpoint_rad_s, 4.f, 0.05f);  // 100 ms * 40 rad/s^2
  EXPECT_NEAR(h.plant.WheelSpeed(0), 4.0, 0.6);
}

TEST(ControlTest, LowSpeedTracking) {
  Harness h;
  for (int ms = 0; ms < 3000; ++ms) {
    if (ms % 50 == 0) h.SendWheelSpeeds(0.5f, -0.5f, 0.5f);
    h.Run(1);
  }
  // 0.5 rad/s is ~115 counts/s: a count every ~9 ms.
  EXPECT_NEAR(h.plant.WheelSpeed(0), 0.5, 0.1);
  EXPECT_NEAR(h.fw.wheel(0).speed_rad_s, 0.5, 0.15);
  EXPECT_EQ(h.fw.fault_bits(), 0u);
}

TEST(ControlTest, TwistCommandUsesSharedKinematics) {
  Harness h;
  const float vx = 0.3f, vy = -0.2f, w = 0.5f;
  for (int ms = 0; ms < 2000; ++ms) {
    if (ms % 50 == 0) h.SendTwist(vx, vy, w);
    h.Run(1);
  }
  const auto g = omni::kinematics::SymmetricGeometry(0.15, 0.05);
  const auto rim =
      omni::kinematics::BodyToWheels(g, omni::kinematics::BodyTwist<double>{vx, vy, w});
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(h.fw.wheel(i).target_rad_s, rim.v_m_s[i] / 0.05, 1e-3);
    EXPECT_NEAR(h.plant.WheelSpeed(i), rim.v_m_s[i] / 0.05, 0.15);
  }
  const auto& t = h.fw.measured_twist();
  EXPECT_NEAR(t.vx_m_s, vx, 0.01);
  EXPECT_NEAR(t.vy_m_s, vy, 0.01);
  EXPECT_NEAR(t.omega_rad_s, w, 0.05);
}

TEST(ControlTest, CommandsAboveSpeedLimitAreScaledKeepingDirection) {
  Harness h;
  h.SendWheelSpeeds(70.f, -35.f, 0.f);  // limit 35 rad/s: scaled by 1/2
  h.Run(1);
  EXPECT_FLOAT_EQ(h.fw.wheel(0).target_rad_s, 35.f);
  EXPECT_FLOAT_EQ(h.fw.wheel(1).target_rad_s, -17.5f);
  EXPECT_EQ(h.fw.counters().commands_limited, 1u);
}

// The watchdog engages no later than watchdog_ms + one period after the last command was
// received, then brings the wheels to rest with the stop deceleration and disables them.
TEST(WatchdogTest, StopsWheelsAfterTimeout) {
  Harness h;
  for (int ms = 0; ms < 1000; ++ms) {
    if (ms % 20 == 0) h.SendWheelSpeeds(15.f, 15.f, 15.f);
    h.Run(1);
  }
  ASSERT_EQ(h.fw.state(), State::kRunning);
  // Last command: arrives now (during the coming period).
  h.SendWheelSpeeds(15.f, 15.f, 15.f);
  int tripped_at = -1;
  int stopped_at = -1;
  for (int ms = 1; ms <= 1000; ++ms) {
    h.Run(1);
    if (tripped_at < 0 && h.fw.state() == State::kStopping) tripped_at = ms;
    if (tripped_at >= 0 && stopped_at < 0 && h.fw.state() == State::kIdle) stopped_at = ms;
  }
  ASSERT_GT(tripped_at, 0);
  EXPECT_GE(tripped_at, 200);
  EXPECT_LE(tripped_at, 200 + 1) << "watchdog 200 ms + one 1 ms period";
  EXPECT_TRUE(h.fw.fault_bits() & kFaultWatchdog);
  // Controlled stop: 15 rad/s at 80 rad/s^2 is ~190 ms, plus settling.
  ASSERT_GT(stopped_at, 0);
  EXPECT_LE(stopped_at - tripped_at, 400);
  EXPECT_TRUE(h.MotorsOff());
  for (int w = 0; w < 3; ++w) EXPECT_NEAR(h.plant.WheelSpeed(w), 0.0, 0.3);
  EXPECT_EQ(h.fw.counters().watchdog_trips, 1u);
  // A new command clears the warning and drives again.
  h.SendWheelSpeeds(5.f, 5.f, 5.f);
  h.Run(1);
  EXPECT_EQ(h.fw.state(), State::kRunning);
  EXPECT_FALSE(h.fw.fault_bits() & kFaultWatchdog);
}

TEST(WatchdogTest, ConfigurableTimeout) {
  Params p;
  p.watchdog_ms = 50;
  Harness h(p);
  h.SendWheelSpeeds(5.f, 5.f, 5.f);
  h.Run(50);
  EXPECT_EQ(h.fw.state(), State::kRunning);
  h.Run(1);
  EXPECT_EQ(h.fw.state(), State::kStopping);
}

void DriveSteady(Harness* h, int ms = 500) {
  for (int i = 0; i < ms; ++i) {
    if (i % 20 == 0) h->SendWheelSpeeds(10.f, -10.f, 10.f);
    h->Run(1);
  }
  ASSERT_EQ(h->fw.state(), State::kRunning);
  ASSERT_FALSE(h->MotorsOff());
}

TEST(FaultTest, EstopStopsMotorsAndLatches) {
  Harness h;
  DriveSteady(&h);
  h.Send(can::EncodeEstop(1));
  h.Run(1);
  EXPECT_EQ(h.fw.state(), State::kEstop);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultEstop);
  EXPECT_TRUE(h.MotorsOff());
  // Motion commands are refused while latched.
  h.SendWheelSpeeds(10.f, 10.f, 10.f);
  h.Run(10);
  EXPECT_EQ(h.fw.state(), State::kEstop);
  EXPECT_TRUE(h.MotorsOff());
  h.Send(can::EncodeClearFaults(1));
  h.Run(1);
  EXPECT_EQ(h.fw.state(), State::kIdle);
  EXPECT_EQ(h.fw.fault_bits(), 0u);
  h.SendWheelSpeeds(10.f, 10.f, 10.f);
  h.Run(1);
  EXPECT_EQ(h.fw.state(), State::kRunning);
}

TEST(FaultTest, EncoderStallWhileDriven) {
  Harness h;
  DriveSteady(&h);
  h.plant.FreezeEncoder(2, true);  // encoder cable off: the loop drives harder, nothing moves
  for (int i = 0; i < 1000 && h.fw.state() == State::kRunning; ++i) {
    if (i % 20 == 0) h.SendWheelSpeeds(10.f, -10.f, 10.f);
    h.Run(1);
  }
  EXPECT_EQ(h.fw.state(), State::kFault);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultEncoderStall);
  EXPECT_TRUE(h.MotorsOff());
}

// Encoder A/B swapped on one wheel (the wiring mistake the bring-up's sign check looks for): the
// loop drives harder the faster the wheel turns. One command of +2 rad/s used to run the wheel
// to full duty and leave it there for good: the watchdog's stop ramps the setpoint to zero, which
// the reversed reading only pushes further. Now it is a latched RUNAWAY fault, motors off.
TEST(FaultTest, AReversedEncoderIsARunawayFaultNotAFullSpeedWheel) {
  Harness h;
  h.plant.ReverseEncoder(0, true);
  h.SendWheelSpeeds(2.f, 0.f, 0.f);
  int faulted_at = -1;
  double speed_at_fault = 0;
  for (int ms = 1; ms <= 3000; ++ms) {
    h.Run(1);
    if (faulted_at < 0 && h.fw.state() == State::kFault) {
      faulted_at = ms;
      speed_at_fault = h.plant.WheelSpeed(0);
    }
  }
  ASSERT_GT(faulted_at, 0) << "state " << static_cast<int>(h.fw.state()) << ", duty "
                           << h.fw.wheel(0).duty << ", wheel " << h.plant.WheelSpeed(0) << " rad/s";
  EXPECT_LE(faulted_at, 600) << "stall_ms (300) after the wheel passes 2 rad/s";
  EXPECT_TRUE(h.fw.fault_bits() & kFaultRunaway);
  EXPECT_TRUE(h.MotorsOff());
  EXPECT_LT(std::abs(h.plant.WheelSpeed(0)), 0.5 * std::abs(speed_at_fault))
      << "coasting with the motors off, from " << speed_at_fault << " rad/s";
  // Latched: a command does not drive it again until CLEAR_FAULTS, after which the same
  // wiring trips again.
  h.SendWheelSpeeds(2.f, 0.f, 0.f);
  h.Run(5);
  EXPECT_EQ(h.fw.state(), State::kFault);
  h.Send(can::EncodeClearFaults(1));
  h.Run(1);
  EXPECT_EQ(h.fw.state(), State::kIdle);
  h.SendWheelSpeeds(2.f, 0.f, 0.f);
  h.Run(1500);
  EXPECT_EQ(h.fw.state(), State::kFault);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultRunaway);
}

// With the runaway check out of reach (stall_duty 1.0 > max_duty), the stop after the watchdog
// has a deadline of its own: the ramp from the fastest setpoint (2 rad/s at 80 rad/s^2, 25 ms)
// plus 300 ms to settle. A wheel still turning then is switched off and latched, not left in
// STOPPING at full duty.
TEST(WatchdogTest, AStopThatDoesNotComeToRestByItsDeadlineIsARunawayFault) {
  Params p;
  p.stall_duty = 1.f;
  Harness h(p);
  h.plant.ReverseEncoder(0, true);
  h.SendWheelSpeeds(2.f, 0.f, 0.f);
  int tripped_at = -1, faulted_at = -1;
  for (int ms = 1; ms <= 3000; ++ms) {
    h.Run(1);
    if (tripped_at < 0 && h.fw.state() == State::kStopping) tripped_at = ms;
    if (faulted_at < 0 && h.fw.state() == State::kFault) faulted_at = ms;
  }
  ASSERT_GT(tripped_at, 0);
  ASSERT_GT(faulted_at, 0) << "still " << static_cast<int>(h.fw.state()) << " at 3 s";
  EXPECT_GE(faulted_at - tripped_at, 325);
  EXPECT_LE(faulted_at - tripped_at, 330);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultRunaway);
  EXPECT_TRUE(h.MotorsOff());
}

TEST(FaultTest, OverCurrentFromLockedWheel) {
  Harness h;
  DriveSteady(&h);
  h.plant.LockWheel(0, true);  // wheel jammed: current rises to V/R
  for (int i = 0; i < 300 && h.fw.state() == State::kRunning; ++i) {
    if (i % 20 == 0) h.SendWheelSpeeds(10.f, -10.f, 10.f);
    h.Run(1);
  }
  EXPECT_EQ(h.fw.state(), State::kFault);
  EXPECT_TRUE(h.fw.fault_bits() & (kFaultOverCurrent | kFaultEncoderStall));
  EXPECT_TRUE(h.MotorsOff());
}

TEST(FaultTest, OverCurrentFromSense) {
  Harness h;
  DriveSteady(&h);
  h.hal.OverrideCurrent(8.f);
  h.Run(25);
  EXPECT_EQ(h.fw.state(), State::kFault);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultOverCurrent);
  EXPECT_TRUE(h.MotorsOff());
}

TEST(FaultTest, UnderVoltage) {
  Harness h;
  DriveSteady(&h);
  h.plant.OverrideSupply(7.0);
  h.Run(60);
  EXPECT_EQ(h.fw.state(), State::kFault);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultUnderVoltage);
  EXPECT_TRUE(h.MotorsOff());
  // Clearing while the supply is still low faults again.
  h.Send(can::EncodeClearFaults(1));
  h.Run(60);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultUnderVoltage);
  h.plant.OverrideSupply(-1.0);
  h.Send(can::EncodeClearFaults(1));
  h.Run(60);
  EXPECT_EQ(h.fw.state(), State::kIdle);
  EXPECT_EQ(h.fw.fault_bits(), 0u);
}

TEST(FaultTest, CanBusOff) {
  Harness h;
  DriveSteady(&h);
  h.hal.bus_off = true;
  h.Run(1);
  EXPECT_EQ(h.fw.state(), State::kFault);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultCanBusOff);
  EXPECT_TRUE(h.MotorsOff());
  h.hal.bus_off = false;
  h.Run(200);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultCanBusOff) << "latched until cleared";
}

TEST(FaultTest, FaultReportedInHeartbeat) {
  Harness h;
  DriveSteady(&h);
  h.Send(can::EncodeEstop(1));
  h.hal.tx.clear();
  h.Run(150);
  bool seen = false;
  for (const CanFrame& f : h.hal.tx) {
    if (can::CommandOf(f.id) != can::kHeartbeat) continue;
    can::Heartbeat hb;
    ASSERT_TRUE(can::DecodeHeartbeat(f, &hb));
    EXPECT_EQ(hb.state, static_cast<uint8_t>(State::kEstop));
    EXPECT_TRUE(hb.fault_bits & kFaultEstop);
    EXPECT_NEAR(hb.bus_voltage_v, 12.f, 0.01f);
    seen = true;
  }
  EXPECT_TRUE(seen);
}

}  // namespace
}  // namespace omni::firmware
