// Kinematics of the three-wheel omnidirectional base (paper 002, section III-A).
//
// Header-only, templated on the scalar, no heap and no exceptions, so the firmware uses it
// with `float` and the host with `double`.
//
// Frames: body frame x forward, y left, z up; world frame fixed, heading theta CCW.
// Wheel i (1-based as in the paper) has a linear rim speed v_i (m/s), positive when the
// wheel pushes the body along its drive direction d_i. With alpha the angle between
// wheels 1 and 2 seen from the centre (120 deg on the paper's robot) and L the distance
// from the centre to each wheel:
//
//   eq. (1)   v = A(alpha, L) * [vx vy w]^T,   rows of A:
//               wheel 1: [ sin(alpha/2)   cos(alpha/2)  L ]
//               wheel 2: [-sin(alpha/2)   cos(alpha/2)  L ]
//               wheel 3: [ 0             -1             L ]
//   eq. (2)   [Xdot Ydot thetadot] = Rz(theta) [vx vy w]
//   eq. (3)   v = A(alpha, L) Rz(-theta) [Xdot Ydot thetadot]^T, rows:
//               wheel 1: [ sin(alpha/2 - theta)   cos(alpha/2 - theta)  L ]
//               wheel 2: [-sin(alpha/2 + theta)   cos(alpha/2 + theta)  L ]
//               wheel 3: [ sin(theta)            -cos(theta)            L ]
//
// Forward kinematics (wheel speeds -> body twist) is the least-squares solution of eq. (1),
// (A^T A)^-1 A^T v, which for three wheels in general position is the exact inverse.
#pragma once

#include <cmath>

namespace omni::kinematics {

template <typename T>
struct BodyTwist {
  T vx_m_s{0};       // forward, body frame
  T vy_m_s{0};       // left, body frame
  T omega_rad_s{0};  // CCW
};

template <typename T>
struct WorldVelocity {
  T xdot_m_s{0};        // world frame
  T ydot_m_s{0};        // world frame
  T thetadot_rad_s{0};  // CCW
};

// Linear rim speeds of wheels 1..3 (index 0..2), m/s.
template <typename T>
struct WheelSpeeds {
  T v_m_s[3]{0, 0, 0};
};

template <typename T>
struct OmniGeometry {
  T alpha_rad;          // angle between wheels 1 and 2 as seen from the centre (2*pi/3 nominal)
  T center_to_wheel_m;  // L: distance from the body centre to each wheel's contact point
  T wheel_radius_m;     // r: rim speed v = r * wheel angular speed
};

// The matrix of eq. (1), row-major.
template <typename T>
inline void BodyMatrix(const OmniGeometry<T>& g, T a[3][3]) {
  const T s = std::sin(g.alpha_rad / T(2));
  const T c = std::cos(g.alpha_rad / T(2));
  const T L = g.center_to_wheel_m;
  // clang-format off
  a[0][0] = s;    a[0][1] = c;     a[0][2] = L;
  a[1][0] = -s;   a[1][1] = c;     a[1][2] = L;
  a[2][0] = T(0); a[2][1] = T(-1); a[2][2] = L;
  // clang-format on
}

// Eq. (1): body twist -> wheel rim speeds.
template <typename T>
inline WheelSpeeds<T> BodyToWheels(const OmniGeometry<T>& g, const BodyTwist<T>& t) {
  T a[3][3];
  BodyMatrix(g, a);
  WheelSpeeds<T> w;
  for (int i = 0; i < 3; ++i) {
    w.v_m_s[i] = a[i][0] * t.vx_m_s + a[i][1] * t.vy_m_s + a[i][2] * t.omega_rad_s;
  }
  return w;
}

// Eq. (2): body twist -> world velocity at heading theta.
template <typename T>
inline WorldVelocity<T> BodyToWorld(T theta_rad, const BodyTwist<T>& t) {
  const T c = std::cos(theta_rad), s = std::sin(theta_rad);
  return {c * t.vx_m_s - s * t.vy_m_s, s * t.vx_m_s + c * t.vy_m_s, t.omega_rad_s};
}

// Inverse of eq. (2).
template <typename T>
inline BodyTwist<T> WorldToBody(T theta_rad, const WorldVelocity<T>& w) {
  const T c = std::cos(theta_rad), s = std::sin(theta_rad);
  return {c * w.xdot_m_s + s * w.ydot_m_s, -s * w.xdot_m_s + c * w.ydot_m_s, w.thetadot_rad_s};
}

// Eq. (3): world velocity at heading theta -> wheel rim speeds, written out as in the paper.
template <typename T>
inline WheelSpeeds<T> WorldToWheels(const OmniGeometry<T>& g, T theta_rad,
                                    const WorldVelocity<T>& w) {
  const T h = g.alpha_rad / T(2);
  const T L = g.center_to_wheel_m;
  WheelSpeeds<T> out;
  out.v_m_s[0] = std::sin(h - theta_rad) * w.xdot_m_s + std::cos(h - theta_rad) * w.ydot_m_s +
                 L * w.thetadot_rad_s;
  out.v_m_s[1] = -std::sin(h + theta_rad) * w.xdot_m_s + std::cos(h + theta_rad) * w.ydot_m_s +
                 L * w.thetadot_rad_s;
  out.v_m_s[2] =
      std::sin(theta_rad) * w.xdot_m_s - std::cos(theta_rad) * w.ydot_m_s + L * w.thetadot_rad_s;
  return out;
}

// Forward kinematics: least-squares body twist from the three rim speeds.
// Returns false (and leaves `out` untouched) when the geometry is degenerate.
template <typename T>
[[nodiscard]] inline bool WheelsToBody(const OmniGeometry<T>& g, const WheelSpeeds<T>& w,
                                       BodyTwist<T>* out) {
  T a[3][3];
  BodyMatrix(g, a);
  // Normal equations N x = b with N = A^T A, b = A^T v.
  T n[3][3];
  T b[3];
  for (int r = 0; r < 3; ++r) {
    b[r] = T(0);
    for (int c = 0; c < 3; ++c) {
      n[r][c] = T(0);
      for (int k = 0; k < 3; ++k) n[r][c] += a[k][r] * a[k][c];
    }
    for (int k = 0; k < 3; ++k) b[r] += a[k][r] * w.v_m_s[k];
  }
  const T det = n[0][0] * (n[1][1] * n[2][2] - n[1][2] * n[2][1]) -
                n[0][1] * (n[1][0] * n[2][2] - n[1][2] * n[2][0]) +
                n[0][2] * (n[1][0] * n[2][1] - n[1][1] * n[2][0]);
  const T scale = n[0][0] * n[1][1] * n[2][2];
  if (!(std::fabs(det) > T(1e-9) * (std::fabs(scale) + T(1e-30)))) return false;
  // Cramer's rule.
  T x[3];
  for (int col = 0; col < 3; ++col) {
    T m[3][3];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) m[r][c] = (c == col) ? b[r] : n[r][c];
    x[col] = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
              m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
              m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])) /
             det;
  }
  out->vx_m_s = x[0];
  out->vy_m_s = x[1];
  out->omega_rad_s = x[2];
  return true;
}

// Nominal geometry of the paper's base (120 deg between wheels); L and r are per robot.
template <typename T>
constexpr OmniGeometry<T> SymmetricGeometry(T center_to_wheel_m, T wheel_radius_m) {
  return {T(2.0943951023931954923), center_to_wheel_m, wheel_radius_m};
}

}  // namespace omni::kinematics
