// Plant model of the omni base for the firmware simulator and the host tests: three DC
// gear-motors driving omni wheels, each with its own inertia, Coulomb and viscous friction,
// a quantised x4 encoder on a 16-bit counter, current sense, a supply voltage, and an
// optional kinematic wheel slip. The true body pose is integrated from the wheels' ground
// contact speeds with the shared forward kinematics (eq. (1) inverted, eq. (2)).
//
// Per wheel (omega = wheel speed, rad/s; u = PWM duty; N = gear ratio):
//   i = (u * V - ke * N * omega) / R            (0 when the bridge is disabled)
//   J dω/dt = N * kt * i - c * sign(omega) - b * omega
//   J = N^2 * J_rotor + m r^2 / 3   (rotor plus a third of the robot's mass at the rim)
// Ground contact speed = r * omega * (1 - slip_i): slip_i is the fraction of rim motion lost.
#pragma once

#include <cstdint>

#include "omni/common/kinematics.h"

namespace omni::firmware::sim {

struct PlantParams {
  double supply_v = 12.0;
  double resistance_ohm = 2.0;
  double kt_nm_a = 0.01;  // motor torque constant (= back-EMF constant, V s/rad)
  double gear_ratio = 30.0;
  double rotor_inertia_kg_m2 = 1.0e-6;
  double robot_mass_kg = 8.0;
  double coulomb_nm = 0.03;     // at the wheel
  double viscous_nm_s = 0.002;  // at the wheel
  double alpha_rad = 2.0943951023931954923;
  double center_to_wheel_m = 0.15;
  double wheel_radius_m = 0.05;
  double ticks_per_rev = 1440.0;  // x4 counts per wheel turn
  double slip[3] = {0.0, 0.0, 0.0};
  uint16_t encoder_offset = 65000;  // initial counter value: exercises the wrap at once
  int substeps = 4;                 // integration steps per Advance()
};

class Plant {
 public:
  explicit Plant(const PlantParams& p);

  // Integrates over dt_s with the current duties.
  void Advance(double dt_s);

  void SetDuty(int w, double duty) { duty_[w] = duty; }
  void SetEnabled(bool on) { enabled_ = on; }
  uint16_t EncoderRaw(int w) const;
  double CurrentA(int w) const { return current_[w]; }
  double SupplyV() const { return supply_override_ >= 0 ? supply_override_ : p_.supply_v; }
  double WheelSpeed(int w) const { return omega_[w]; }
  int64_t EncoderCounts(int w) const;

  // Fault injection.
  void FreezeEncoder(int w, bool frozen);
  void LockWheel(int w, bool locked) { locked_[w] = locked; }
  // Encoder channels A and B swapped: the raw counter runs the other way.
  void ReverseEncoder(int w, bool reversed) { reversed_[w] = reversed; }
  void OverrideSupply(double v) { supply_override_ = v; }  // < 0: back to nominal
  void SetSlip(int w, double s) { p_.slip[w] = s; }

  // True pose of the base in the start frame, from ground contact speeds.
  double x_m() const { return x_; }
  double y_m() const { return y_; }
  double theta_rad() const { return theta_; }
  double distance_m() const { return distance_; }  // path length of the base centre
  const PlantParams& params() const { return p_; }

 private:
  PlantParams p_;
  double omega_[3] = {0, 0, 0};
  double angle_[3] = {0, 0, 0};  // wheel angle, rad
  double current_[3] = {0, 0, 0};
  double duty_[3] = {0, 0, 0};
  bool frozen_[3] = {false, false, false};
  int64_t frozen_counts_[3] = {0, 0, 0};
  bool locked_[3] = {false, false, false};
  bool reversed_[3] = {false, false, false};
  bool enabled_ = false;
  double supply_override_ = -1.0;
  double x_ = 0, y_ = 0, theta_ = 0, distance_ = 0;
};

}  // namespace omni::firmware::sim
