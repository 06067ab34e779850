#include "omni/base_bridge/teleop.h"

#include <algorithm>
#include <cmath>

namespace omni::base_bridge {

TeleopAction TeleopState::Key(char c, double now_s) {
  auto direction = [&](int x, int y, int turn) {
    if (estopped_) return TeleopAction::kRefused;
    dir_x_ = x;
    dir_y_ = y;
    dir_turn_ = turn;
    last_key_s_ = now_s;
    timeout_said_ = false;
    return TeleopAction::kTwist;
  };
  auto stop = [&] { dir_x_ = dir_y_ = dir_turn_ = 0; };
  switch (c) {
    case 'w':
      return direction(1, 0, 0);
    case 's':
      return direction(-1, 0, 0);
    case 'a':
      return direction(0, 1, 0);
    case 'd':
      return direction(0, -1, 0);
    case 'q':
      return direction(0, 0, 1);
    case 'e':
      return direction(0, 0, -1);
    // Diagonals (a terminal repeats only the last key held, so w + a together cannot be told
    // from a): the ring around i / k of ROS' teleop_twist_keyboard in its holonomic mode.
    case 'u':
      return direction(1, 1, 0);
    case 'o':
      return direction(1, -1, 0);
    case 'm':
      return direction(-1, 1, 0);
    case '.':
      return direction(-1, -1, 0);
    case '+':
    case '=':
    case '-':
    case '_': {
      // A direction the dead man's switch has stopped stays stopped: a speed key must not
      // start it again (only a direction key moves the base).
      if (opt_.key_timeout_s > 0 && now_s - last_key_s_ > opt_.key_timeout_s) stop();
      const double sign = (c == '+' || c == '=') ? 1.0 : -1.0;
      linear_ = std::clamp(linear_ + sign * opt_.linear_step_m_s, opt_.linear_step_m_s,
                           std::max(opt_.linear_step_m_s, opt_.max_linear_m_s));
      angular_ = std::clamp(angular_ + sign * opt_.angular_step_rad_s, opt_.angular_step_rad_s,
                            std::max(opt_.angular_step_rad_s, opt_.max_angular_rad_s));
      last_key_s_ = now_s;  // a direction still held goes on at the new speed
      return TeleopAction::kSpeed;
    }
    case ' ':
      stop();
      return TeleopAction::kTwist;
    case '!':
      stop();
      estopped_ = true;
      return TeleopAction::kEstop;
    case 'c':
      stop();  // clearing faults never resumes a motion
      estopped_ = false;
      return TeleopAction::kClearFaults;
    case 27:  // Esc
    case 3:   // Ctrl-C (raw terminal)
    case 4:   // Ctrl-D
      stop();
      return TeleopAction::kQuit;
    default:
      return TeleopAction::kNone;
  }
}

TeleopTwist TeleopState::TwistAt(double now_s) const {
  TeleopTwist t;
  if (estopped_) return t;
  if (opt_.key_timeout_s > 0 && now_s - last_key_s_ > opt_.key_timeout_s) return t;
  // A diagonal moves at the same speed as a straight key, split between x and y.
  const double along = (dir_x_ != 0 && dir_y_ != 0) ? linear_ * std::sqrt(0.5) : linear_;
  t.vx_m_s = dir_x_ * along;
  t.vy_m_s = dir_y_ * along;
  t.omega_rad_s = dir_turn_ * angular_;
  return t;
}

bool TeleopState::TimedOutNow(double now_s) {
  if (timeout_said_ || opt_.key_timeout_s <= 0 || estopped_) return false;
  if (dir_x_ == 0 && dir_y_ == 0 && dir_turn_ == 0) return false;
  if (now_s - last_key_s_ <= opt_.key_timeout_s) return false;
  timeout_said_ = true;
  return true;
}

void TeleopKeyReader::Feed(const char* data, size_t n, std::vector<char>* keys) {
  for (size_t i = 0; i < n; ++i) {
    const char c = data[i];
    const auto u = static_cast<unsigned char>(c);
    switch (state_) {
      case State::kKeys:
        if (c == 27) {
          state_ = State::kEscape;
        } else {
          keys->push_back(c);
        }
        break;
      case State::kEscape:
        if (c == '[') {
          state_ = State::kCsi;
          sequence_bytes_ = 0;
        } else if (c == 'O') {
          state_ = State::kSs3;
        } else if (c == 27) {
          keys->push_back(27);  // Esc pressed twice: one Esc, the second may start a sequence
        } else {
          keys->push_back(27);  // Esc, then a key (or Alt+key: read as Esc, which quits: safe)
          keys->push_back(c);
          state_ = State::kKeys;
        }
        break;
      case State::kCsi:
        // A key's sequence: parameter bytes 0x30-0x3F (digits, ';'), then a final byte
        // 0x40-0x7E. Anything else (a space, '!', '+', '-': intermediates no key sends) or a
        // long run means it was not one (Alt+[ then keys): that byte is read as a key.
        if (u >= 0x40 && u <= 0x7E) {
          state_ = State::kKeys;
        } else if (u < 0x30 || u > 0x3F || ++sequence_bytes_ > kMaxSequenceBytes) {
          // Not a sequence after all (a control byte or a non-ASCII byte): read it as a key.
          state_ = State::kKeys;
          --i;
        }
        break;
      case State::kSs3:
        state_ = State::kKeys;          // ESC O x: x is the final byte, if it is one (0x40-0x7E)
        if (u < 0x40 || u > 0x7E) --i;  // Alt+O then a key: the key is read as one
        break;
    }
  }
}

void TeleopKeyReader::Flush(std::vector<char>* keys) {
  if (state_ == State::kEscape) keys->push_back(27);
  // An unfinished sequence whose rest never came (Alt+[ or Alt+O) is dropped; what comes next
  // is keys.
  state_ = State::kKeys;
}

const char* TeleopHelp() {
  return "keys: hold w/s forward/back, a/d left/right, u/o forward-left/right, m/. "
         "back-left/right,\n"
         "      q/e turn (the base stops when keys stop coming), + / - faster/slower, space stop,\n"
         "      ! e-stop, c clear faults, Esc or Ctrl-C or Ctrl-D quit\n";
}

}  // namespace omni::base_bridge
