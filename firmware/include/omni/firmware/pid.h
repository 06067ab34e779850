// Speed controller of one wheel: PI(D) with feed-forward, anti-windup and output clamp,
// behind an acceleration (slew-rate) limiter on the setpoint.
//
//   u = kff * sp + kp * e + I - kd * d(meas)/dt,   e = sp - meas,   |u| <= u_max
//   I += ki * e * dt   only while u is not saturated in the direction e pushes
//   (conditional integration), and I itself is clamped to [-u_max, u_max].
#pragma once

namespace omni::firmware {

struct PidGains {
  float kp = 0.f;     // duty per rad/s of error
  float ki = 0.f;     // duty per rad of accumulated error
  float kd = 0.f;     // duty per rad/s^2 (on measurement, not on error)
  float kff = 0.f;    // duty per rad/s of setpoint (feed-forward: 1 / no-load speed at full duty)
  float u_max = 1.f;  // output clamp, duty
};

class SpeedPid {
 public:
  void Reset() {
    integral_ = 0.f;
    last_meas_ = 0.f;
    primed_ = false;
  }
  // One step of length dt_s; returns the clamped duty.
  float Update(const PidGains& g, float setpoint, float measured, float dt_s) {
    const float e = setpoint - measured;
    float d = 0.f;
    if (primed_ && dt_s > 0.f) d = (measured - last_meas_) / dt_s;
    last_meas_ = measured;
    primed_ = true;
    const float unsat = g.kff * setpoint + g.kp * e + integral_ - g.kd * d;
    const float u = Clamp(unsat, -g.u_max, g.u_max);
    const bool pushing_further = (unsat >= g.u_max && e > 0.f) || (unsat <= -g.u_max && e < 0.f);
    if (!pushing_further) {
      integral_ = Clamp(integral_ + g.ki * e * dt_s, -g.u_max, g.u_max);
    }
    return u;
  }
  float integral() const { return integral_; }

  static float Clamp(float v, float lo, float hi) { return v < lo ? lo : (v > hi ? hi : v); }

 private:
  float integral_ = 0.f;
  float last_meas_ = 0.f;
  bool primed_ = false;
};

// Moves `current` towards `target` by at most max_rate * dt_s.
inline float RampTowards(float current, float target, float max_rate, float dt_s) {
  const float step = max_rate * dt_s;
  if (target > current + step) return current + step;
  if (target < current - step) return current - step;
  return target;
}

}  // namespace omni::firmware
