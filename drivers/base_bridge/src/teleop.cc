#include "omni/base_bridge/teleop.h"

#include <algorithm>

namespace omni::base_bridge {

TeleopAction ApplyTeleopKey(char c, const TeleopOptions& o, TeleopTwist* t) {
  auto step = [](double* v, double d, double limit) { *v = std::clamp(*v + d, -limit, limit); };
  switch (c) {
    case 'w':
      step(&t->vx_m_s, o.linear_step_m_s, o.max_linear_m_s);
      return TeleopAction::kTwist;
    case 's':
      step(&t->vx_m_s, -o.linear_step_m_s, o.max_linear_m_s);
      return TeleopAction::kTwist;
    case 'a':
      step(&t->vy_m_s, o.linear_step_m_s, o.max_linear_m_s);
      return TeleopAction::kTwist;
    case 'd':
      step(&t->vy_m_s, -o.linear_step_m_s, o.max_linear_m_s);
      return TeleopAction::kTwist;
    case 'q':
      step(&t->omega_rad_s, o.angular_step_rad_s, o.max_angular_rad_s);
      return TeleopAction::kTwist;
    case 'e':
      step(&t->omega_rad_s, -o.angular_step_rad_s, o.max_angular_rad_s);
      return TeleopAction::kTwist;
    case ' ':
      *t = {};
      return TeleopAction::kTwist;
    case '!':
      *t = {};
      return TeleopAction::kEstop;
    case 'c':
      return TeleopAction::kClearFaults;
    case 27:  // Esc
    case 3:   // Ctrl-C (raw terminal)
    case 4:   // Ctrl-D
      *t = {};
      return TeleopAction::kQuit;
    default:
      return TeleopAction::kNone;
  }
}

const char* TeleopHelp() {
  return "keys: w/s forward/back, a/d left/right, q/e turn left/right, space stop,\n"
         "      ! e-stop, c clear faults, Esc or Ctrl-C or Ctrl-D quit\n";
}

}  // namespace omni::base_bridge
