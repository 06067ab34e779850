// Keyboard teleoperation of the base (`omni drive --keys`): each key changes the body twist that
// is then sent on BASE_CMD at a fixed rate, or sends a one-off e-stop / clear-faults. No I/O in
// here, so the key map is unit-tested.
//
//   w / s   forward / backward  (vx +- linear_step)      space  stop (zero twist)
//   a / d   left / right        (vy +- linear_step)      !      e-stop
//   q / e   turn left / right   (omega +- angular_step)  c      clear faults
//   Esc, Ctrl-C, Ctrl-D: quit (a zero twist is sent)
#pragma once

namespace omni::base_bridge {

struct TeleopOptions {
  double linear_step_m_s = 0.1;
  double angular_step_rad_s = 0.2;
  double max_linear_m_s = 1.0;  // the twist is clamped here (the bridge clamps again)
  double max_angular_rad_s = 2.0;
};

struct TeleopTwist {
  double vx_m_s = 0, vy_m_s = 0, omega_rad_s = 0;
};

enum class TeleopAction { kNone, kTwist, kEstop, kClearFaults, kQuit };

// Applies key `c` to `twist`: kTwist when the twist changed (or a stop was asked for), kEstop
// (the twist is zeroed too), kClearFaults, kQuit (zeroed), kNone for any other key.
TeleopAction ApplyTeleopKey(char c, const TeleopOptions& o, TeleopTwist* twist);

// The key help printed by `omni drive --keys`.
const char* TeleopHelp();

}  // namespace omni::base_bridge
