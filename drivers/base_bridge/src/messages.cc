#include "omni/base_bridge/messages.h"

#include <algorithm>

namespace omni::base_bridge {

omni::odometry_t ToMessage(const Odometry& od, const BaseBridgeOptions& o) {
  omni::odometry_t m;
  m.utime = od.utime;
  m.seq = od.seq;
  m.frame = o.odom_frame;
  m.child_frame = o.base_frame;
  m.x_m = od.x_m;
  m.y_m = od.y_m;
  m.yaw_rad = od.yaw_rad;
  m.vx_m_s = od.vx_m_s;
  m.vy_m_s = od.vy_m_s;
  m.omega_rad_s = od.omega_rad_s;
  std::copy(od.pose_cov, od.pose_cov + 9, m.pose_covariance);
  std::copy(od.twist_cov, od.twist_cov + 9, m.twist_covariance);
  return m;
}

omni::wheel_encoders_t ToMessage(const Encoders& en, const BaseBridgeOptions& o) {
  omni::wheel_encoders_t m;
  m.utime = en.utime;
  m.mcu_time_us = en.mcu_time_us;
  m.seq = en.seq;
  m.num_wheels = 3;
  m.position_ticks.assign(en.position_ticks, en.position_ticks + 3);
  m.velocity_rad_s.assign(en.velocity_rad_s, en.velocity_rad_s + 3);
  m.current_a.assign(en.current_a, en.current_a + 3);
  m.ticks_per_rev = static_cast<float>(o.ticks_per_rev);
  return m;
}

omni::base_status_t ToMessage(const BaseStatus& s, const Counters& c) {
  omni::base_status_t m;
  m.utime = s.utime;
  m.state = s.state;
  m.fault_bits = s.fault_bits;
  m.firmware_alive = s.firmware_alive;
  m.missed_heartbeats = s.missed_heartbeats;
  m.bus_voltage_v = s.bus_voltage_v;
  std::copy(s.wheel_speed_rad_s, s.wheel_speed_rad_s + 3, m.wheel_speed_rad_s);
  std::copy(s.wheel_setpoint_rad_s, s.wheel_setpoint_rad_s + 3, m.wheel_setpoint_rad_s);
  m.commands_clamped = c.commands_clamped;
  m.can_rx_errors = c.can_rx_errors + c.unknown_frames;
  m.feedback_frames_lost = c.feedback_frames_lost;
  return m;
}

Command FromMessage(const omni::base_cmd_t& m) {
  Command c;
  c.mode = static_cast<Command::Mode>(m.mode);
  if (m.mode != omni::base_cmd_t::MODE_TWIST && m.mode != omni::base_cmd_t::MODE_ESTOP &&
      m.mode != omni::base_cmd_t::MODE_CLEAR_FAULTS)
    c.mode = Command::kInvalid;
  c.vx_m_s = m.vx_m_s;
  c.vy_m_s = m.vy_m_s;
  c.omega_rad_s = m.omega_rad_s;
  return c;
}

}  // namespace omni::base_bridge
