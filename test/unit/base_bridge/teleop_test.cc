#include "omni/base_bridge/teleop.h"

#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/base_bridge/messages.h"

namespace omni::base_bridge {
namespace {

// A held key moves the base at the current speed; the twist drops to zero once keys stop coming
// for key_timeout_s (the dead man's switch: before, the last twist was sent until the process
// ended, so a stalled SSH link left the base driving).
TEST(Teleop, AHeldKeyMovesAndTheBaseStopsWhenKeysStop) {
  const TeleopOptions o;
  TeleopState s(o);
  EXPECT_EQ(s.Key('w', 0.0), TeleopAction::kTwist);
  EXPECT_NEAR(s.TwistAt(0.1).vx_m_s, o.linear_speed_m_s, 1e-12);
  // Auto-repeat every 0.05 s keeps it moving well past the timeout.
  for (int i = 1; i <= 40; ++i) s.Key('w', 0.05 * i);
  EXPECT_NEAR(s.TwistAt(2.0 + o.key_timeout_s - 0.01).vx_m_s, o.linear_speed_m_s, 1e-12);
  EXPECT_FALSE(s.TimedOutNow(2.0 + o.key_timeout_s - 0.01));
  const TeleopTwist stopped = s.TwistAt(2.0 + o.key_timeout_s + 0.01);
  EXPECT_EQ(stopped.vx_m_s, 0);
  EXPECT_EQ(stopped.vy_m_s, 0);
  EXPECT_EQ(stopped.omega_rad_s, 0);
  EXPECT_TRUE(s.TimedOutNow(2.0 + o.key_timeout_s + 0.01));
  EXPECT_FALSE(s.TimedOutNow(3.5)) << "said once";
  // A direction replaces the last one; q / e turn.
  s.Key('a', 4.0);
  EXPECT_EQ(s.TwistAt(4.1).vx_m_s, 0);
  EXPECT_NEAR(s.TwistAt(4.1).vy_m_s, o.linear_speed_m_s, 1e-12);
  s.Key('e', 4.2);
  EXPECT_EQ(s.TwistAt(4.3).vy_m_s, 0);
  EXPECT_NEAR(s.TwistAt(4.3).omega_rad_s, -o.angular_speed_rad_s, 1e-12);
  EXPECT_EQ(s.Key(' ', 4.4), TeleopAction::kTwist);
  EXPECT_EQ(s.TwistAt(4.41).omega_rad_s, 0);
  // Diagonals: u / o / m / . at the straight keys' speed, split between x and y.
  const double half = o.linear_speed_m_s * std::sqrt(0.5);
  const struct {
    char key;
    double vx, vy;
  } diagonals[] = {{'u', half, half}, {'o', half, -half}, {'m', -half, half}, {'.', -half, -half}};
  for (const auto& d : diagonals) {
    EXPECT_EQ(s.Key(d.key, 4.5), TeleopAction::kTwist) << d.key;
    const TeleopTwist t = s.TwistAt(4.6);
    EXPECT_NEAR(t.vx_m_s, d.vx, 1e-12) << d.key;
    EXPECT_NEAR(t.vy_m_s, d.vy, 1e-12) << d.key;
    EXPECT_EQ(t.omega_rad_s, 0) << d.key;
    EXPECT_NEAR(std::hypot(t.vx_m_s, t.vy_m_s), o.linear_speed_m_s, 1e-12) << d.key;
  }
  s.Key(' ', 4.7);
  // Without the switch (0) the twist holds, as a planner's would.
  TeleopOptions hold = o;
  hold.key_timeout_s = 0;
  TeleopState h(hold);
  h.Key('s', 0);
  EXPECT_NEAR(h.TwistAt(100).vx_m_s, -o.linear_speed_m_s, 1e-12);
  EXPECT_FALSE(h.TimedOutNow(100));
}

TEST(Teleop, SpeedsStepWithinTheirLimits) {
  const TeleopOptions o;
  TeleopState s(o);
  s.Key('w', 0);
  EXPECT_EQ(s.Key('+', 0.1), TeleopAction::kSpeed);
  EXPECT_NEAR(s.TwistAt(0.2).vx_m_s, o.linear_speed_m_s + o.linear_step_m_s, 1e-12);
  for (int i = 0; i < 30; ++i) s.Key('=', 0.2);
  EXPECT_NEAR(s.linear_speed_m_s(), o.max_linear_m_s, 1e-12);
  EXPECT_NEAR(s.angular_speed_rad_s(), o.max_angular_rad_s, 1e-12);
  for (int i = 0; i < 30; ++i) s.Key('-', 0.3);
  EXPECT_NEAR(s.linear_speed_m_s(), o.linear_step_m_s, 1e-12) << "never zero";
  EXPECT_NEAR(s.angular_speed_rad_s(), o.angular_step_rad_s, 1e-12);
  // A speed key after the dead man's switch stopped the base does not start it again.
  s.Key('w', 1.0);
  EXPECT_GT(s.TwistAt(1.1).vx_m_s, 0);
  EXPECT_EQ(s.TwistAt(1.0 + o.key_timeout_s + 0.1).vx_m_s, 0);
  EXPECT_EQ(s.Key('+', 3.0), TeleopAction::kSpeed);
  EXPECT_EQ(s.TwistAt(3.01).vx_m_s, 0);
  for (int i = 0; i < 20; ++i) s.Key('+', 3.0 + 0.05 * i);  // held '+'
  EXPECT_EQ(s.TwistAt(4.0).vx_m_s, 0);
}

// An e-stop zeroes the twist and refuses direction keys until clear-faults, which leaves the
// twist at zero (before, a twist keyed while e-stopped was sent the moment faults cleared, and
// the base lurched off).
TEST(Teleop, EstopRefusesDirectionsAndClearingFaultsNeverResumesAMotion) {
  const TeleopOptions o;
  TeleopState s(o);
  s.Key('w', 0);
  EXPECT_EQ(s.Key('x', 0.01), TeleopAction::kNone);
  EXPECT_EQ(s.Key('\n', 0.01), TeleopAction::kNone);
  EXPECT_NEAR(s.TwistAt(0.02).vx_m_s, o.linear_speed_m_s, 1e-12);
  EXPECT_EQ(s.Key('!', 0.05), TeleopAction::kEstop);
  EXPECT_TRUE(s.estopped());
  EXPECT_EQ(s.TwistAt(0.06).vx_m_s, 0);
  for (char c : std::string("wwwwwasdqe")) EXPECT_EQ(s.Key(c, 0.1), TeleopAction::kRefused) << c;
  EXPECT_EQ(s.TwistAt(0.11).vx_m_s, 0);
  EXPECT_EQ(s.Key('c', 0.2), TeleopAction::kClearFaults);
  EXPECT_FALSE(s.estopped());
  const TeleopTwist after = s.TwistAt(0.21);
  EXPECT_EQ(after.vx_m_s, 0);
  EXPECT_EQ(after.vy_m_s, 0);
  EXPECT_EQ(after.omega_rad_s, 0);
  s.Key('w', 0.3);
  EXPECT_EQ(s.Key(27, 0.31), TeleopAction::kQuit);
  EXPECT_EQ(s.TwistAt(0.32).vx_m_s, 0);
  EXPECT_EQ(s.Key(3, 0.4), TeleopAction::kQuit);
  EXPECT_EQ(s.Key(4, 0.4), TeleopAction::kQuit);
}

std::string Keys(TeleopKeyReader* r, const std::string& bytes) {
  std::vector<char> k;
  r->Feed(bytes.data(), bytes.size(), &k);
  return std::string(k.begin(), k.end());
}

// Arrow keys (escape sequences) are skipped whole, and what follows them in the same read is
// still read (before, the rest of a read after an arrow was dropped: a space or '!' batched
// behind it over SSH was lost); a sequence split between reads is still one; a lone ESC is the
// Esc key once nothing follows it.
TEST(TeleopKeys, EscapeSequencesAreSkippedAndTheKeysAfterThemKept) {
  TeleopKeyReader r;
  EXPECT_EQ(Keys(&r, "www\x1b[A "), "www ");
  EXPECT_EQ(Keys(&r, "\x1b[A!"), "!");
  EXPECT_EQ(Keys(&r, "\x1bOB w"), " w");   // SS3 form (application cursor keys)
  EXPECT_EQ(Keys(&r, "\x1b[1;5C!"), "!");  // with parameters (Ctrl+Right)
  EXPECT_EQ(Keys(&r, "w\x1b"), "w");       // split: the ESC waits ...
  EXPECT_TRUE(r.escape_pending());
  EXPECT_EQ(Keys(&r, "[D "), " ");  // ... and the rest completes the arrow
  EXPECT_EQ(Keys(&r, "\x1b"), "");
  std::vector<char> k;
  r.Flush(&k);  // nothing came: the Esc key
  ASSERT_EQ(k.size(), 1u);
  EXPECT_EQ(k[0], 27);
  EXPECT_FALSE(r.escape_pending());
  EXPECT_EQ(Keys(&r, "\x1bw"), std::string("\x1b") + "w");  // Esc then a key
  // Alt+[ or Alt+O then keys: the keys are not swallowed as a sequence's bytes.
  EXPECT_EQ(Keys(&r, "\x1b[ !"), " !");
  EXPECT_EQ(Keys(&r, "\x1bO!"), "!");
  EXPECT_EQ(Keys(&r, "\x1b[+-"), "+-");
  EXPECT_EQ(Keys(&r, "\x1b[12"), "");  // digits: maybe a sequence, waiting ...
  EXPECT_TRUE(r.escape_pending());
  k.clear();
  r.Flush(&k);  // ... nothing more came: dropped, not the Esc key
  EXPECT_TRUE(k.empty());
  EXPECT_EQ(Keys(&r, "w"), "w");
  EXPECT_EQ(Keys(&r, "\x1b[\x03"), std::string("\x03"));  // a control byte ends it: Ctrl-C
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
