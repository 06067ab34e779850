#include "plant.h"

#include <cmath>

namespace omni::firmware::sim {

Plant::Plant(const PlantParams& p) : p_(p) {}

int64_t Plant::EncoderCounts(int w) const {
  if (frozen_[w]) return frozen_counts_[w];
  return static_cast<int64_t>(std::floor(angle_[w] / (2.0 * M_PI) * p_.ticks_per_rev));
}

uint16_t Plant::EncoderRaw(int w) const {
  const int64_t counts = reversed_[w] ? -EncoderCounts(w) : EncoderCounts(w);
  return static_cast<uint16_t>(static_cast<uint16_t>(p_.encoder_offset) +
                               static_cast<uint16_t>(counts & 0xFFFF));
}

void Plant::FreezeEncoder(int w, bool frozen) {
  if (frozen && !frozen_[w]) frozen_counts_[w] = EncoderCounts(w);
  frozen_[w] = frozen;
}

void Plant::Advance(double dt_s) {
  const int n = p_.substeps > 0 ? p_.substeps : 1;
  const double h = dt_s / n;
  const double r = p_.wheel_radius_m;
  const double inertia =
      p_.gear_ratio * p_.gear_ratio * p_.rotor_inertia_kg_m2 + p_.robot_mass_kg * r * r / 3.0;
  const omni::kinematics::OmniGeometry<double> g{p_.alpha_rad, p_.center_to_wheel_m, r};
  for (int k = 0; k < n; ++k) {
    omni::kinematics::WheelSpeeds<double> contact;
    for (int w = 0; w < 3; ++w) {
      const double v = enabled_ ? duty_[w] * SupplyV() : 0.0;
      const double back_emf = p_.kt_nm_a * p_.gear_ratio * omega_[w];
      current_[w] = enabled_ ? (v - back_emf) / p_.resistance_ohm : 0.0;
      if (locked_[w]) {
        omega_[w] = 0.0;
        current_[w] = enabled_ ? v / p_.resistance_ohm : 0.0;
      } else {
        const double drive = p_.gear_ratio * p_.kt_nm_a * current_[w] - p_.viscous_nm_s * omega_[w];
        if (omega_[w] == 0.0 && std::fabs(drive) <= p_.coulomb_nm) {
          // Stiction: not enough torque to break away.
        } else {
          const double dir =
              omega_[w] != 0.0 ? (omega_[w] > 0 ? 1.0 : -1.0) : (drive > 0 ? 1.0 : -1.0);
          const double next = omega_[w] + h * (drive - dir * p_.coulomb_nm) / inertia;
          // Friction cannot reverse the motion within a step.
          omega_[w] =
              (omega_[w] != 0.0 && next * omega_[w] < 0.0 && std::fabs(drive) <= p_.coulomb_nm)
                  ? 0.0
                  : next;
        }
      }
      angle_[w] += h * omega_[w];
      contact.v_m_s[w] = r * omega_[w] * (1.0 - p_.slip[w]);
    }
    omni::kinematics::BodyTwist<double> body;
    if (omni::kinematics::WheelsToBody(g, contact, &body)) {
      // Midpoint heading for the translation (exact enough at 4 substeps per ms).
      const double mid = theta_ + 0.5 * h * body.omega_rad_s;
      const auto world = omni::kinematics::BodyToWorld(mid, body);
      x_ += h * world.xdot_m_s;
      y_ += h * world.ydot_m_s;
      theta_ += h * world.thetadot_rad_s;
      distance_ += h * std::hypot(body.vx_m_s, body.vy_m_s);
    }
  }
}

}  // namespace omni::firmware::sim
