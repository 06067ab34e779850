// The built-in simulator: exact ray casts against hand-computed geometry, the sensor models on a
// known pose, the tour of the built-in world on both bases (collision-free, finished, odometry
// drifting from the truth the way slipping wheels or noisy encoders make it), the firmware base
// on its own (odometry through the bridge, slip, the watchdog stop), determinism by seed, and
// world-file errors.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/base_bridge/slip_monitor.h"
#include "omni/base_status_t.hpp"
#include "omni/depth_image_t.hpp"
#include "omni/imu_t.hpp"
#include "omni/kinect/depth_codec.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/sim/firmware_base.h"
#include "omni/sim/simulator.h"
#include "omni/wheel_encoders_t.hpp"

namespace omni::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;

// A 4 x 4 m room of 2 m walls (inner faces at 0 and 4) with a 0.1 m tall box in it.
World Room() {
  return World({{-0.1, -0.1, 0.0, 4.1, 0, 2},
                {4.0, -0.1, 4.1, 4.1, 0, 2},
                {-0.1, -0.1, 4.1, 0.0, 0, 2},
                {-0.1, 4.0, 4.1, 4.1, 0, 2},
                {3.0, 1.5, 3.5, 2.5, 0, 0.1}});
}

TEST(SimWorld, RayCastsHitTheNearestFaceOrTheFloor) {
  const World w = Room();
  // Along +x at 0.3 m height from (1, 2): over the low box (0.1 m) to the east wall at x = 4.
  EXPECT_NEAR(w.Cast({1, 2, 0.3}, {1, 0, 0}, 20), 3.0, 1e-12);
  // At 0.05 m the low box's west face (x = 3) comes first.
  EXPECT_NEAR(w.Cast({1, 2, 0.05}, {1, 0, 0}, 20), 2.0, 1e-12);
  // Diagonally to the north-west corner region: y = 4 at t = 2 along (-0.5, 1) * t... (x = 0)
  EXPECT_NEAR(w.Cast({1, 2, 0.3}, {-0.5, 1, 0}, 20), 2.0, 1e-12);
  // Straight down from 0.45 m: the floor; down at 45 degrees: the floor at 0.45 m ahead.
  EXPECT_NEAR(w.Cast({1, 2, 0.45}, {0, 0, -1}, 20), 0.45, 1e-12);
  EXPECT_NEAR(w.Cast({1, 2, 0.45}, {1, 0, -1}, 20), 0.45, 1e-12);
  // Nothing within t_max.
  EXPECT_LT(w.Cast({1, 2, 0.3}, {1, 0, 0}, 2.5), 0);
  // Up into open sky (no ceiling).
  EXPECT_LT(w.Cast({1, 2, 0.3}, {0, 0, 1}, 20), 0);
  EXPECT_TRUE(w.Free(1, 2, 0.3));
  EXPECT_FALSE(w.Free(0.2, 2, 0.3));       // touches the west wall
  EXPECT_FALSE(w.Free(2.8, 2, 0.3));       // touches the low box
  EXPECT_TRUE(w.Free(2.8, 2, 0.3, 0.15));  // ... unless it clears 0.15 m
}

TEST(SimSensors, ScanRangesMatchTheGeometry) {
  SimOptions o;
  o.range_noise_m = 0;
  o.dropout_probability = 0;
  o.lidar_beams = 360;
  o.lidar_x_m = 0;
  Simulator sim(Room(), o);
  // Base at (1, 2) facing +y: beam i looks at heading pi/2 - pi + i deg in the world.
  const std::vector<float> r = sim.ScanRanges(Pose2(1, 2, kPi / 2));
  ASSERT_EQ(r.size(), 360u);
  EXPECT_NEAR(r[180], 2.0, 1e-5);             // straight ahead (+y): north wall at y = 4
  EXPECT_NEAR(r[0], 2.0, 1e-5);               // behind (-y): south wall at y = 0
  EXPECT_NEAR(r[90], 3.0, 1e-5);              // right of +y is +x: east wall (over the low box)
  EXPECT_NEAR(r[270], 1.0, 1e-5);             // left: west wall at x = 0
  EXPECT_NEAR(r[225], std::sqrt(2.0), 1e-5);  // 45 deg to the north-west corner (0, 3)... wall
  // With noise the ranges scatter by about range_noise_m.
  o.range_noise_m = 0.01;
  Simulator noisy(Room(), o);
  const std::vector<float> n = noisy.ScanRanges(Pose2(1, 2, kPi / 2));
  double sq = 0;
  for (size_t i = 0; i < n.size(); ++i) sq += (n[i] - r[i]) * (n[i] - r[i]);
  const double rms = std::sqrt(sq / static_cast<double>(n.size()));
  EXPECT_GT(rms, 0.005);
  EXPECT_LT(rms, 0.02);
}

TEST(SimSensors, DepthImageSeesTheWallTheFloorAndTheLowBox) {
  SimOptions o;
  o.depth_noise_per_m2 = 0;
  o.cam_x_m = 0;
  o.cam_height_m = 0.45;
  Simulator sim(Room(), o);
  // Facing +x from (1, 2): the east wall is 3 m ahead along the optical axis.
  const std::vector<uint16_t> img = sim.DepthImage(Pose2(1, 2, 0));
  const int w = o.depth_width, h = o.depth_height;
  ASSERT_EQ(img.size(), static_cast<size_t>(w * h));
  // The optical axis passes between the centre pixels; a pixel on the middle row just below it
  // looks down a little: it still sees the wall, at depth 3 m (depth is along the axis).
  EXPECT_NEAR(img[static_cast<size_t>(h / 2 - 1) * w + w / 2], 3000, 1);
  // The bottom row looks down by atan(119.5 / 262.5) = 24.5 deg: the floor at z = 0.45 / tan.
  const double z_floor = 0.45 / (119.5 / 262.5);
  EXPECT_NEAR(img[static_cast<size_t>(h - 1) * w + w / 2], std::lround(z_floor * 1000), 1);
  // The low box (x 3..3.5, y 1.5..2.5, 0.1 m tall) is seen slightly below the horizon: some
  // centre-column pixel between the wall and the floor reads 2.0 m (its west face).
  bool box = false;
  for (int v = h / 2; v < h; ++v) box |= img[static_cast<size_t>(v) * w + w / 2] == 2000;
  EXPECT_TRUE(box);
}

struct Recorded {
  std::vector<SimEvent> events;
  std::vector<Pose2> truth;
  std::vector<int64_t> truth_utime;
  SimStats stats;
};

Recorded RunSim(const SimOptions& o) {
  Recorded rec;
  Simulator sim(World::BuiltIn(), o);
  rec.stats = sim.Run([&](const SimEvent& e) { rec.events.push_back(e); },
                      [&](int64_t, int64_t utime, const Pose2& p) {
                        rec.truth.push_back(p);
                        rec.truth_utime.push_back(utime);
                      });
  return rec;
}

class SimulatorTour : public ::testing::TestWithParam<SimOptions::Base> {};

TEST_P(SimulatorTour, DrivesTheBuiltInTourWithoutTouchingAnything) {
  SimOptions o;
  o.base = GetParam();
  const bool firmware = o.base == SimOptions::Base::kFirmware;
  o.depth = false;  // the sensor test above covers depth; this one covers the tour
  const Recorded rec = RunSim(o);
  EXPECT_TRUE(rec.stats.tour_finished);
  EXPECT_GT(rec.stats.distance_m, 80);
  EXPECT_LT(rec.stats.duration_s, 400);
  const World w = World::BuiltIn();
  for (const Pose2& p : rec.truth) ASSERT_TRUE(w.Free(p.x, p.y, 0.25)) << p.x << " " << p.y;
  // Events in time order, each channel at its rate.
  std::map<std::string, int> count;
  int64_t last = 0;
  for (const auto& e : rec.events) {
    ASSERT_GE(e.utime, last);
    last = e.utime;
    ++count[e.channel];
  }
  const double dur = rec.stats.duration_s;
  EXPECT_NEAR(count["LIDAR_SCAN"], dur * o.lidar_hz, 2);
  EXPECT_NEAR(count["IMU"], dur * o.imu_hz, 2);
  EXPECT_EQ(count.count("DEPTH"), 0u);
  EXPECT_EQ(count["WHEEL_ODOM"], rec.stats.odometry);
  if (firmware) {
    // The bridge publishes odometry and encoders at the firmware's 100 Hz feedback rate and
    // status at 10 Hz, from the base's boot 0.2 s before the first scan (the first feedback
    // frame only sets the encoders' zero).
    EXPECT_NEAR(count["WHEEL_ODOM"], (dur + 0.2) * 100, 3);
    EXPECT_EQ(count["WHEEL_ENCODERS"], count["WHEEL_ODOM"]);
    EXPECT_NEAR(count["BASE_STATUS"], (dur + 0.2) * 10, 2);
    // Odometry is on the bus before the first scan.
    for (const auto& e : rec.events) {
      if (e.channel == "LIDAR_SCAN") FAIL() << "a scan before any odometry";
      if (e.channel == "WHEEL_ODOM") break;
    }
    // A healthy run: the firmware still running the speed loops, no fault, no watchdog stop,
    // the bridge content (heartbeats seen, geometry checked against the firmware's).
    EXPECT_EQ(rec.stats.firmware_state, omni::base_status_t::STATE_RUNNING);
    EXPECT_EQ(rec.stats.firmware_faults, 0u);
    EXPECT_EQ(rec.stats.watchdog_trips, 0u);
    EXPECT_EQ(rec.stats.base_problem, "");
    EXPECT_GT(rec.stats.can_frames, dur * 100 * 5);  // feedback frames alone: ~5 per 10 ms
    int statuses = 0;
    for (const auto& e : rec.events) {
      if (e.channel != "BASE_STATUS") continue;
      omni::base_status_t m;
      ASSERT_GE(m.decode(e.payload.data(), 0, static_cast<int>(e.payload.size())), 0);
      if (++statuses < 3) continue;  // before the first firmware heartbeat
      EXPECT_TRUE(m.firmware_alive) << "status " << statuses;
      EXPECT_EQ(m.fault_bits, 0);
      EXPECT_EQ(m.feedback_frames_lost, 0);
    }
  } else {
    EXPECT_NEAR(count["WHEEL_ODOM"], dur * o.odom_hz, 2);
    EXPECT_EQ(count.count("WHEEL_ENCODERS"), 0u);
  }
  // Every scan decodes and sees walls in most directions. A sweep (the default) takes the
  // revolution and is published when it ends; the message is stamped with its first beam.
  int scans = 0;
  for (const auto& e : rec.events) {
    if (e.channel != "LIDAR_SCAN") continue;
    omni::laser_scan_t m;
    ASSERT_GE(m.decode(e.payload.data(), 0, static_cast<int>(e.payload.size())), 0);
    ASSERT_NEAR(m.scan_time_s, 0.1 * 359 / 360, 1e-6);
    ASSERT_GE(e.utime, m.utime + std::llround(m.scan_time_s * 1e6));
    int valid = 0;
    for (float r : m.ranges_m) valid += std::isfinite(r);
    ASSERT_GT(valid, 200) << "scan " << scans;
    ++scans;
  }
  // The wheels' slip (or the encoders' scale errors) make the odometry drift: metres by the end
  // of the tour, while the truth returns to the start. (The firmware base's odometry starts at
  // zero in its own odom frame, the ideal base's at the start pose.)
  omni::odometry_t last_odom;
  for (const auto& e : rec.events) {
    if (e.channel != "WHEEL_ODOM") continue;
    ASSERT_GE(last_odom.decode(e.payload.data(), 0, static_cast<int>(e.payload.size())), 0);
  }
  const Pose2& end = rec.truth.back();
  EXPECT_LT(std::hypot(end.x - 2.5, end.y - 3.0), 0.3);
  Pose2 odom(last_odom.x_m, last_odom.y_m, last_odom.yaw_rad);
  if (firmware) odom = rec.truth.front() * odom;
  const double drift = std::hypot(odom.x - end.x, odom.y - end.y);
  EXPECT_GT(drift, 0.3);
  EXPECT_LT(drift, 20);
}

INSTANTIATE_TEST_SUITE_P(Bases, SimulatorTour,
                         ::testing::Values(SimOptions::Base::kFirmware, SimOptions::Base::kIdeal),
                         [](const ::testing::TestParamInfo<SimOptions::Base>& i) {
                           return i.param == SimOptions::Base::kFirmware ? "Firmware" : "Ideal";
                         });

// The firmware base alone: a straight run without slip is measured by the bridge's odometry to
// within encoder quantisation; slip on one wheel turns the base while the odometry does not see
// it; and when commands stop, the bridge ramps down and the firmware's watchdog parks the base.
TEST(FirmwareBase, OdometryThroughTheBridgeSlipAndTheWatchdogStop) {
  const double dt = 0.005;
  int64_t now = 1700000000000000;
  auto drive = [&](FirmwareBase* b, const kinematics::BodyTwist<double>* cmd, double seconds,
                   omni::odometry_t* last) {
    for (int i = 0; i < std::lround(seconds / dt); ++i) {
      b->Advance(cmd, now, dt, [&](const SimEvent& e) {
        if (e.channel == "WHEEL_ODOM") {
          ASSERT_GE(last->decode(e.payload.data(), 0, static_cast<int>(e.payload.size())), 0);
        }
      });
      now += 5000;
    }
  };
  const kinematics::BodyTwist<double> ahead{0.3, 0.1, 0.2};
  {
    FirmwareBase base(0.2, 0.05);
    ASSERT_TRUE(base.booted(nullptr));
    for (int w = 0; w < 3; ++w) base.SetSlip(w, 0.0);
    omni::odometry_t odom;
    drive(&base, &ahead, 5.0, &odom);
    const Pose2 truth = base.pose();
    EXPECT_GT(std::hypot(truth.x, truth.y), 1.0);  // it drove
    EXPECT_NEAR(truth.theta, WrapAngle(0.2 * 5.0), 0.05);
    // The odometry starts at the first feedback frame (after 10 ms of motion from rest).
    EXPECT_LT(std::hypot(odom.x_m - truth.x, odom.y_m - truth.y), 0.005);
    EXPECT_NEAR(odom.yaw_rad, truth.theta, 0.005);
    EXPECT_EQ(base.bridge().counters().geometry_mismatches, 0);
    EXPECT_EQ(base.Problem(now), "");
    // Commands stop: the bridge ramps the twist to zero and stops sending, the watchdog stops
    // the wheels and the firmware goes back to IDLE with the motors off.
    drive(&base, nullptr, 1.5, &odom);
    EXPECT_EQ(base.firmware().state(), firmware::State::kIdle);
    EXPECT_EQ(base.firmware().counters().watchdog_trips, 1u);
    const Pose2 parked = base.pose();
    drive(&base, nullptr, 0.5, &odom);
    EXPECT_LT(std::hypot(base.pose().x - parked.x, base.pose().y - parked.y), 1e-4);
  }
  {
    // Wheel 1 loses 5 % of its rim motion: the truth and the odometry part.
    FirmwareBase base(0.2, 0.05);
    for (int w = 0; w < 3; ++w) base.SetSlip(w, w == 0 ? 0.05 : 0.0);
    omni::odometry_t odom;
    const kinematics::BodyTwist<double> straight{0.4, 0.0, 0.0};
    drive(&base, &straight, 5.0, &odom);
    EXPECT_LT(std::abs(odom.yaw_rad), 0.005);  // the encoders saw a straight run
    EXPECT_GT(std::abs(base.pose().theta), 0.01);
    EXPECT_GT(std::hypot(odom.x_m - base.pose().x, odom.y_m - base.pose().y), 0.02);
  }
}

// The bridge's slip check (base_bridge/slip_monitor.h) on the simulated base: its WHEEL_ODOM and
// IMU, 60 s of the tour. With the wheels' shipped slip (2.6 / 1.0 / 2.0 % +- 1 %, which the
// odometry calibration of the mappers absorbs) no window is flagged; with wheel 1 losing 30 %
// of its rim motion the encoders' heading runs away from the gyro's and it is.
TEST(FirmwareBase, SlipCheckFlagsASlippingWheelAndNotTheUsualSlip) {
  auto run = [](double slip0) {
    SimOptions o;
    o.depth = false;
    o.max_duration_s = 60;
    if (slip0 > 0) o.wheel_slip[0] = slip0;
    const Recorded rec = RunSim(o);
    base_bridge::SlipMonitor m{base_bridge::SlipOptions{}};
    for (const SimEvent& e : rec.events) {
      const int n = static_cast<int>(e.payload.size());
      if (e.channel == "WHEEL_ODOM") {
        omni::odometry_t od;
        EXPECT_GE(od.decode(e.payload.data(), 0, n), 0);
        m.AddOdometry(od.utime, Pose2(od.x_m, od.y_m, od.yaw_rad));
      } else if (e.channel == "IMU") {
        omni::imu_t im;
        EXPECT_GE(im.decode(e.payload.data(), 0, n), 0);
        EXPECT_TRUE(m.AddGyro(im.utime, im.angular_velocity_rad_s[2]));
      }
    }
    return m.counters();
  };
  const base_bridge::SlipCounters usual = run(0), slipping = run(0.3);
  std::printf(
      "slip windows: %lld of %lld with the usual slip, %lld of %lld (%lld events) with "
      "wheel 1 at 30 %%\n",
      static_cast<long long>(usual.slip_windows), static_cast<long long>(usual.windows),
      static_cast<long long>(slipping.slip_windows), static_cast<long long>(slipping.windows),
      static_cast<long long>(slipping.slip_events));
  EXPECT_GT(usual.windows, 200);
  EXPECT_EQ(usual.slip_windows, 0);
  EXPECT_GT(slipping.slip_events, 0);
  EXPECT_GT(slipping.slip_windows, slipping.windows / 10);
}

// Driven from outside (BASE_CMD from the bus in omni-sim --drive bus): a schedule of commands
// by simulated time, handed to the simulator as they fall due; the run ends at `end_s`.
struct Scheduled {
  double at_s;
  base_bridge::Command cmd;
};

Recorded RunDriven(SimOptions o, const std::vector<Scheduled>& schedule, double end_s) {
  o.depth = false;
  o.wheel_slip_noise = 0;
  Simulator sim(World::BuiltIn(), o);
  size_t next = 0;
  sim.set_command_source([&](int64_t utime, std::vector<base_bridge::Command>* cmds) {
    const double t = static_cast<double>(utime - o.start_utime) * 1e-6;
    for (; next < schedule.size() && schedule[next].at_s <= t; ++next)
      cmds->push_back(schedule[next].cmd);
    return t < end_s;
  });
  Recorded rec;
  rec.stats = sim.Run([&](const SimEvent& e) { rec.events.push_back(e); },
                      [&](int64_t, int64_t utime, const Pose2& p) {
                        rec.truth.push_back(p);
                        rec.truth_utime.push_back(utime);
                      });
  return rec;
}

// A twist every 50 ms (20 Hz, as `omni drive` sends them) over [from_s, to_s).
void Twists(std::vector<Scheduled>* s, double from_s, double to_s, double vx, double vy,
            double omega) {
  for (double t = from_s; t < to_s - 1e-9; t += 0.05) {
    base_bridge::Command c;
    c.vx_m_s = vx;
    c.vy_m_s = vy;
    c.omega_rad_s = omega;
    s->push_back({t, c});
  }
}

base_bridge::Command Mode(base_bridge::Command::Mode m) {
  base_bridge::Command c;
  c.mode = m;
  return c;
}

// The pose at the scan closest to simulated time t (scans every 0.1 s from t = 0).
Pose2 At(const Recorded& r, double t) {
  const size_t i = std::min(r.truth.size() - 1, static_cast<size_t>(std::lround(t * 10)));
  return r.truth[i];
}

class SimulatorDriven : public ::testing::TestWithParam<SimOptions::Base> {};

// Commands move the base as a robot's would, and it stops by itself when they stop: 0.3 m/s
// ahead for 2 s, then silence; the base starts at the tour's first pose facing +x.
TEST_P(SimulatorDriven, MovesWhereTheCommandsSayAndStopsWhenTheyStop) {
  SimOptions o;
  o.base = GetParam();
  std::vector<Scheduled> s;
  Twists(&s, 1.0, 3.0, 0.3, 0.0, 0.0);
  const Recorded r = RunDriven(o, s, 6.0);
  EXPECT_TRUE(r.stats.stopped);
  EXPECT_FALSE(r.stats.tour_finished);
  EXPECT_EQ(r.stats.commands, 40);
  EXPECT_EQ(r.stats.commands_rejected, 0);
  ASSERT_EQ(r.truth.size(), 60u);
  const Pose2 start = At(r, 0), before = At(r, 0.9), end = At(r, 5.9);
  EXPECT_LT(std::hypot(before.x - start.x, before.y - start.y), 1e-6);  // nothing commanded
  // 2 s at 0.3 m/s, plus what the bridge's timeout (0.3 s) and ramps add and the slip takes.
  EXPECT_NEAR(end.x - start.x, 0.6, 0.12);
  EXPECT_NEAR(end.y - start.y, 0.0, 0.03);
  EXPECT_NEAR(end.theta, start.theta, 0.03);
  // Stopped within a second of the last command (its timeout, the ramp, the watchdog).
  const Pose2 stopped = At(r, 4.0);
  EXPECT_LT(std::hypot(end.x - stopped.x, end.y - stopped.y), 1e-3);
  if (o.base == SimOptions::Base::kFirmware) {
    EXPECT_EQ(r.stats.firmware_state, static_cast<int>(firmware::State::kIdle));
    EXPECT_EQ(r.stats.firmware_faults & firmware::kLatchedFaults, 0u);
    EXPECT_EQ(r.stats.watchdog_trips, 1u);
    EXPECT_EQ(r.stats.base_problem, "");
  }
}

// An e-stop holds the base whatever twists follow, until faults are cleared; commands the base
// cannot take (an unknown mode, a NaN speed) are refused and counted, and change nothing.
TEST_P(SimulatorDriven, EstopHoldsUntilClearedAndBadCommandsAreRefused) {
  SimOptions o;
  o.base = GetParam();
  std::vector<Scheduled> s;
  base_bridge::Command nan_twist;
  nan_twist.vx_m_s = std::nan("");
  s.push_back({0.5, nan_twist});
  s.push_back({0.5, Mode(static_cast<base_bridge::Command::Mode>(7))});
  s.push_back({0.6, Mode(base_bridge::Command::kEstop)});
  Twists(&s, 1.0, 2.0, 0.0, 0.3, 0.0);  // ignored: e-stopped
  s.push_back({2.5, Mode(base_bridge::Command::kClearFaults)});
  Twists(&s, 3.0, 4.0, 0.0, 0.3, 0.0);  // sideways, as only an omni base can
  std::sort(s.begin(), s.end(),
            [](const Scheduled& a, const Scheduled& b) { return a.at_s < b.at_s; });
  const Recorded r = RunDriven(o, s, 6.0);
  EXPECT_EQ(r.stats.commands_rejected, 2);
  const Pose2 start = At(r, 0), cleared = At(r, 2.9), end = At(r, 5.9);
  EXPECT_LT(std::hypot(cleared.x - start.x, cleared.y - start.y), 1e-3);
  EXPECT_NEAR(end.y - start.y, 0.3, 0.08);
  EXPECT_NEAR(end.x - start.x, 0.0, 0.03);
  if (o.base == SimOptions::Base::kFirmware) {
    EXPECT_EQ(r.stats.firmware_faults & firmware::kLatchedFaults, 0u);
    EXPECT_EQ(r.stats.base_problem, "");
  }
}

INSTANTIATE_TEST_SUITE_P(Bases, SimulatorDriven,
                         ::testing::Values(SimOptions::Base::kFirmware, SimOptions::Base::kIdeal),
                         [](const ::testing::TestParamInfo<SimOptions::Base>& i) {
                           return i.param == SimOptions::Base::kFirmware ? "Firmware" : "Ideal";
                         });

// The simulated bridge runs with the limits, timing, covariances and channels the shipped
// config/base_bridge.yaml gives the robot's bridge (the geometry is the simulated base's).
TEST(FirmwareBase, ShippedBridgeOptionsAreThoseOfTheShippedConfig) {
  auto shipped = base_bridge::LoadBaseBridgeOptions(OMNI_SOURCE_DIR "/config/base_bridge.yaml");
  ASSERT_TRUE(shipped.ok()) << shipped.error().message;
  const base_bridge::BaseBridgeOptions a = FirmwareBase::ShippedBridgeOptions(), &b = *shipped;
  EXPECT_EQ(a.node_id, b.node_id);
  EXPECT_EQ(a.feedback_period_s, b.feedback_period_s);
  EXPECT_EQ(a.max_vx_m_s, b.max_vx_m_s);
  EXPECT_EQ(a.max_vy_m_s, b.max_vy_m_s);
  EXPECT_EQ(a.max_omega_rad_s, b.max_omega_rad_s);
  EXPECT_EQ(a.max_linear_accel_m_s2, b.max_linear_accel_m_s2);
  EXPECT_EQ(a.max_angular_accel_rad_s2, b.max_angular_accel_rad_s2);
  EXPECT_EQ(a.send_rate_hz, b.send_rate_hz);
  EXPECT_EQ(a.command_timeout_s, b.command_timeout_s);
  EXPECT_EQ(a.firmware_heartbeat_period_s, b.firmware_heartbeat_period_s);
  EXPECT_EQ(a.missed_heartbeats_for_silent, b.missed_heartbeats_for_silent);
  EXPECT_EQ(a.reconnect_period_s, b.reconnect_period_s);
  EXPECT_EQ(a.status_rate_hz, b.status_rate_hz);
  EXPECT_EQ(a.odom_var_xy_per_m, b.odom_var_xy_per_m);
  EXPECT_EQ(a.odom_var_yaw_per_rad, b.odom_var_yaw_per_rad);
  EXPECT_EQ(a.twist_var_linear, b.twist_var_linear);
  EXPECT_EQ(a.twist_var_angular, b.twist_var_angular);
  EXPECT_EQ(a.odom_frame, b.odom_frame);
  EXPECT_EQ(a.base_frame, b.base_frame);
  EXPECT_EQ(a.cmd_channel, b.cmd_channel);
  EXPECT_EQ(a.odom_channel, b.odom_channel);
  EXPECT_EQ(a.encoders_channel, b.encoders_channel);
  EXPECT_EQ(a.status_channel, b.status_channel);
}

TEST(Simulator, SameSeedSameBytesOtherSeedOtherNoise) {
  SimOptions o;
  o.max_duration_s = 3;
  o.depth_hz = 2;
  const Recorded a = RunSim(o), b = RunSim(o);
  ASSERT_EQ(a.events.size(), b.events.size());
  for (size_t i = 0; i < a.events.size(); ++i) ASSERT_EQ(a.events[i].payload, b.events[i].payload);
  o.seed = 2;
  const Recorded c = RunSim(o);
  ASSERT_EQ(a.events.size(), c.events.size());
  size_t differ = 0;
  for (size_t i = 0; i < a.events.size(); ++i) differ += a.events[i].payload != c.events[i].payload;
  EXPECT_GT(differ, a.events.size() / 2);
  // Depth frames decode losslessly to 320 x 240 millimetre images.
  int frames = 0;
  for (const auto& e : a.events) {
    if (e.channel != "DEPTH") continue;
    omni::depth_image_t m;
    ASSERT_GE(m.decode(e.payload.data(), 0, static_cast<int>(e.payload.size())), 0);
    std::vector<uint16_t> px;
    ASSERT_TRUE(
        kinect::DecodeDepth(m.encoding, m.data.data(), m.data.size(), m.width, m.height, &px).ok());
    EXPECT_EQ(px.size(), 320u * 240u);
    ++frames;
  }
  EXPECT_EQ(frames, 7);  // t = 0, 0.5, ..., 3.0
}

// People in the scene: a walker on a known track is where the sensors say, inside it nothing is
// measured, it walks its track, waits for and steps away from the base, and never leaves the
// free floor.
TEST(SimWalkers, TheLidarAndTheCameraSeeAWalkerWhereItStands) {
  SimOptions o;
  o.range_noise_m = 0;
  o.dropout_probability = 0;
  o.depth_noise_per_m2 = 0;
  o.lidar_x_m = 0;
  o.cam_x_m = 0;
  // A track along y at x = 3, the walker halfway (y = 2): 0.2 m wide either side.
  o.walker_tracks = {{3.0, 1.0, 3.0, 3.0, 0.8, 0.5}};
  Simulator sim(Room(), o);
  ASSERT_EQ(sim.WalkerPositions().size(), 1u);
  EXPECT_NEAR(sim.WalkerPositions()[0].x(), 3.0, 1e-12);
  EXPECT_NEAR(sim.WalkerPositions()[0].y(), 2.0, 1e-12);
  // From (1, 2) facing +x: straight ahead the walker's near side at x = 2.8, where the room's
  // east wall (x = 4) was; a beam passing 0.3 m beside it still reaches the wall.
  const std::vector<float> r = sim.ScanRanges(Pose2(1, 2, 0));
  EXPECT_NEAR(r[180], 1.8, 1e-5);
  const double a = std::atan2(0.3, 2.0);  // to (3, 2.3): outside the 0.2 m radius
  const int beam = 180 + static_cast<int>(std::lround(a * 180 / kPi));
  const double beam_a = (beam - 180) * kPi / 180;
  EXPECT_NEAR(r[static_cast<size_t>(beam)], 3.0 / std::cos(beam_a), 1e-4);
  // The camera sees it too, above the lidar's plane: the centre column at 1.8 m from the
  // horizon up to the top of the image (1.75 m tall, the camera at 0.45 m sees up to
  // 0.45 + 1.8 * tan(24.5 deg) = 1.27 m there).
  const std::vector<uint16_t> img = sim.DepthImage(Pose2(1, 2, 0));
  const int w = o.depth_width, h = o.depth_height;
  EXPECT_EQ(img[static_cast<size_t>(0) * w + w / 2], 1800);
  EXPECT_EQ(img[static_cast<size_t>(h / 2 - 1) * w + w / 2], 1800);
  // Without the walker the same pixels see the wall.
  SimOptions empty = o;
  empty.walker_tracks.clear();
  Simulator none(Room(), empty);
  EXPECT_NEAR(none.ScanRanges(Pose2(1, 2, 0))[180], 3.0, 1e-5);
  EXPECT_EQ(none.DepthImage(Pose2(1, 2, 0))[static_cast<size_t>(h / 2 - 1) * w + w / 2], 3000);
  // From inside the walker nothing is measured (the cast ends at 0, below the minimum range).
  EXPECT_EQ(sim.Cast({3.05, 2.0, 0.3}, {1, 0, 0}, 20), 0.0);
  EXPECT_TRUE(std::isnan(sim.BeamRange(Pose2(2.95, 2.0, 0), 180)));
  // Over its head (a ray from 2 m down onto it) the top is hit.
  EXPECT_NEAR(sim.Cast({3.0, 2.0, 2.0}, {0, 0, -1}, 20), 0.25, 1e-12);
}

TEST(SimWalkers, WalkTheirTrackWaitForTheBaseAndStepAwayFromIt) {
  SimOptions o;
  o.walker_tracks = {{1.0, 1.0, 3.0, 1.0, 1.0, 0.0}};  // along x at y = 1, from x = 1
  Simulator sim(Room(), o);
  SimStats st;
  const Pose2 far_away(3.5, 3.5, 0);
  // Alone it walks to the end in 2 s, turns and comes back.
  for (int i = 0; i < 100; ++i) sim.StepWalkers(far_away, 0.01, &st);
  EXPECT_NEAR(sim.WalkerPositions()[0].x(), 2.0, 1e-9);
  for (int i = 0; i < 150; ++i) sim.StepWalkers(far_away, 0.01, &st);
  EXPECT_NEAR(sim.WalkerPositions()[0].x(), 2.5, 1e-9);  // 1 m on, then 0.5 m back
  EXPECT_NEAR(st.walker_distance_m, 2.5, 1e-9);
  EXPECT_EQ(st.walker_yields, 0);
  // The base stands on its track at x = 1.5: it walks up to keep_clear_m (0.7 m) and waits.
  const Pose2 in_the_way(1.5, 1.0, 0);
  for (int i = 0; i < 300; ++i) sim.StepWalkers(in_the_way, 0.01, &st);
  EXPECT_NEAR(sim.WalkerPositions()[0].x(), 1.5 + o.keep_clear_m, 0.011);
  EXPECT_GT(st.walker_yields, 100);
  // The base drives at it, 0.1 m beside its track: it steps back and aside, never touched.
  Pose2 base(1.5, 0.9, 0);
  std::vector<Eigen::Vector2d> pushed_through;
  for (int i = 0; i < 100; ++i) {
    base = Pose2(base.x + 0.004, 0.9, 0);  // 0.4 m/s
    sim.StepWalkers(base, 0.01, &st);
    const Eigen::Vector2d p = sim.WalkerPositions()[0];
    pushed_through.push_back(p);
    EXPECT_GE(std::hypot(p.x() - base.x, p.y() - base.y), 0.5) << i;
    EXPECT_TRUE(Room().Free(p.x(), p.y(), o.walker_radius_m));
  }
  EXPECT_EQ(st.walker_contacts, 0);
  EXPECT_GT(pushed_through.back().y(), 1.05);  // off its track
  // Once the base has gone, it goes back the way it was pushed (every step onto a spot it
  // stood on then) until it is on its track again, and walks on from there.
  int back_at = -1;
  for (int i = 0; i < 200 && back_at < 0; ++i) {
    sim.StepWalkers(far_away, 0.01, &st);
    const Eigen::Vector2d p = sim.WalkerPositions()[0];
    if (std::abs(p.y() - 1.0) < 1e-9) {
      back_at = i;
      break;
    }
    double nearest = 1e9;
    for (const auto& q : pushed_through) nearest = std::min(nearest, (p - q).norm());
    ASSERT_LT(nearest, 1e-9) << "step " << i << " at " << p.transpose();
  }
  EXPECT_GE(back_at, 5);
  for (int i = 0; i < 500; ++i) sim.StepWalkers(far_away, 0.01, &st);
  const Eigen::Vector2d back = sim.WalkerPositions()[0];
  EXPECT_NEAR(back.y(), 1.0, 1e-9);
  EXPECT_GE(back.x(), 1.0);
  EXPECT_LE(back.x(), 3.0);
}

// A base parked in a walker's way does not hold it for good: on its track it turns back after
// walker_patience_s; pushed off its track and then blocked on the way it came, it gives that
// way up and goes round the base to its track.
TEST(SimWalkers, AWalkerKeptWaitingByAParkedBaseGoesAnotherWay) {
  SimOptions o;
  o.walker_tracks = {{1.0, 1.0, 3.0, 1.0, 1.0, 0.5}};  // along x at y = 1, from x = 2 towards 3
  Simulator sim(Room(), o);
  SimStats st;
  const Pose2 parked(3.2, 1.0, 0);  // beyond the track's end, 0.7 m from x = 2.5
  const int steps_patience = static_cast<int>(std::lround(o.walker_patience_s / 0.01));
  auto run = [&](const Pose2& base, int steps, double* min_x, double* max_x, int* longest_still) {
    Eigen::Vector2d last = sim.WalkerPositions()[0];
    int still = 0;
    for (int i = 0; i < steps; ++i) {
      sim.StepWalkers(base, 0.01, &st);
      const Eigen::Vector2d p = sim.WalkerPositions()[0];
      still = (p - last).norm() < 1e-12 ? still + 1 : 0;
      *longest_still = std::max(*longest_still, still);
      *min_x = std::min(*min_x, p.x());
      *max_x = std::max(*max_x, p.x());
      last = p;
    }
  };
  double min_x = 1e9, max_x = -1e9;
  int longest_still = 0;
  run(parked, 3000, &min_x, &max_x, &longest_still);  // 30 s
  EXPECT_NEAR(max_x, 3.2 - o.keep_clear_m, 0.011);    // walked up to the parked base
  EXPECT_LT(min_x, 1.05);                             // and, kept waiting, back to the other end
  EXPECT_GE(longest_still, steps_patience - 1);       // it did wait
  EXPECT_LE(longest_still, steps_patience + 1);       // but no longer than its patience
  // Pushed off its track, then the base parks where it blocks the way back.
  Pose2 base(1.0, 0.9, 0);
  const Eigen::Vector2d start = sim.WalkerPositions()[0];
  ASSERT_LT(std::abs(start.y() - 1.0), 1e-9);
  base = Pose2(start.x() - 0.6, 0.9, 0);
  for (int i = 0; i < 60; ++i) {
    base = Pose2(base.x + 0.004, 0.9, 0);
    sim.StepWalkers(base, 0.01, &st);
  }
  ASSERT_GT(sim.WalkerPositions()[0].y(), 1.05);  // off its track
  min_x = 1e9;
  max_x = -1e9;
  longest_still = 0;
  bool back_on_track = false;
  for (int i = 0; i < 3000 && !back_on_track; ++i) {
    run(base, 1, &min_x, &max_x, &longest_still);
    back_on_track = std::abs(sim.WalkerPositions()[0].y() - 1.0) < 1e-9;
  }
  EXPECT_TRUE(back_on_track) << "at " << sim.WalkerPositions()[0].transpose();
  EXPECT_LE(longest_still, steps_patience + 1);
  EXPECT_EQ(st.walker_contacts, 0);
}

// Pushed off its track to the far side of the low box, a walker goes round the box to get back
// (the straight line back runs into it; such a walker used to wait there for the rest of the
// run).
TEST(SimWalkers, FindTheirWayBackRoundWhatIsInTheWay) {
  SimOptions o;
  o.walker_tracks = {{0.5, 2.0, 2.7, 2.0, 1.0, 1.0}};  // along x at y = 2, ending west of the box
  Simulator sim(Room(), o);
  ASSERT_TRUE(Room().Free(3.75, 2.0, o.walker_radius_m));
  sim.PlaceWalkerOffTrack(0, {3.75, 2.0});  // east of the box (x 3.0-3.5, y 1.5-2.5)
  SimStats st;
  const Pose2 gone(0.5, 3.5, 0);
  int back_after = -1;
  for (int i = 0; i < 1000 && back_after < 0; ++i) {
    sim.StepWalkers(gone, 0.01, &st);
    const Eigen::Vector2d p = sim.WalkerPositions()[0];
    EXPECT_TRUE(Room().Free(p.x(), p.y(), o.walker_radius_m)) << i;
    if (std::abs(p.y() - 2.0) < 1e-9 && p.x() <= 2.7 + 1e-9) back_after = i;
  }
  // Round the box: 0.7 m along its face (slower: the steps turned off the way back there), then
  // about 1.5 m back to the track's end; it takes 3.2 s at 1 m/s.
  EXPECT_GE(back_after, 0);
  EXPECT_LT(back_after, 500);
  EXPECT_EQ(st.walker_contacts, 0);
  // Pushed while still off its track (a base coming from the south as it goes round the box),
  // it still reaches its track, and never by a jump (each step at most its 1 cm).
  sim.PlaceWalkerOffTrack(0, {3.75, 2.0});
  Eigen::Vector2d last = sim.WalkerPositions()[0];
  bool on_track = false;
  for (int i = 0; i < 1200 && !on_track; ++i) {
    const Pose2 base = i < 100 ? Pose2(3.75, 1.0 + 0.004 * i, 0) : gone;
    sim.StepWalkers(base, 0.01, &st);
    const Eigen::Vector2d p = sim.WalkerPositions()[0];
    ASSERT_LE((p - last).norm(), 0.01 + 1e-9) << i;
    last = p;
    on_track = i > 100 && std::abs(p.y() - 2.0) < 1e-9 && p.x() <= 2.7 + 1e-9;
  }
  EXPECT_TRUE(on_track) << last.transpose();
}

TEST(SimWalkers, DrawnFromTheSeedOnFreeFloorAndTheTourStillDrivenUntouched) {
  SimOptions o;
  o.walkers = 8;
  o.depth = false;
  const World world = World::BuiltIn();
  Simulator a(world, o), b(world, o);
  ASSERT_EQ(a.walker_tracks().size(), 8u);
  const Pose2 start = Simulator::BuiltInTour().front();
  for (size_t i = 0; i < 8; ++i) {
    const WalkerTrack& t = a.walker_tracks()[i];
    EXPECT_EQ(t.ax, b.walker_tracks()[i].ax);  // the same seed, the same tracks
    const double len = std::hypot(t.bx - t.ax, t.by - t.ay);
    EXPECT_GE(len, 2.5);
    EXPECT_LE(len, 10.0);
    for (double f = 0; f <= 1.0; f += 0.01)
      EXPECT_TRUE(world.Free(t.ax + f * (t.bx - t.ax), t.ay + f * (t.by - t.ay), 0.2)) << i;
    const Eigen::Vector2d p = a.WalkerPositions()[i];
    EXPECT_GE(std::hypot(p.x() - start.x, p.y() - start.y), 1.5);
  }
  o.seed = 2;
  EXPECT_NE(Simulator(world, o).walker_tracks()[0].ax, a.walker_tracks()[0].ax);
  // The whole tour with them: finished, nobody touched, the base's path and the sensors' noise
  // exactly those of the run without them (they draw from their own stream; no depth camera
  // here, whose draws depend on what its pixels hit), and the scans differ only where a walker
  // stood in a beam: shorter there, never longer.
  // Nobody stands still for long either: pushed against a pillar, a walker finds its way round
  // it back to its track (one waited there for the rest of the tour before).
  o.seed = 1;
  Recorded with;
  Simulator sim(world, o);
  std::vector<Eigen::Vector2d> before = sim.WalkerPositions();
  std::vector<int> still_s(before.size(), 0);
  int longest_still_s = 0, scans = 0;
  with.stats = sim.Run(
      [&](const SimEvent& e) {
        with.events.push_back(e);
        if (e.channel != "LIDAR_SCAN" || ++scans % 10 != 0) return;  // once a second
        const std::vector<Eigen::Vector2d> now = sim.WalkerPositions();
        for (size_t i = 0; i < now.size(); ++i) {
          still_s[i] = (now[i] - before[i]).norm() < 0.05 ? still_s[i] + 1 : 0;
          longest_still_s = std::max(longest_still_s, still_s[i]);
        }
        before = now;
      },
      [&](int64_t, int64_t, const Pose2& p) { with.truth.push_back(p); });
  EXPECT_LE(longest_still_s, 5);
  EXPECT_TRUE(with.stats.tour_finished);
  EXPECT_EQ(with.stats.walkers, 8);
  EXPECT_GT(with.stats.walker_distance_m, 8 * 0.6 * with.stats.duration_s);
  EXPECT_EQ(with.stats.walker_contacts, 0);
  SimOptions bare = o;
  bare.walkers = 0;
  const Recorded without = RunSim(bare);
  ASSERT_EQ(with.truth.size(), without.truth.size());
  for (size_t i = 0; i < with.truth.size(); ++i) {
    ASSERT_EQ(with.truth[i].x, without.truth[i].x) << i;
    ASSERT_EQ(with.truth[i].theta, without.truth[i].theta) << i;
  }
  std::vector<const SimEvent*> scans_with, scans_without;
  for (const auto& e : with.events)
    if (e.channel == "LIDAR_SCAN") scans_with.push_back(&e);
  for (const auto& e : without.events)
    if (e.channel == "LIDAR_SCAN") scans_without.push_back(&e);
  ASSERT_EQ(scans_with.size(), scans_without.size());
  int64_t shorter = 0, other = 0;
  for (size_t k = 0; k < scans_with.size(); ++k) {
    omni::laser_scan_t a_scan, b_scan;
    ASSERT_GE(a_scan.decode(scans_with[k]->payload.data(), 0,
                            static_cast<int>(scans_with[k]->payload.size())),
              0);
    ASSERT_GE(b_scan.decode(scans_without[k]->payload.data(), 0,
                            static_cast<int>(scans_without[k]->payload.size())),
              0);
    for (size_t i = 0; i < a_scan.ranges_m.size(); ++i) {
      const float x = a_scan.ranges_m[i], y = b_scan.ranges_m[i];
      if (std::isnan(x) && std::isnan(y)) continue;
      if (x == y) continue;
      if (!std::isnan(x) && (std::isnan(y) || x < y)) {
        ++shorter;
      } else {
        ++other;  // a walker closer than the lidar's minimum range: no reading
      }
    }
  }
  EXPECT_GT(shorter, 5000);  // 8 people in a 20 x 14 m floor are seen often
  EXPECT_LT(other, shorter / 100);
}

TEST(SimWorld, WorldFilesAreCheckedEntryByEntry) {
  const std::string dir = ::testing::TempDir();
  auto load = [&](const std::string& text) {
    const std::string path = dir + "/world.yaml";
    std::ofstream(path) << text;
    return World::Load(path);
  };
  auto ok = load("boxes:\n  - [0, 0, 1, 1, 0, 2]\n  - [2, 2, 3, 3, 0, 0.1]\n");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->boxes().size(), 2u);
  auto bad_key = load("boxs:\n  - [0, 0, 1, 1, 0, 2]\n");
  ASSERT_FALSE(bad_key.ok());
  EXPECT_NE(bad_key.error().message.find("boxs"), std::string::npos);
  auto bad_entry = load("boxes:\n  - [0, 0, 1, 1, 0, 2]\n  - [1, 0, 0, 1, 0, 2]\n");
  ASSERT_FALSE(bad_entry.ok());
  EXPECT_NE(bad_entry.error().message.find("boxes[1]"), std::string::npos);
  auto short_entry = load("boxes:\n  - [0, 0, 1]\n");
  ASSERT_FALSE(short_entry.ok());
  auto nan_entry = load("boxes:\n  - [0, 0, 1, 1, 0, .nan]\n");
  ASSERT_FALSE(nan_entry.ok());
  EXPECT_FALSE(World::Load(dir + "/no-such-world.yaml").ok());
  // A key that is not a name used to throw out of Load (the process terminated).
  auto odd_key = load("? [1]\n: 2\nboxes:\n  - [0, 0, 1, 1, 0, 2]\n");
  ASSERT_FALSE(odd_key.ok());
  EXPECT_NE(odd_key.error().message.find("not a name"), std::string::npos);
  // A box 4 km out: its ground-truth map would have been 80,000^2 cells.
  auto far = load("boxes:\n  - [0, 0, 1, 1, 0, 2]\n  - [4000, 0, 4001, 1, 0, 2]\n");
  ASSERT_FALSE(far.ok());
  EXPECT_NE(far.error().message.find("at most 800 m"), std::string::npos) << far.error().message;
}

}  // namespace
}  // namespace omni::sim
