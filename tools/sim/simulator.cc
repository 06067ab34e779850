#include "omni/sim/simulator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

#include "omni/depth_image_t.hpp"
#include "omni/imu_t.hpp"
#include "omni/kinect/depth_codec.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/sim/firmware_base.h"

namespace omni::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kBaseRadiusM = 0.3;  // the base's footprint, for walkers touching it
constexpr size_t kMaxTrail = 200000;  // steps a pushed walker remembers (1000 s at 200 Hz)

// Integrates a body twist over dt at the midpoint heading.
Pose2 Integrate(const Pose2& p, const kinematics::BodyTwist<double>& t, double dt) {
  const double mid = p.theta + 0.5 * t.omega_rad_s * dt;
  const double c = std::cos(mid), s = std::sin(mid);
  return Pose2(p.x + (c * t.vx_m_s - s * t.vy_m_s) * dt, p.y + (s * t.vx_m_s + c * t.vy_m_s) * dt,
               WrapAngle(p.theta + t.omega_rad_s * dt));
}

}  // namespace

Simulator::Simulator(World world, SimOptions options)
    : world_(std::move(world)), o_(options), tour_(BuiltInTour()), rng_(options.seed) {
  MakeWalkers();
}

void Simulator::MakeWalkers() {
  tracks_ = o_.walker_tracks;
  const double r = o_.walker_radius_m;
  if (tracks_.empty() && o_.walkers > 0 && !world_.boxes().empty()) {
    // An own random stream: without the depth camera the base's path and the sensors' noise are
    // drawn as without walkers (the camera's draws depend on what its pixels hit).
    std::mt19937_64 g(o_.seed ^ 0x5DEECE66DULL);
    double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
    for (const Box& b : world_.boxes()) {
      x0 = std::min(x0, b.x0);
      y0 = std::min(y0, b.y0);
      x1 = std::max(x1, b.x1);
      y1 = std::max(y1, b.y1);
    }
    std::uniform_real_distribution<double> ux(x0, x1), uy(y0, y1), ua(-kPi, kPi), ul(2.5, 10.0),
        uv(0.75, 1.25), u01(0.0, 1.0);
    const Pose2 start = tour_.empty() ? Pose2() : tour_.front();
    // A spare 0.1 m from the walls where the walker starts and along its track, so that it can
    // step aside there.
    auto roomy = [&](double x, double y) {
      return x >= x0 && x <= x1 && y >= y0 && y <= y1 && world_.Free(x, y, r + 0.1);
    };
    for (int attempt = 0; attempt < 100000 && static_cast<int>(tracks_.size()) < o_.walkers;
         ++attempt) {
      const double ax = ux(g), ay = uy(g), a = ua(g), want = ul(g), speed = uv(g), phase = u01(g);
      if (!roomy(ax, ay)) continue;
      const double cx = std::cos(a), sy = std::sin(a);
      double len = 0;
      while (len + 0.05 <= want && roomy(ax + (len + 0.05) * cx, ay + (len + 0.05) * sy))
        len += 0.05;
      if (len < 2.5) continue;
      const double px = ax + phase * len * cx, py = ay + phase * len * sy;
      if (std::hypot(px - start.x, py - start.y) < 1.5) continue;
      tracks_.push_back({ax, ay, ax + len * cx, ay + len * sy, o_.walker_speed_m_s * speed, phase});
    }
  }
  walkers_.clear();
  for (size_t i = 0; i < tracks_.size(); ++i) {
    const WalkerTrack& t = tracks_[i];
    Walker w;
    w.s = std::clamp(t.phase, 0.0, 1.0) * std::hypot(t.bx - t.ax, t.by - t.ay);
    w.p = TrackPoint(i, w.s);
    walkers_.push_back(w);
  }
}

Eigen::Vector2d Simulator::TrackPoint(size_t i, double s) const {
  const WalkerTrack& t = tracks_[i];
  const Eigen::Vector2d a(t.ax, t.ay), b(t.bx, t.by);
  const double len = (b - a).norm();
  return len > 1e-9 ? Eigen::Vector2d(a + std::clamp(s, 0.0, len) / len * (b - a)) : a;
}

std::vector<Eigen::Vector2d> Simulator::WalkerPositions() const {
  std::vector<Eigen::Vector2d> out;
  for (const Walker& w : walkers_) out.push_back(w.p);
  return out;
}

void Simulator::StepWalkers(const Pose2& robot, double dt, SimStats* stats) {
  const double r = o_.walker_radius_m, keep = o_.keep_clear_m;
  const Eigen::Vector2d rc(robot.x, robot.y);
  for (size_t i = 0; i < walkers_.size(); ++i) {
    const WalkerTrack& t = tracks_[i];
    const Eigen::Vector2d a(t.ax, t.ay), b(t.bx, t.by);
    const double len = (b - a).norm();
    const double step = std::max(0.0, t.speed_m_s) * dt;
    Walker& w = walkers_[i];
    const double d = (w.p - rc).norm();
    // A move to q is taken when the floor there is free and, near the base, it is not closer to
    // the base than where the walker stands.
    auto take = [&](const Eigen::Vector2d& q) {
      const double dq = (q - rc).norm();
      if (!world_.Free(q.x(), q.y(), r) || (dq < keep && dq <= d)) return false;
      if (stats != nullptr) stats->walker_distance_m += (q - w.p).norm();
      w.p = q;
      return true;
    };
    // A step of `step` towards `dir` (unit), or as close to it as the walls allow: turned away
    // from it by up to 2 rad, to the side it turned to last, so that it follows a wall round
    // instead of dithering along it.
    auto step_towards = [&](const Eigen::Vector2d& dir) {
      if (take(w.p + step * dir)) {
        w.detour = 0;
        return true;
      }
      const int first = w.detour != 0 ? w.detour : 1;
      for (int side : {first, -first})
        for (double turn : {0.5, 1.0, 1.5, 2.0}) {
          const double c = std::cos(side * turn), sn = std::sin(side * turn);
          if (take(w.p + step * Eigen::Vector2d(c * dir.x() - sn * dir.y(),
                                                sn * dir.x() + c * dir.y()))) {
            w.detour = side;
            return true;
          }
        }
      return false;
    };
    bool yielded = false;
    // Kept waiting long enough (a base parked in the way): another way, below.
    auto out_of_patience = [&] {
      w.waited_s += dt;
      if (w.waited_s < o_.walker_patience_s) return false;
      w.waited_s = 0;
      return true;
    };
    if (d < keep) {
      // The base comes at it: away from the base. Where it stood is kept, to go back the way it
      // came.
      const Eigen::Vector2d from = w.p;
      if (step_towards(d > 1e-9 ? Eigen::Vector2d((w.p - rc) / d) : Eigen::Vector2d(1, 0))) {
        if (w.trail.size() >= kMaxTrail) w.trail.clear();  // too long: back the shortest way
        w.trail.push_back(from);
      }
      w.off_track = true;
      w.waited_s = 0;
      yielded = true;
    } else if (w.off_track && !w.trail.empty()) {
      // Back the way it was pushed (every point of it was free floor), once the base has passed.
      if (take(w.trail.back())) {
        w.trail.pop_back();
        // Where it left its track, at the same s (unless the trail began off it: then on by the
        // shortest way, below).
        if (w.trail.empty() && (w.p - TrackPoint(i, w.s)).norm() < 1e-9) {
          w.off_track = false;
          w.detour = 0;
        }
      } else {
        yielded = true;
        // Then to the nearest point of its track, round the base (the branch below).
        if (out_of_patience()) w.trail.clear();
      }
    } else if (w.off_track) {
      // No way back kept (a trail over kMaxTrail steps, or one that began off the track): to the
      // nearest point of its track, round what is in the way.
      const double s = len > 1e-9 ? std::clamp((w.p - a).dot(b - a) / len, 0.0, len) : 0.0;
      const Eigen::Vector2d on = TrackPoint(i, s), to = on - w.p;
      const double gap = to.norm();
      if (gap <= step && take(on)) {
        w.off_track = false;
        w.detour = 0;
        w.s = s;
      } else {
        yielded = !step_towards(gap > 1e-9 ? Eigen::Vector2d(to / gap) : Eigen::Vector2d(1, 0));
      }
    } else {
      double s = w.s + w.dir * step, dir = w.dir;
      if (s > len) {
        s = std::max(0.0, 2 * len - s);
        dir = -1;
      } else if (s < 0) {
        s = std::min(len, -s);
        dir = 1;
      }
      if (take(TrackPoint(i, s))) {
        w.s = s;
        w.dir = dir;
      } else {
        yielded = true;                         // waiting for the base to pass
        if (out_of_patience()) w.dir = -w.dir;  // it does not: back the way it came
      }
    }
    if (!yielded) w.waited_s = 0;
    if (stats != nullptr) {
      stats->walker_yields += yielded ? 1 : 0;
      if ((w.p - rc).norm() < r + kBaseRadiusM) ++stats->walker_contacts;
    }
  }
}

double Simulator::Cast(const Vec3& o, const Vec3& d, double t_max) const {
  const double world = world_.Cast(o, d, t_max);
  if (walkers_.empty()) return world;
  double best = world >= 0 ? world : t_max;
  bool hit = world >= 0;
  const double r = o_.walker_radius_m, h = o_.walker_height_m;
  const double a = d.x * d.x + d.y * d.y;
  for (size_t i = 0; i < walkers_.size(); ++i) {
    const Eigen::Vector2d& c = walkers_[i].p;
    const double ox = o.x - c.x(), oy = o.y - c.y();
    const double cc = ox * ox + oy * oy - r * r;
    if (cc <= 0 && o.z >= 0 && o.z <= h) return 0.0;  // inside a walker
    double t = -1;
    if (a > 0) {  // its side
      const double half_b = ox * d.x + oy * d.y, disc = half_b * half_b - a * cc;
      if (disc >= 0) {
        const double t0 = (-half_b - std::sqrt(disc)) / a;
        const double z = o.z + t0 * d.z;
        if (t0 >= 0 && z >= 0 && z <= h) t = t0;
      }
    }
    if (t < 0 && o.z > h && d.z < 0) {  // its top, seen from above
      const double tc = (h - o.z) / d.z, x = ox + tc * d.x, y = oy + tc * d.y;
      if (x * x + y * y <= r * r) t = tc;
    }
    if (t >= 0 && t < best) {
      best = t;
      hit = true;
    }
  }
  return hit ? best : -1.0;
}

std::vector<Pose2> Simulator::BuiltInTour() {
  const double e = 0, n = kPi / 2, w = kPi, s = -kPi / 2;
  return {
      // The corridor loop, counter-clockwise; along the east side the base strafes (it keeps
      // facing east while it drives north), which only an omnidirectional base can do.
      {2.5, 3.0, e},
      {17.5, 3.0, e},
      {17.5, 11.0, e},
      {2.5, 11.0, w},
      {2.5, 3.0, s},
      // Through the inner room: in by the south doorway, out by the north one, then the east
      // and south corridors again (loops close on ground already mapped).
      {9.7, 3.0, e},
      {9.7, 6.0, n},
      {11.7, 8.0, n},
      {11.7, 11.0, n},
      {17.5, 11.0, e},
      {17.5, 3.0, s},
      {2.5, 3.0, w},
  };
}

float Simulator::BeamRange(const Pose2& base, int i) {
  const Pose2 sensor = base * Pose2(o_.lidar_x_m, o_.lidar_y_m, o_.lidar_yaw_rad);
  std::normal_distribution<double> noise(0.0, o_.range_noise_m);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const double a = sensor.theta - kPi + i * (2 * kPi / o_.lidar_beams);
  const Vec3 origin{sensor.x, sensor.y, o_.lidar_height_m};
  const double t = Cast(origin, {std::cos(a), std::sin(a), 0.0}, o_.range_max_m);
  const double n = noise(rng_);
  const bool dropout = u01(rng_) < o_.dropout_probability;
  double r = std::numeric_limits<double>::quiet_NaN();
  if (t >= o_.range_min_m && !dropout) r = std::max(o_.range_min_m, t + n);
  if (r >= o_.range_max_m) r = std::numeric_limits<double>::quiet_NaN();
  return static_cast<float>(r);
}

std::vector<float> Simulator::ScanRanges(const Pose2& base) {
  std::vector<float> ranges(static_cast<size_t>(o_.lidar_beams));
  for (int i = 0; i < o_.lidar_beams; ++i) ranges[static_cast<size_t>(i)] = BeamRange(base, i);
  return ranges;
}

std::vector<uint16_t> Simulator::DepthImage(const Pose2& base) {
  const Pose2 cam = base * Pose2(o_.cam_x_m, o_.cam_y_m, o_.cam_yaw_rad);
  const double cy = std::cos(cam.theta), sy = std::sin(cam.theta);
  const double ct = std::cos(o_.cam_tilt_rad), st = std::sin(o_.cam_tilt_rad);
  const double cxp = (o_.depth_width - 1) / 2.0, cyp = (o_.depth_height - 1) / 2.0;
  const Vec3 origin{cam.x, cam.y, o_.cam_height_m};
  std::normal_distribution<double> n01(0.0, 1.0);
  std::vector<uint16_t> img(static_cast<size_t>(o_.depth_width) * o_.depth_height, 0);
  for (int v = 0; v < o_.depth_height; ++v) {
    for (int u = 0; u < o_.depth_width; ++u) {
      // Optical ray (x right, y down, z = 1) in the camera body frame, tilted, then yawed.
      const double xo = (u - cxp) / o_.depth_fx, yo = (v - cyp) / o_.depth_fy;
      const double fwd = 1.0, left = -xo, up = -yo;
      const double fwd_t = fwd * ct + up * st, up_t = up * ct - fwd * st;
      const Vec3 d{fwd_t * cy - left * sy, fwd_t * sy + left * cy, up_t};
      // |d| = |(xo, yo, 1)|, so the cast's parameter is the depth along the optical axis.
      const double z = Cast(origin, d, o_.depth_max_m * 1.5);
      if (z < o_.depth_min_m) continue;
      const double noisy = z + o_.depth_noise_per_m2 * z * z * n01(rng_);
      if (noisy < o_.depth_min_m || noisy > o_.depth_max_m) continue;
      img[static_cast<size_t>(v) * o_.depth_width + u] =
          static_cast<uint16_t>(std::lround(noisy * 1000.0));
    }
  }
  return img;
}

SimStats Simulator::Run(const std::function<void(const SimEvent&)>& sink,
                        const std::function<void(int64_t, int64_t, const Pose2&)>& truth) {
  SimStats st;
  st.walkers = static_cast<int>(walkers_.size());
  const auto geom = kinematics::SymmetricGeometry(o_.center_to_wheel_m, o_.wheel_radius_m);
  const double dt = 1.0 / o_.physics_hz;
  std::normal_distribution<double> n01(0.0, 1.0);
  std::vector<Pose2> route;
  for (int lap = 0; lap < std::max(1, o_.laps); ++lap)
    route.insert(route.end(), tour_.begin() + (lap == 0 ? 0 : 1), tour_.end());
  if (route.empty()) return st;
  Pose2 pose = route.front(), odom = pose;
  const Pose2 start = pose;
  const bool firmware = o_.base == SimOptions::Base::kFirmware;
  // The bridge's limits and timing: the firmware base's bridge runs with them, and the ideal
  // base applies them to outside commands.
  const base_bridge::BaseBridgeOptions limits =
      o_.bridge ? *o_.bridge : FirmwareBase::ShippedBridgeOptions();
  std::unique_ptr<FirmwareBase> base;
  if (firmware) {
    base = std::make_unique<FirmwareBase>(o_.center_to_wheel_m, o_.wheel_radius_m, limits);
    if (!base->booted(&st.base_problem)) return st;
  }
  auto base_sink = [&](const SimEvent& e) {
    if (e.channel == base->bridge_options().odom_channel) ++st.odometry;
    sink(e);
  };
  if (firmware) {
    // The base boots before the tour starts: firmware heartbeats and encoder feedback (the
    // odometry at rest) are on the bus when the first scan is taken, as on a robot whose base
    // came up first.
    const double boot_s = 0.2;
    for (int64_t us = o_.start_utime - std::llround(boot_s * 1e6); us < o_.start_utime;
         us += std::llround(dt * 1e6))
      base->Advance(nullptr, us, dt, base_sink);
  }
  double imu_yaw = pose.theta;
  double vx_w = 0, vy_w = 0;  // commanded world velocity
  // Driven from outside (set_command_source): the commands of this step, and for the ideal
  // base the twist it holds, since when, and whether it is e-stopped.
  const bool external = static_cast<bool>(command_source_);
  std::vector<base_bridge::Command> arrived;
  kinematics::BodyTwist<double> held{};
  int64_t held_since = 0;
  bool estopped = false;
  size_t target = 1;
  int64_t seq_scan = 0, seq_odom = 0, seq_imu = 0, seq_depth = 0;
  double next_scan = 0, next_odom = 0, next_imu = 0, next_depth = 0;
  // A lidar revolution in progress (lidar_sweep): beam i is measured at sweep_t0 + i *
  // sweep_beam_s from the pose interpolated within the physics step.
  const double sweep_beam_s = 1.0 / (o_.lidar_hz * o_.lidar_beams);
  omni::laser_scan_t sweep{};
  bool sweeping = false;
  double sweep_t0 = 0;
  Pose2 sweep_pose;
  int sweep_next_beam = 0;
  kinematics::BodyTwist<double> measured{};
  int64_t utime = o_.start_utime;
  for (int64_t step = 0;; ++step) {
    const double t = static_cast<double>(step) * dt;
    utime = o_.start_utime + static_cast<int64_t>(std::llround(t * 1e6));
    if (o_.max_duration_s > 0 && t > o_.max_duration_s) break;
    arrived.clear();
    if ((stop_ != nullptr && stop_->load()) || (external && !command_source_(utime, &arrived))) {
      st.stopped = true;
      break;
    }
    st.commands += static_cast<int64_t>(arrived.size());
    // The next waypoint not yet reached (the tour's follower only).
    while (!external && target < route.size()) {
      const Pose2& goal = route[target];
      if (std::hypot(goal.x - pose.x, goal.y - pose.y) >= o_.waypoint_tolerance_m ||
          std::abs(WrapAngle(goal.theta - pose.theta)) >= 0.1)
        break;
      ++target;
    }
    if (!external && target >= route.size()) {
      st.tour_finished = true;
      break;
    }
    // Sensors at this instant (true pose `pose`, odometry `odom`).
    // Odometry first: a consumer then has odometry at every scan's time. (The firmware base's
    // odometry comes from the bridge as the base advances, stamped up to this instant.)
    if (!firmware && t >= next_odom) {
      omni::odometry_t m{};
      m.utime = utime;
      m.seq = seq_odom++;
      m.frame = "odom";
      m.child_frame = "base";
      m.x_m = odom.x;
      m.y_m = odom.y;
      m.yaw_rad = odom.theta;
      m.vx_m_s = measured.vx_m_s;
      m.vy_m_s = measured.vy_m_s;
      m.omega_rad_s = measured.omega_rad_s;
      const double d = st.distance_m;
      m.pose_covariance[0] = m.pose_covariance[4] = 1e-4 * d;
      m.pose_covariance[8] = 1e-3 * d;
      m.twist_covariance[0] = m.twist_covariance[4] = o_.wheel_noise_m_s * o_.wheel_noise_m_s;
      m.twist_covariance[8] = m.twist_covariance[0] / (o_.center_to_wheel_m * o_.center_to_wheel_m);
      sink(EncodeEvent("WHEEL_ODOM", utime, m));
      ++st.odometry;
      next_odom += 1.0 / o_.odom_hz;
    }
    if (t >= next_scan - 1e-9) {  // (next_scan accumulates rounding error)
      omni::laser_scan_t m{};
      m.utime = utime;  // the first beam's time
      m.seq = seq_scan;
      m.frame = "laser";
      m.sensor_x_m = o_.lidar_x_m;
      m.sensor_y_m = o_.lidar_y_m;
      m.sensor_yaw_rad = o_.lidar_yaw_rad;
      m.angle_min_rad = static_cast<float>(-kPi);
      m.angle_increment_rad = static_cast<float>(2 * kPi / o_.lidar_beams);
      m.range_min_m = static_cast<float>(o_.range_min_m);
      m.range_max_m = static_cast<float>(o_.range_max_m);
      m.num_intensities = 0;
      if (o_.lidar_sweep) {
        // The beams are measured one after another over the revolution as the base moves; the
        // scan is published when its last beam is in (below).
        m.scan_time_s = static_cast<float>(sweep_beam_s * (o_.lidar_beams - 1));
        m.ranges_m.assign(static_cast<size_t>(o_.lidar_beams), 0.f);
        m.num_ranges = o_.lidar_beams;
        sweep = m;
        sweep_t0 = t;
        sweep_pose = pose;
        sweep_next_beam = 0;
        sweeping = true;
      } else {
        m.scan_time_s = 0.f;  // every beam at one instant
        m.ranges_m = ScanRanges(pose);
        m.num_ranges = static_cast<int32_t>(m.ranges_m.size());
        sink(EncodeEvent("LIDAR_SCAN", utime, m));
        if (truth) truth(seq_scan, utime, pose);
        ++st.scans;
      }
      ++seq_scan;
      next_scan += 1.0 / o_.lidar_hz;
    }
    if (t >= next_imu) {
      omni::imu_t m{};
      m.utime = utime;
      m.seq = seq_imu++;
      m.frame = "imu";
      m.orientation_wxyz[0] = std::cos(imu_yaw / 2);
      m.orientation_wxyz[3] = std::sin(imu_yaw / 2);
      m.orientation_covariance[8] = 1e-2;
      m.orientation_covariance[0] = m.orientation_covariance[4] = 1e-3;
      m.angular_velocity_rad_s[2] = measured_gyro_;
      for (int i = 0; i < 3; ++i) {
        m.angular_velocity_covariance[4 * i] = o_.gyro_noise_rad_s * o_.gyro_noise_rad_s;
        m.linear_acceleration_covariance[4 * i] = o_.accel_noise_m_s2 * o_.accel_noise_m_s2;
        m.linear_acceleration_m_s2[i] = (i == 2 ? 9.80665 : 0.0) + o_.accel_noise_m_s2 * n01(rng_);
        m.magnetic_field_t[i] = std::numeric_limits<double>::quiet_NaN();
      }
      m.temperature_c = std::numeric_limits<float>::quiet_NaN();
      sink(EncodeEvent("IMU", utime, m));
      ++st.imu;
      next_imu += 1.0 / o_.imu_hz;
    }
    if (o_.depth && t >= next_depth) {
      const std::vector<uint16_t> img = DepthImage(pose);
      omni::depth_image_t m{};
      m.utime = utime;
      m.seq = seq_depth++;
      m.frame = "depth_optical";
      m.width = o_.depth_width;
      m.height = o_.depth_height;
      m.fx = o_.depth_fx;
      m.fy = o_.depth_fy;
      m.cx = (o_.depth_width - 1) / 2.0;
      m.cy = (o_.depth_height - 1) / 2.0;
      m.depth_scale = 1000.0;
      m.registered_to_color = false;
      m.encoding = static_cast<int8_t>(kinect::DepthEncoding::kDeltaZlib);
      m.uncompressed_size = static_cast<int32_t>(img.size() * 2);
      if (kinect::EncodeDepth(kinect::DepthEncoding::kDeltaZlib, img.data(), o_.depth_width,
                              o_.depth_height, {}, &m.data)
              .ok()) {
        m.size = static_cast<int32_t>(m.data.size());
        sink(EncodeEvent("DEPTH", utime, m));
        ++st.depth_frames;
      }
      next_depth += 1.0 / o_.depth_hz;
    }

    kinematics::BodyTwist<double> cmd{};
    if (!external && t < o_.still_s) {
      // Standing still before the tour: a zero twist, as a planner holds at power-up.
    } else if (!external) {
      // Waypoint follower: holonomic, slowing into each waypoint, acceleration-limited.
      const Pose2& goal = route[target];
      const double ex = goal.x - pose.x, ey = goal.y - pose.y;
      const double dist = std::hypot(ex, ey);
      const double heading_err = WrapAngle(goal.theta - pose.theta);
      const double speed = dist > 1e-9 ? std::min(o_.max_speed_m_s, 0.6 * dist + 0.05) : 0.0;
      const double want_x = dist > 1e-9 ? speed * ex / dist : 0.0;
      const double want_y = dist > 1e-9 ? speed * ey / dist : 0.0;
      const double dvx = want_x - vx_w, dvy = want_y - vy_w, dv = std::hypot(dvx, dvy);
      const double dv_max = o_.max_accel_m_s2 * dt;
      const double k = dv > dv_max ? dv_max / dv : 1.0;
      vx_w += k * dvx;
      vy_w += k * dvy;
      const double omega =
          std::clamp(2.0 * heading_err, -o_.max_yaw_rate_rad_s, o_.max_yaw_rate_rad_s);
      cmd =
          kinematics::WorldToBody(pose.theta, kinematics::WorldVelocity<double>{vx_w, vy_w, omega});
    } else if (!firmware) {
      // The ideal base takes outside commands as the bridge would: twists clamped to its
      // limits and held for its command timeout, an e-stop until faults are cleared; the
      // bridge's acceleration ramp is left out (the ideal base has no dynamics either).
      for (const auto& c : arrived) {
        if (c.mode == base_bridge::Command::kEstop) {
          estopped = true;
        } else if (c.mode == base_bridge::Command::kClearFaults) {
          estopped = false;
        } else if (c.mode != base_bridge::Command::kTwist || !std::isfinite(c.vx_m_s) ||
                   !std::isfinite(c.vy_m_s) || !std::isfinite(c.omega_rad_s)) {
          ++st.commands_rejected;
        } else {
          held = {std::clamp(c.vx_m_s, -limits.max_vx_m_s, limits.max_vx_m_s),
                  std::clamp(c.vy_m_s, -limits.max_vy_m_s, limits.max_vy_m_s),
                  std::clamp(c.omega_rad_s, -limits.max_omega_rad_s, limits.max_omega_rad_s)};
          held_since = utime;
        }
      }
      const bool fresh = static_cast<double>(utime - held_since) * 1e-6 <= limits.command_timeout_s;
      if (!estopped && fresh && held_since != 0) cmd = held;
    }
    Pose2 next;
    double true_omega = cmd.omega_rad_s;
    if (firmware) {
      // The command goes through the bridge and the firmware to the plant; each wheel slips by
      // its own fraction this step, which its encoder does not see.
      for (int i = 0; i < 3; ++i)
        base->SetSlip(i, std::clamp(o_.wheel_slip[i] + o_.wheel_slip_noise * n01(rng_), 0.0, 0.5));
      if (external) {
        for (const auto& c : arrived) base->OnCommand(c, utime);
        base->Advance(nullptr, utime, dt, base_sink);
      } else {
        base->Advance(&cmd, utime, dt, base_sink);
      }
      next = start * base->pose();
      true_omega = WrapAngle(next.theta - pose.theta) / dt;
    } else {
      // The wheels turn at eq. (1)'s rim speeds; the encoders see them with scale errors and
      // noise; the odometry integrates what the encoders saw.
      const auto wheels = kinematics::BodyToWheels(geom, cmd);
      kinematics::WheelSpeeds<double> seen;
      for (int i = 0; i < 3; ++i)
        seen.v_m_s[i] =
            wheels.v_m_s[i] * (1.0 + o_.wheel_scale_error[i]) + o_.wheel_noise_m_s * n01(rng_);
      if (!kinematics::WheelsToBody(geom, seen, &measured)) measured = {};
      next = Integrate(pose, cmd, dt);
      odom = Integrate(odom, measured, dt);
    }
    measured_gyro_ = true_omega + o_.gyro_bias_rad_s + o_.gyro_noise_rad_s * n01(rng_);
    imu_yaw = WrapAngle(imu_yaw + measured_gyro_ * dt);
    st.distance_m += std::hypot(next.x - pose.x, next.y - pose.y);
    st.rotation_rad += std::abs(true_omega) * dt;
    if (sweeping) {
      // Beams whose time falls in this step, from the pose between `pose` (t) and `next`.
      for (; sweep_next_beam < o_.lidar_beams; ++sweep_next_beam) {
        const double tb = sweep_t0 + sweep_next_beam * sweep_beam_s;
        if (tb >= t + dt) break;
        const double f = std::clamp((tb - t) / dt, 0.0, 1.0);
        sweep.ranges_m[static_cast<size_t>(sweep_next_beam)] =
            BeamRange(Interpolate(pose, next, f), sweep_next_beam);
      }
      if (sweep_next_beam == o_.lidar_beams) {
        // Published when the revolution is complete (the event's time), stamped with its first
        // beam's time, as the RPLidar driver does.
        const int64_t done = o_.start_utime + static_cast<int64_t>(std::llround((t + dt) * 1e6));
        sink(EncodeEvent("LIDAR_SCAN", done, sweep));
        if (truth) truth(sweep.seq, sweep.utime, sweep_pose);
        ++st.scans;
        sweeping = false;
      }
    }
    StepWalkers(next, dt, &st);
    pose = next;
    st.duration_s = t;
  }
  if (firmware) {
    const auto& fs = base->stats();
    st.can_frames = fs.frames_to_firmware + fs.frames_from_firmware;
    st.encoders = fs.encoders;
    st.base_status = fs.status;
    st.firmware_state = static_cast<int>(base->firmware().state());
    st.firmware_faults = base->firmware().fault_bits();
    st.watchdog_trips = base->firmware().counters().watchdog_trips;
    st.base_problem = base->Problem(utime);
    if (external) st.commands_rejected = base->bridge().counters().commands_rejected;
  }
  return st;
}

}  // namespace omni::sim
