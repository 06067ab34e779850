#include "omni/base_bridge/base_bridge.h"
#include "omni/can/can_bus.h"
#include "omni/common/config.h"

namespace omni::base_bridge {
namespace {

Result<BaseBridgeOptions> Load(Result<ConfigReader> reader) {
  if (!reader.ok()) return reader.error();
  ConfigReader& r = *reader;
  BaseBridgeOptions o;
  r.Get("can", &o.can_url, Required(), NonEmpty());
  if (!o.can_url.empty())
    if (auto u = can::ParseCanUrl(o.can_url); !u.ok()) r.AddError("can", u.error().message);
  r.Get("node_id", &o.node_id, Optional(), InRange(0, 63));
  ConfigReader g = r.Section("geometry");
  g.Get("alpha_rad", &o.alpha_rad, Optional(), InRange(0.1, 3.0));
  g.Get("center_to_wheel_m", &o.center_to_wheel_m, Required(), InRange(0.01, 5.0));
  g.Get("wheel_radius_m", &o.wheel_radius_m, Required(), InRange(0.005, 1.0));
  g.Get("ticks_per_rev", &o.ticks_per_rev, Required(), InRange(1.0, 1e7));
  g.Get("feedback_period_s", &o.feedback_period_s, Optional(), InRange(0.001, 1.0));
  ConfigReader l = r.Section("limits");
  // Upper bounds: a limit far beyond any base (1e12 m/s was accepted) is no limit at all.
  l.Get("max_vx_m_s", &o.max_vx_m_s, Required(), InRange(1e-3, 10.0));
  l.Get("max_vy_m_s", &o.max_vy_m_s, Required(), InRange(1e-3, 10.0));
  l.Get("max_omega_rad_s", &o.max_omega_rad_s, Required(), InRange(1e-3, 50.0));
  l.Get("max_linear_accel_m_s2", &o.max_linear_accel_m_s2, Required(), InRange(1e-3, 100.0));
  l.Get("max_angular_accel_rad_s2", &o.max_angular_accel_rad_s2, Required(), InRange(1e-3, 500.0));
  ConfigReader t = r.Section("timing");
  t.Get("send_rate_hz", &o.send_rate_hz, Optional(), InRange(5.0, 1000.0));
  t.Get("command_timeout_s", &o.command_timeout_s, Optional(), InRange(0.01, 10.0));
  t.Get("firmware_heartbeat_period_s", &o.firmware_heartbeat_period_s, Optional(),
        InRange(0.01, 5.0));
  t.Get("missed_heartbeats_for_silent", &o.missed_heartbeats_for_silent, Optional(),
        InRange(2, 100));
  t.Get("reconnect_period_s", &o.reconnect_period_s, Optional(), InRange(0.01, 60.0));
  t.Get("status_rate_hz", &o.status_rate_hz, Optional(), InRange(0.1, 100.0));
  ConfigReader c = r.Section("odometry");
  c.Get("var_xy_per_m", &o.odom_var_xy_per_m, Optional(), NonNegative<double>());
  c.Get("var_yaw_per_rad", &o.odom_var_yaw_per_rad, Optional(), NonNegative<double>());
  c.Get("twist_var_linear", &o.twist_var_linear, Optional(), NonNegative<double>());
  c.Get("twist_var_angular", &o.twist_var_angular, Optional(), NonNegative<double>());
  c.Get("frame", &o.odom_frame, Optional(), NonEmpty());
  c.Get("child_frame", &o.base_frame, Optional(), NonEmpty());
  ConfigReader ch = r.Section("channels");
  ch.Get("cmd", &o.cmd_channel, Optional(), NonEmpty());
  ch.Get("odom", &o.odom_channel, Optional(), NonEmpty());
  ch.Get("encoders", &o.encoders_channel, Optional(), NonEmpty());
  ch.Get("status", &o.status_channel, Optional(), NonEmpty());
  ch.Get("imu", &o.imu_channel, Optional(), NonEmpty());
  ConfigReader sl = r.Section("slip");
  sl.Get("enabled", &o.slip.enabled, Optional());
  sl.Get("window_s", &o.slip.window_s, Optional(), InRange(0.05, 10.0));
  sl.Get("threshold_rad", &o.slip.threshold_rad, Optional(), Positive<double>());
  sl.Get("threshold_fraction", &o.slip.threshold_fraction, Optional(), NonNegative<double>());
  sl.Get("gyro_bias_rad_s", &o.slip.gyro_bias_rad_s, Optional());
  ReadGyroBiasOptions(sl.Section("bias_learning"), &o.slip.bias_learning);
  if (o.send_rate_hz * o.command_timeout_s < 2.0) {
    r.AddError("timing.command_timeout_s", "must cover at least two send periods");
  }
  Status s = r.Finish();
  if (!s.ok()) return s.error();
  return o;
}

}  // namespace

Result<BaseBridgeOptions> LoadBaseBridgeOptions(const std::string& path) {
  return Load(ConfigReader::FromFile(path));
}
Result<BaseBridgeOptions> LoadBaseBridgeOptionsFromString(const std::string& yaml,
                                                          const std::string& name) {
  return Load(ConfigReader::FromString(yaml, name));
}

}  // namespace omni::base_bridge
