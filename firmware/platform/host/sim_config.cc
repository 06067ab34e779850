#include "sim_config.h"

#include <vector>

#include "omni/common/config.h"

namespace omni::firmware::sim {
namespace {

Result<SimOptions> Load(Result<ConfigReader> reader) {
  if (!reader.ok()) return reader.error();
  ConfigReader& r = *reader;
  SimOptions o;
  r.Get("can", &o.can_url, Required(), NonEmpty());
  int node = o.firmware.node_id;
  r.Get("node_id", &node, Optional(), InRange(0, 63));
  o.firmware.node_id = static_cast<uint8_t>(node);

  ConfigReader fw = r.Section("firmware");
  Params& p = o.firmware;
  fw.Get("kp", &p.kp, Optional(), NonNegative<float>());
  fw.Get("ki", &p.ki, Optional(), NonNegative<float>());
  fw.Get("kd", &p.kd, Optional(), NonNegative<float>());
  fw.Get("kff", &p.kff, Optional(), NonNegative<float>());
  fw.Get("max_duty", &p.max_duty, Optional(), InRange(0.05f, 1.f));
  fw.Get("max_wheel_speed_rad_s", &p.max_wheel_speed_rad_s, Optional(), Positive<float>());
  fw.Get("max_wheel_accel_rad_s2", &p.max_wheel_accel_rad_s2, Optional(), Positive<float>());
  fw.Get("stop_decel_rad_s2", &p.stop_decel_rad_s2, Optional(), Positive<float>());
  fw.Get("watchdog_ms", &p.watchdog_ms, Optional(), InRange<uint32_t>(10, 5000));
  fw.Get("current_limit_a", &p.current_limit_a, Optional(), Positive<float>());
  fw.Get("under_voltage_v", &p.under_voltage_v, Optional(), NonNegative<float>());
  fw.Get("stall_ms", &p.stall_ms, Optional(), InRange<uint32_t>(10, 10000));
  fw.Get("center_to_wheel_m", &p.center_to_wheel_m, Optional(), Positive<float>());
  fw.Get("wheel_radius_m", &p.wheel_radius_m, Optional(), Positive<float>());
  fw.Get("ticks_per_rev", &p.ticks_per_rev, Optional(), Positive<float>());
  fw.Get("feedback_period_ms", &p.feedback_period_ms, Optional(), InRange<uint32_t>(1, 1000));
  fw.Get("heartbeat_period_ms", &p.heartbeat_period_ms, Optional(), InRange<uint32_t>(10, 5000));

  ConfigReader pl = r.Section("plant");
  PlantParams& q = o.plant;
  pl.Get("supply_v", &q.supply_v, Optional(), Positive<double>());
  pl.Get("resistance_ohm", &q.resistance_ohm, Optional(), Positive<double>());
  pl.Get("kt_nm_a", &q.kt_nm_a, Optional(), Positive<double>());
  pl.Get("gear_ratio", &q.gear_ratio, Optional(), Positive<double>());
  pl.Get("rotor_inertia_kg_m2", &q.rotor_inertia_kg_m2, Optional(), Positive<double>());
  pl.Get("robot_mass_kg", &q.robot_mass_kg, Optional(), Positive<double>());
  pl.Get("coulomb_nm", &q.coulomb_nm, Optional(), NonNegative<double>());
  pl.Get("viscous_nm_s", &q.viscous_nm_s, Optional(), NonNegative<double>());
  pl.Get("center_to_wheel_m", &q.center_to_wheel_m, Optional(), Positive<double>());
  pl.Get("wheel_radius_m", &q.wheel_radius_m, Optional(), Positive<double>());
  pl.Get("ticks_per_rev", &q.ticks_per_rev, Optional(), Positive<double>());
  std::vector<double> slip;
  pl.Get<std::vector<double>>("slip", &slip, Optional(), [](const std::vector<double>& v) {
    if (v.size() != 3) return std::string("must list 3 values (wheels 1, 2, 3)");
    for (double s : v)
      if (!(s >= 0.0 && s < 1.0)) return std::string("each value must be in [0, 1)");
    return std::string();
  });
  for (size_t i = 0; i < slip.size() && i < 3; ++i) q.slip[i] = slip[i];

  uint16_t bad = 0;
  if (ValidateParams(p, &bad) != FwStatus::kOk) {
    r.AddError("firmware", "parameter id " + std::to_string(bad) +
                               " is outside its range (see firmware/src/params.cc)");
  }
  Status s = r.Finish();
  if (!s.ok()) return s.error();
  return o;
}

}  // namespace

Result<SimOptions> LoadSimOptions(const std::string& path) {
  return Load(ConfigReader::FromFile(path));
}
Result<SimOptions> LoadSimOptionsFromString(const std::string& yaml, const std::string& name) {
  return Load(ConfigReader::FromString(yaml, name));
}

}  // namespace omni::firmware::sim
