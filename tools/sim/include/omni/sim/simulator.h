// The built-in simulator: the three-wheel omni base driving a scripted tour of a World, with the
// sensors the stack expects on the bus, so the whole pipeline runs without hardware or data.
//
// Motion: a holonomic waypoint follower commands a body twist from the true pose. Two bases:
//   firmware (the default): the twist goes through the real base bridge and firmware code to
//     the motor-and-wheel plant (firmware_base.h); the true pose is the plant's, WHEEL_ODOM is
//     the bridge's encoder odometry (plus WHEEL_ENCODERS and BASE_STATUS), and it drifts
//     because each wheel slips by its own fraction (plus noise) that the encoders cannot see.
//   ideal: the true pose integrates the twist (eq. 2); the wheels' rim speeds follow from
//     eq. (1), the encoders see them with a per-wheel scale error and noise, and the odometry
//     integrates the forward kinematics of what they saw.
// Either way the odometry drifts the way a real omni base's does (systematic heading drift plus
// a random walk), while the truth stays exact.
//
// Sensors (each at its own rate, stamped with simulated time):
//   LIDAR_SCAN  laser_scan_t: a 360-degree scanner in a plane at lidar_height_m, Gaussian range
//               noise, NaN beyond range_max_m or on random dropouts;
//   WHEEL_ODOM  odometry_t: the encoder odometry above, with its twist (firmware base: the base
//               bridge's, at the firmware's 100 Hz feedback rate, with WHEEL_ENCODERS and
//               BASE_STATUS beside it; ideal base: at odom_hz);
//   IMU         imu_t: gyro z with bias and noise, accelerometer at rest plus noise, heading
//               quaternion from the integrated gyro;
//   DEPTH       depth_image_t: a pinhole depth camera (Kinect-like noise growing with the square
//               of the depth, millimetre units, DELTA_ZLIB encoded), mounted like
//               config/octomap_builder.yaml's camera_mount defaults.
// People (`walkers`): vertical cylinders walking back and forth on straight tracks through the
// free floor, seen by the lidar and the depth camera but not part of the world's truth map, so
// the mappers meet moving obstacles the way a robot among people does (below).
// Everything random comes from `seed`: the same options give the same bytes (and with no walkers
// the bytes of a simulator without them).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "omni/base_bridge/base_bridge.h"
#include "omni/common/geometry.h"
#include "omni/common/kinematics.h"
#include "omni/sim/event.h"
#include "omni/sim/world.h"

namespace omni::sim {

// A person walking back and forth between two points of the floor, a vertical cylinder. It
// starts `phase` of the way from a to b, heading for b. It waits while walking on would bring it
// closer than `keep_clear_m` to the robot's centre, and steps away when the robot comes at it
// (the tour's follower does not steer around people); it only ever moves to where the world is
// free for its radius. A walker kept waiting `walker_patience_s` (a base parked in its way) turns
// back along its track, or, on its way back to the track, gives up the way it was pushed and
// heads for the nearest point of the track instead.
struct WalkerTrack {
  double ax = 0, ay = 0, bx = 0, by = 0;  // world frame, metres
  double speed_m_s = 0.8;
  double phase = 0;  // [0, 1]
};

struct SimOptions {
  uint64_t seed = 1;
  int64_t start_utime = 1700000000000000;  // simulated clock at t = 0
  double max_duration_s = 0;               // 0: until the tour ends
  int laps = 1;                            // times the tour is driven
  double still_s = 0;  // the tour's follower first stands still this long (a robot at power-up)
  double physics_hz = 200;
  enum class Base { kFirmware, kIdeal } base = Base::kFirmware;
  // Motion.
  double max_speed_m_s = 0.4;
  double max_accel_m_s2 = 0.5;
  double max_yaw_rate_rad_s = 0.8;
  double waypoint_tolerance_m = 0.15;
  double center_to_wheel_m = 0.2;
  double wheel_radius_m = 0.05;
  // Ideal base: measured = true * (1 + e), plus noise.
  double wheel_scale_error[3] = {0.010, -0.006, 0.004};
  double wheel_noise_m_s = 0.01;  // per physics step, per wheel
  // Firmware base: the fraction of rim motion each wheel loses at the ground (the encoders see
  // the motor turn, the base moves less), redrawn every physics step with this sigma. The
  // differences between wheels match the ideal base's scale errors.
  double wheel_slip[3] = {0.026, 0.010, 0.020};
  double wheel_slip_noise = 0.01;
  // Lidar.
  double lidar_hz = 10;
  int lidar_beams = 360;
  double lidar_x_m = 0.1, lidar_y_m = 0.0, lidar_yaw_rad = 0.0, lidar_height_m = 0.3;
  double range_min_m = 0.15, range_max_m = 12.0;
  double range_noise_m = 0.01;
  double dropout_probability = 0.01;
  // true: the beams are measured one after another over the revolution (1 / lidar_hz) while
  // the base moves, as a spinning lidar does, and the scan is published when the revolution
  // ends (scan_time_s says how long it took; the mappers undo the motion from odometry);
  // false: every beam at the scan's instant (scan_time_s 0).
  bool lidar_sweep = true;
  // Odometry and IMU.
  double odom_hz = 50;
  double imu_hz = 100;
  double gyro_bias_rad_s = 0.002;
  double gyro_noise_rad_s = 0.005;
  double accel_noise_m_s2 = 0.05;
  // Depth camera (optical frame z forward, x right, y down).
  bool depth = true;
  double depth_hz = 5;
  int depth_width = 320, depth_height = 240;
  double depth_fx = 262.5, depth_fy = 262.5;  // 58 x 49 degrees at 320 x 240 (Kinect v1 / 2)
  double cam_x_m = 0.10, cam_y_m = 0.0, cam_height_m = 0.45, cam_yaw_rad = 0.0;
  double cam_tilt_rad = 0.0;  // positive looks down
  double depth_min_m = 0.4, depth_max_m = 8.0;
  double depth_noise_per_m2 = 0.0012;  // sigma = k * z^2 (Kinect v1 order of magnitude)
  // People walking through the scene (WalkerTrack): `walkers` tracks are drawn from the seed
  // (each 2.5-10 m of free floor, not within 1.5 m of the tour's start, at walker_speed_m_s
  // +-25 %) unless walker_tracks gives them. 0 (default): an empty floor.
  int walkers = 0;
  std::vector<WalkerTrack> walker_tracks;
  double walker_speed_m_s = 0.8;
  double walker_radius_m = 0.2;  // shoulders seen by the camera, legs by the lidar: one cylinder
  double walker_height_m = 1.75;
  double keep_clear_m = 0.7;  // walker centre to robot centre: 0.2 + the base's 0.3 + 0.2 spare
  double walker_patience_s = 8.0;  // waiting this long, a walker goes another way (above)
  // The base bridge's limits, timing, covariances and channels (nullopt: as
  // config/base_bridge.yaml ships them); its geometry is always the simulated base's. The
  // ideal base applies the same speed limits and command timeout to outside commands.
  std::optional<base_bridge::BaseBridgeOptions> bridge;
};

struct SimStats {
  int64_t scans = 0, odometry = 0, imu = 0, depth_frames = 0;
  double duration_s = 0, distance_m = 0, rotation_rad = 0;
  bool tour_finished = false;
  bool stopped = false;  // the command source or the stop flag ended the run
  // Commands from the command source, and those the base refused (unknown mode, non-finite).
  int64_t commands = 0, commands_rejected = 0;
  // Firmware base only: what crossed the simulated CAN bus, the other bridge messages, and
  // the base's state at the end (firmware state and fault bits as in base_status_t, the
  // bridge's health text, "" when all is well).
  int64_t can_frames = 0, encoders = 0, base_status = 0;
  int firmware_state = 0;
  uint32_t firmware_faults = 0;
  uint32_t watchdog_trips = 0;
  std::string base_problem;
  // People: how many walked, how far, the physics steps summed over walkers that one waited or
  // stepped aside for the robot, and those one overlapped the robot's footprint (it was
  // cornered against a wall; 0 on the built-in tour).
  int walkers = 0;
  double walker_distance_m = 0;
  int64_t walker_yields = 0, walker_contacts = 0;
};

class Simulator {
 public:
  Simulator(World world, SimOptions options);

  // The scripted tour (x, y, heading) of the built-in world; other worlds pass their own.
  static std::vector<Pose2> BuiltInTour();
  void set_tour(std::vector<Pose2> waypoints) { tour_ = std::move(waypoints); }

  // Driving the base from outside instead of the tour's follower (BASE_CMD from the bus, a
  // test): called at every physics step, before it, with the simulated time; appends the
  // commands that arrived since the last call to *commands, oldest first, and returns false to
  // end the run. The base starts at the tour's first pose and does what the commands say, as
  // the robot's would: a twist is held for the bridge's command timeout, then the base ramps to
  // a stop (the firmware base also parks its motors when the bridge goes quiet); an e-stop
  // holds it until a clear-faults command.
  using CommandSource =
      std::function<bool(int64_t utime, std::vector<base_bridge::Command>* commands)>;
  void set_command_source(CommandSource source) { command_source_ = std::move(source); }
  // When set and true at a step, the run ends there (a signal): what was simulated is kept.
  void set_stop_flag(const std::atomic<bool>* stop) { stop_ = stop; }

  // Runs to the end of the tour (or max_duration_s, or until the command source ends it), handing
  // every message to `sink` in time order; `truth` gets the true base pose at every scan (scan
  // index, utime, pose).
  SimStats Run(const std::function<void(const SimEvent&)>& sink,
               const std::function<void(int64_t, int64_t, const Pose2&)>& truth);

  // Sensor models, public for tests: ranges of one scan from `base` (true pose), and one depth
  // image in millimetres (0 = no reading).
  std::vector<float> ScanRanges(const Pose2& base);
  // One beam's range (with noise and dropouts) from `base`.
  float BeamRange(const Pose2& base, int beam);
  std::vector<uint16_t> DepthImage(const Pose2& base);

  // Where each walker stands now (world frame), in the order of the tracks.
  std::vector<Eigen::Vector2d> WalkerPositions() const;
  const std::vector<WalkerTrack>& walker_tracks() const { return tracks_; }
  // Puts walker i at p off its track, as if the base had pushed it there (tests).
  void PlaceWalkerOffTrack(size_t i, const Eigen::Vector2d& p) {
    walkers_.at(i).p = p;
    walkers_.at(i).off_track = true;
  }
  // Walks every walker on by dt with the robot at `robot` (true pose); Run calls it each step.
  void StepWalkers(const Pose2& robot, double dt, SimStats* stats);
  // The nearest hit along o + t * d (t in units of |d|) of the world and the walkers, or a
  // negative value when nothing is hit before t_max (0 when o is inside a walker).
  double Cast(const Vec3& o, const Vec3& d, double t_max) const;

 private:
  struct Walker {
    Eigen::Vector2d p{0, 0};             // where it stands, world frame
    double s = 0;                        // on its track: metres from a
    double dir = 1;                      // +1 towards b, -1 towards a
    bool off_track = false;              // stepped away from the base, on its way back
    int detour = 0;                      // going round something: +1 turning left, -1 right
    std::vector<Eigen::Vector2d> trail;  // where it stood while pushed, to go back that way
    double waited_s = 0;                 // kept waiting since its last step
  };
  Eigen::Vector2d TrackPoint(size_t i, double s) const;
  void MakeWalkers();

  World world_;
  SimOptions o_;
  std::vector<Pose2> tour_;
  CommandSource command_source_;
  const std::atomic<bool>* stop_ = nullptr;
  std::mt19937_64 rng_;
  double measured_gyro_ = 0;  // last gyro z reading, rad/s
  std::vector<WalkerTrack> tracks_;
  std::vector<Walker> walkers_;
};

}  // namespace omni::sim
