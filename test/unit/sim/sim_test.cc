// The built-in simulator: exact ray casts against hand-computed geometry, the sensor models on a
// known pose, the tour of the built-in world (collision-free, finished, odometry drifting from
// the truth the way noisy encoders make it), determinism by seed, and world-file errors.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/depth_image_t.hpp"
#include "omni/kinect/depth_codec.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/sim/simulator.h"

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

TEST(Simulator, DrivesTheBuiltInTourWithoutTouchingAnything) {
  SimOptions o;
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
  EXPECT_NEAR(count["WHEEL_ODOM"], dur * o.odom_hz, 2);
  EXPECT_NEAR(count["IMU"], dur * o.imu_hz, 2);
  EXPECT_EQ(count.count("DEPTH"), 0u);
  // Every scan decodes and sees walls in most directions.
  int scans = 0;
  for (const auto& e : rec.events) {
    if (e.channel != "LIDAR_SCAN") continue;
    omni::laser_scan_t m;
    ASSERT_GE(m.decode(e.payload.data(), 0, static_cast<int>(e.payload.size())), 0);
    int valid = 0;
    for (float r : m.ranges_m) valid += std::isfinite(r);
    ASSERT_GT(valid, 200) << "scan " << scans;
    ++scans;
  }
  // The encoders' scale errors make the odometry drift: metres by the end of the tour, while
  // the truth returns to the start.
  omni::odometry_t last_odom;
  for (const auto& e : rec.events) {
    if (e.channel != "WHEEL_ODOM") continue;
    ASSERT_GE(last_odom.decode(e.payload.data(), 0, static_cast<int>(e.payload.size())), 0);
  }
  const Pose2& end = rec.truth.back();
  EXPECT_LT(std::hypot(end.x - 2.5, end.y - 3.0), 0.3);
  const double drift = std::hypot(last_odom.x_m - end.x, last_odom.y_m - end.y);
  EXPECT_GT(drift, 0.3);
  EXPECT_LT(drift, 20);
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
}

}  // namespace
}  // namespace omni::sim
