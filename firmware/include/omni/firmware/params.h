// Tunable parameters of the firmware: gains, limits, watchdog, geometry. Read and written over
// CAN (GET_PARAM / SET_PARAM) by id; every id has a range and writes outside it are refused.
#pragma once

#include <cstdint>

#include "omni/firmware/status.h"

namespace omni::firmware {

struct Params {
  // Speed loop (per wheel, wheel angular speed in rad/s, output duty in [-1, 1]).
  float kp = 0.2f;
  float ki = 0.5f;
  float kd = 0.f;
  float kff = 0.026f;  // ~ 1 / no-load wheel speed at full duty
  float max_duty = 0.95f;
  float max_wheel_speed_rad_s = 35.f;
  float max_wheel_accel_rad_s2 = 40.f;  // 2 m/s^2 at the rim with r = 5 cm
  float stop_decel_rad_s2 = 80.f;       // controlled stop after the watchdog
  uint32_t watchdog_ms = 200;
  // Faults.
  float current_limit_a = 5.f;  // over-current if above this for over_current_ms
  uint32_t over_current_ms = 20;
  float under_voltage_v = 9.f;  // under-voltage if below this for under_voltage_ms
  uint32_t under_voltage_ms = 50;
  uint32_t stall_ms = 300;  // encoder stalled while |duty| >= stall_duty
  float stall_duty = 0.3f;
  // Geometry (shared eq. (1)-(3) kinematics).
  float alpha_rad = 2.0943951f;     // angle between wheels 1 and 2
  float center_to_wheel_m = 0.15f;  // L
  float wheel_radius_m = 0.05f;     // r
  float ticks_per_rev = 1440.f;     // x4 counts per wheel revolution
  // Timing.
  uint32_t control_period_us = 1000;  // fixed, set at build time for the board
  uint32_t feedback_period_ms = 10;
  uint32_t heartbeat_period_ms = 100;
  uint8_t node_id = 1;
};

// CAN parameter ids (GET_PARAM / SET_PARAM). Stable: never renumber, only append.
enum ParamId : uint16_t {
  kParamKp = 1,
  kParamKi = 2,
  kParamKd = 3,
  kParamKff = 4,
  kParamMaxDuty = 5,
  kParamMaxWheelSpeed = 6,
  kParamMaxWheelAccel = 7,
  kParamStopDecel = 8,
  kParamWatchdogMs = 9,
  kParamCurrentLimit = 10,
  kParamOverCurrentMs = 11,
  kParamUnderVoltage = 12,
  kParamUnderVoltageMs = 13,
  kParamStallMs = 14,
  kParamStallDuty = 15,
  kParamAlpha = 16,
  kParamCenterToWheel = 17,
  kParamWheelRadius = 18,
  kParamTicksPerRev = 19,
  kParamFeedbackPeriodMs = 20,
  kParamHeartbeatPeriodMs = 21,
  kParamControlPeriodUs = 22,  // read-only
  kParamFirmwareVersion = 23,  // read-only
};

inline constexpr uint32_t kFirmwareVersion = 0x000100;  // 0.1.0

// Reads parameter `id` into *value.
[[nodiscard]] FwStatus GetParam(const Params& p, uint16_t id, float* value);
// Writes parameter `id`; refuses non-finite and out-of-range values (Params unchanged).
[[nodiscard]] FwStatus SetParam(Params* p, uint16_t id, float value);
// Checks every parameter against its range (a Params built by hand, e.g. from a config file).
[[nodiscard]] FwStatus ValidateParams(const Params& p, uint16_t* bad_id);

}  // namespace omni::firmware
