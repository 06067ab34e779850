#include "omni/firmware/params.h"

namespace omni::firmware {
namespace {

struct Entry {
  uint16_t id;
  float Params::*f;     // float parameter, or
  uint32_t Params::*u;  // integer parameter
  float lo, hi;
  bool read_only;
};

constexpr Entry kTable[] = {
    {kParamKp, &Params::kp, nullptr, 0.f, 10.f, false},
    {kParamKi, &Params::ki, nullptr, 0.f, 100.f, false},
    {kParamKd, &Params::kd, nullptr, 0.f, 1.f, false},
    {kParamKff, &Params::kff, nullptr, 0.f, 1.f, false},
    {kParamMaxDuty, &Params::max_duty, nullptr, 0.05f, 1.f, false},
    {kParamMaxWheelSpeed, &Params::max_wheel_speed_rad_s, nullptr, 0.1f, 300.f, false},
    {kParamMaxWheelAccel, &Params::max_wheel_accel_rad_s2, nullptr, 0.1f, 10000.f, false},
    {kParamStopDecel, &Params::stop_decel_rad_s2, nullptr, 0.1f, 10000.f, false},
    {kParamWatchdogMs, nullptr, &Params::watchdog_ms, 10.f, 5000.f, false},
    {kParamCurrentLimit, &Params::current_limit_a, nullptr, 0.1f, 60.f, false},
    {kParamOverCurrentMs, nullptr, &Params::over_current_ms, 1.f, 1000.f, false},
    {kParamUnderVoltage, &Params::under_voltage_v, nullptr, 0.f, 60.f, false},
    {kParamUnderVoltageMs, nullptr, &Params::under_voltage_ms, 1.f, 5000.f, false},
    {kParamStallMs, nullptr, &Params::stall_ms, 10.f, 10000.f, false},
    {kParamStallDuty, &Params::stall_duty, nullptr, 0.01f, 1.f, false},
    {kParamAlpha, &Params::alpha_rad, nullptr, 0.1f, 3.0f, false},
    {kParamCenterToWheel, &Params::center_to_wheel_m, nullptr, 0.01f, 2.f, false},
    {kParamWheelRadius, &Params::wheel_radius_m, nullptr, 0.005f, 0.5f, false},
    {kParamTicksPerRev, &Params::ticks_per_rev, nullptr, 4.f, 1000000.f, false},
    {kParamFeedbackPeriodMs, nullptr, &Params::feedback_period_ms, 1.f, 1000.f, false},
    {kParamHeartbeatPeriodMs, nullptr, &Params::heartbeat_period_ms, 10.f, 5000.f, false},
    {kParamControlPeriodUs, nullptr, &Params::control_period_us, 100.f, 10000.f, true},
};

const Entry* Find(uint16_t id) {
  for (const Entry& e : kTable) {
    if (e.id == id) return &e;
  }
  return nullptr;
}

float Read(const Params& p, const Entry& e) {
  return e.f != nullptr ? p.*(e.f) : static_cast<float>(p.*(e.u));
}

bool InRange(const Entry& e, float v) { return v == v && v >= e.lo && v <= e.hi; }

}  // namespace

FwStatus GetParam(const Params& p, uint16_t id, float* value) {
  if (id == kParamFirmwareVersion) {
    *value = static_cast<float>(kFirmwareVersion);
    return FwStatus::kOk;
  }
  const Entry* e = Find(id);
  if (e == nullptr) return FwStatus::kUnknown;
  *value = Read(p, *e);
  return FwStatus::kOk;
}

FwStatus SetParam(Params* p, uint16_t id, float value) {
  if (id == kParamFirmwareVersion) return FwStatus::kReadOnly;
  const Entry* e = Find(id);
  if (e == nullptr) return FwStatus::kUnknown;
  if (e->read_only) return FwStatus::kReadOnly;
  if (!InRange(*e, value)) return FwStatus::kInvalid;  // also rejects NaN
  if (e->f != nullptr) {
    p->*(e->f) = value;
  } else {
    p->*(e->u) = static_cast<uint32_t>(value + 0.5f);
  }
  return FwStatus::kOk;
}

FwStatus ValidateParams(const Params& p, uint16_t* bad_id) {
  for (const Entry& e : kTable) {
    if (!InRange(e, Read(p, e))) {
      if (bad_id != nullptr) *bad_id = e.id;
      return FwStatus::kInvalid;
    }
  }
  if (p.ticks_per_rev < 4.f || p.node_id > 63) {
    if (bad_id != nullptr) *bad_id = 0;
    return FwStatus::kInvalid;
  }
  return FwStatus::kOk;
}

}  // namespace omni::firmware
