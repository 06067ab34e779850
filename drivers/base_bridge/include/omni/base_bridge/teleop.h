// Keyboard teleoperation of the base (`omni drive --keys`). A direction key moves the base while
// it is held (the terminal repeats it): the twist is sent on BASE_CMD at a fixed rate and drops
// to zero when no key came for `key_timeout_s` (a dead man's switch: a stalled SSH link or a
// frozen laptop stops the base instead of leaving it driving).
//
//   w / s   forward / backward      + / -   faster / slower (both speeds, one step)
//   a / d   left / right            space   stop now
//   q / e   turn left / right       !       e-stop (repeated until c; direction keys refused)
//   u / o   forward-left / -right   m / .   backward-left / -right (at the same speed, split)
//                                   c       clear faults (the twist stays zero)
//   Esc, Ctrl-C, Ctrl-D: quit (a zero twist is sent)
// No I/O in here, so the keys, the timing and the escape-sequence parsing are unit-tested.
#pragma once

#include <cstddef>
#include <vector>

namespace omni::base_bridge {

struct TeleopOptions {
  double linear_speed_m_s = 0.2;     // speed of a held direction key at the start
  double angular_speed_rad_s = 0.5;  // turn rate of a held q / e at the start
  double linear_step_m_s = 0.1;      // + / - change the speeds by these steps ...
  double angular_step_rad_s = 0.25;
  double max_linear_m_s = 1.0;  // ... within these limits (the bridge clamps again)
  double max_angular_rad_s = 2.0;
  // The dead man's switch: the twist is zero once no key came for this long (longer than a
  // terminal's key-repeat delay, 0.25-0.66 s, so a held key keeps moving). 0: the twist holds
  // until space or another key, as a planner's command would (no switch).
  double key_timeout_s = 0.75;
};

struct TeleopTwist {
  double vx_m_s = 0, vy_m_s = 0, omega_rad_s = 0;
};

enum class TeleopAction {
  kNone,         // a key without a meaning
  kTwist,        // the twist changed (or a stop was asked for)
  kSpeed,        // the speeds changed
  kEstop,        // e-stop: the twist is zero and direction keys are refused until kClearFaults
  kClearFaults,  // clear faults: the twist stays zero
  kRefused,      // a direction key while e-stopped
  kQuit,         // quit: the twist is zero
};

// The teleop's state: which direction is held, the speeds, the e-stop, the last key's time.
class TeleopState {
 public:
  explicit TeleopState(const TeleopOptions& options = {}) : opt_(options) {}
  // Key `c` at the monotonic time `now_s`.
  TeleopAction Key(char c, double now_s);
  // The twist to send at `now_s`: zero while e-stopped, or once no key came for key_timeout_s.
  TeleopTwist TwistAt(double now_s) const;
  // True once, at the first call after a moving twist timed out (to say so).
  bool TimedOutNow(double now_s);
  bool estopped() const { return estopped_; }
  double linear_speed_m_s() const { return linear_; }
  double angular_speed_rad_s() const { return angular_; }

 private:
  TeleopOptions opt_;
  double linear_ = opt_.linear_speed_m_s, angular_ = opt_.angular_speed_rad_s;
  // The held direction: each of -1, 0, +1, scaled by the speeds.
  int dir_x_ = 0, dir_y_ = 0, dir_turn_ = 0;
  double last_key_s_ = 0;
  bool estopped_ = false;
  bool timeout_said_ = true;  // nothing to say until a direction key
};

// Splits the bytes a terminal sends into keys. A key such as an arrow sends an escape sequence
// (ESC [ ... final byte, or ESC O x), which is skipped whole however the bytes are split between
// reads, and what follows it is read as keys (a batched read over SSH does not lose the space or
// '!' after an arrow). ESC followed by anything else is the Esc key, then that byte; an ESC or
// an unfinished sequence at the end of the bytes so far waits for the next read, or for Flush
// (nothing more came within 50 ms: a lone ESC is the Esc key, an unfinished sequence is dropped).
class TeleopKeyReader {
 public:
  void Feed(const char* data, size_t n, std::vector<char>* keys);
  // No byte followed a pending ESC: it was the Esc key (appended to `keys`).
  void Flush(std::vector<char>* keys);
  // An ESC or a sequence is waiting for its next byte.
  bool escape_pending() const { return state_ != State::kKeys; }

 private:
  enum class State { kKeys, kEscape, kCsi, kSs3 };
  static constexpr int kMaxSequenceBytes = 16;
  State state_ = State::kKeys;
  int sequence_bytes_ = 0;
};

// The key help printed by `omni drive --keys`.
const char* TeleopHelp();

}  // namespace omni::base_bridge
