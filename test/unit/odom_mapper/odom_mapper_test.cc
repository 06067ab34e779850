#include "omni/odom_mapper/odom_mapper.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

namespace omni::odom_mapper {
namespace {

// A base driving along +x at 1 m/s towards a wall at x = 5.02 m, odometry every 10 ms, while its
// lidar sweeps 181 beams over [-45, +45] degrees in `sweep_s` seconds starting at t = 1 s:
// beam i measures the wall from where the base is at its own time. Returns the x extent of the
// occupied cells (metres) of the resulting map.
// `clockwise`: the beams run from +45 to -45 degrees (angle_increment < 0), as an RPLidar's do.
std::pair<double, double> WallExtent(float sweep_s, float scan_time_told, OdomMapperCounters* c,
                                     bool clockwise = false) {
  OdomMapper m(OdomMapperOptions{});
  for (int k = 0; k <= 300; ++k) {
    const int64_t t = 10000 * k;
    EXPECT_TRUE(m.AddOdometry(t, Pose2(1e-6 * static_cast<double>(t), 0, 0)));
  }
  Scan s;
  s.utime = 1000000;
  s.angle_min_rad = static_cast<float>(clockwise ? M_PI / 4 : -M_PI / 4);
  s.angle_increment_rad = static_cast<float>((clockwise ? -1 : 1) * M_PI / 2 / 180);
  s.range_max_m = 20;
  s.scan_time_s = scan_time_told;
  for (int i = 0; i <= 180; ++i) {
    const double x = 1.0 + sweep_s * i / 180.0;  // where the base is at beam i's time
    const double a = s.angle_min_rad + i * s.angle_increment_rad;
    s.ranges_m.push_back(static_cast<float>((5.02 - x) / std::cos(a)));
  }
  EXPECT_TRUE(m.AddScan(s));
  *c = m.counters();
  const io::GridMap g = m.Map();
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (int row = 0; row < g.height; ++row)
    for (int col = 0; col < g.width; ++col)
      if (g.at(col, row) > 50) {
        const double x = g.origin_x_m + (col + 0.5) * g.resolution_m;
        lo = std::min(lo, x);
        hi = std::max(hi, x);
      }
  return {lo, hi};
}

TEST(OdomMapper, PlacesEachBeamOfASweepAtItsOwnOdometryPose) {
  OdomMapperCounters c;
  // An instant scan: one cell column at the wall.
  auto e = WallExtent(0.f, 0.f, &c);
  EXPECT_NEAR(e.first, 5.025, 1e-9);
  EXPECT_NEAR(e.second, 5.025, 1e-9);
  EXPECT_EQ(c.sweeps_corrected + c.sweeps_uncorrected, 0);
  // A 0.1 s sweep (10 cm of travel) that says so: still one column.
  e = WallExtent(0.1f, 0.1f, &c);
  EXPECT_NEAR(e.first, 5.025, 1e-9);
  EXPECT_NEAR(e.second, 5.025, 1e-9);
  EXPECT_EQ(c.sweeps_corrected, 1);
  // The same sweep taken as instant: the wall smears 10 cm towards the base.
  e = WallExtent(0.1f, 0.f, &c);
  EXPECT_LT(e.first, 4.95);
  EXPECT_NEAR(e.second, 5.025, 1e-9);
  // Beams measured clockwise (negative increment, the RPLidar's order): corrected alike.
  e = WallExtent(0.1f, 0.1f, &c, /*clockwise=*/true);
  EXPECT_NEAR(e.first, 5.025, 1e-9);
  EXPECT_NEAR(e.second, 5.025, 1e-9);
  EXPECT_EQ(c.sweeps_corrected, 1);
}

// A scan whose geometry is absurd (a NaN mount pose, beams over more than a turn) is refused
// and counted as such, as the SLAM mappers do; it used to be "mapped" with every beam counted
// as beyond the grid's cap (review 2026-12-06).
TEST(OdomMapper, AScanWithAbsurdGeometryIsRefusedAndCounted) {
  OdomMapper m(OdomMapperOptions{});
  for (int k = 0; k <= 10; ++k) ASSERT_TRUE(m.AddOdometry(10000 * k, Pose2(0, 0, 0)));
  Scan s;
  s.utime = 50000;
  s.angle_min_rad = -1.f;
  s.angle_increment_rad = 0.01f;
  s.range_max_m = 20;
  s.ranges_m.assign(200, 2.f);
  Scan nan_mount = s;
  nan_mount.sensor_in_base = Pose2(std::nan(""), 0, 0);
  EXPECT_FALSE(m.AddScan(nan_mount));
  Scan wide = s;
  wide.angle_increment_rad = 0.1f;  // 200 beams over 20 rad
  EXPECT_FALSE(m.AddScan(wide));
  EXPECT_EQ(m.counters().scans_bad_geometry, 2);
  EXPECT_EQ(m.counters().scans_mapped, 0);
  EXPECT_EQ(m.counters().beams_beyond_grid_cap, 0);
  EXPECT_TRUE(m.AddScan(s));
  EXPECT_EQ(m.counters().scans_mapped, 1);
}

// Returns below range_min (a mast 0.10 m from a lidar whose range_min is 0.15 m) are no walls:
// the map once had them as an obstacle beside the robot (review finding).
// An arc of 200 returns at 2 m, seen from the origin at 50 ms (range_min 0.15 m).
Scan ArcScan(float range_max_m) {
  Scan s;
  s.utime = 50000;
  s.angle_min_rad = -1.f;
  s.angle_increment_rad = 0.01f;
  s.range_min_m = 0.15f;
  s.range_max_m = range_max_m;
  s.ranges_m.assign(200, 2.f);
  return s;
}

TEST(OdomMapper, ReturnsBelowRangeMinAreNotMapped) {
  OdomMapper m(OdomMapperOptions{});
  for (int k = 0; k <= 10; ++k) ASSERT_TRUE(m.AddOdometry(10000 * k, Pose2(0, 0, 0)));
  Scan s = ArcScan(20);
  for (int b = 0; b < 10; ++b) s.ranges_m[b] = 0.10f;
  ASSERT_TRUE(m.AddScan(s));
  const io::GridMap g = m.Map();
  int walls = 0, near = 0;
  for (int row = 0; row < g.height; ++row)
    for (int col = 0; col < g.width; ++col)
      if (g.at(col, row) > 50) {
        ++walls;
        const double x = g.origin_x_m + (col + 0.5) * g.resolution_m;
        const double y = g.origin_y_m + (row + 0.5) * g.resolution_m;
        near += std::hypot(x, y) < 0.5 ? 1 : 0;
      }
  EXPECT_GT(walls, 20);  // the arc at 2 m
  EXPECT_EQ(near, 0);
}

// A scan with range_max 0 (a driver that gives none: no limit, as the SLAM mappers read it) is
// mapped, walls and all. It was counted mapped while the grid got nothing: its beams were
// integrated with 0 as the limit, under which no return is a hit.
TEST(OdomMapper, AScanWithRangeMaxZeroIsMapped) {
  OdomMapper m(OdomMapperOptions{});
  for (int k = 0; k <= 10; ++k) ASSERT_TRUE(m.AddOdometry(10000 * k, Pose2(0, 0, 0)));
  ASSERT_TRUE(m.AddScan(ArcScan(0)));
  const io::GridMap g = m.Map();
  int walls = 0;
  for (int8_t v : g.cells) walls += v > 50 ? 1 : 0;
  EXPECT_GT(walls, 20);  // the arc at 2 m
}

TEST(OdomMapper, ASweepBeyondTheOdometryIsMappedAsItIsAndCounted) {
  OdomMapper m(OdomMapperOptions{});
  ASSERT_TRUE(m.AddOdometry(0, Pose2(0, 0, 0)));
  ASSERT_TRUE(m.AddOdometry(1000000, Pose2(1, 0, 0)));
  Scan s;
  s.utime = 1000000;
  s.angle_min_rad = -1.f;
  s.angle_increment_rad = 0.01f;
  s.range_max_m = 20;
  s.scan_time_s = 0.1f;  // odometry ends at the first beam
  s.ranges_m.assign(201, 3.f);
  ASSERT_TRUE(m.AddScan(s));
  EXPECT_EQ(m.counters().sweeps_uncorrected, 1);
  EXPECT_EQ(m.counters().sweeps_corrected, 0);
  EXPECT_EQ(m.counters().scans_mapped, 1);
}

// Odometry that glitches (one sample 10 km out), repeats a scan, is stamped an hour ahead
// once: the map stays where the robot is, the grid stays small, each event is counted.
TEST(OdomMapper, OdometryGlitchesAndRepeatsNeitherCorruptNorGrowTheMap) {
  OdomMapper m(OdomMapperOptions{});
  auto scan = [](int64_t utime, int64_t seq) {
    Scan s;
    s.utime = utime;
    s.seq = seq;
    s.angle_min_rad = -1.f;
    s.angle_increment_rad = 0.01f;
    s.range_max_m = 20;
    s.ranges_m.assign(201, 3.f);
    return s;
  };
  int64_t t = 0;
  for (int k = 0; k < 20; ++k, t += 100000) ASSERT_TRUE(m.AddOdometry(t, Pose2(0.01 * k, 0, 0)));
  ASSERT_TRUE(m.AddOdometry(t, Pose2(1e4, 0, 0)));  // a corrupt sample: bridged
  t += 100000;
  for (int k = 20; k < 25; ++k, t += 100000) ASSERT_TRUE(m.AddOdometry(t, Pose2(0.01 * k, 0, 0)));
  EXPECT_EQ(m.counters().odom_jumps, 2);  // out and back
  // Mapped where the robot really is: the last odometry pose continues from x = 0.19 m.
  ASSERT_TRUE(m.AddScan(scan(t - 100000, 1)));
  EXPECT_NEAR(m.trajectory().back().base_pose.x, 0.23, 1e-9);
  EXPECT_FALSE(m.AddScan(scan(t - 100000, 1)));  // the same scan again
  EXPECT_EQ(m.counters().scans_duplicate, 1);
  // One sample an hour ahead: five in-order samples after it prove it wrong.
  ASSERT_TRUE(m.AddOdometry(t + 3600000000LL, Pose2(0.25, 0, 0)));
  for (int k = 25; k < 29; ++k, t += 100000) EXPECT_FALSE(m.AddOdometry(t, Pose2(0.01 * k, 0, 0)));
  EXPECT_TRUE(m.AddOdometry(t, Pose2(0.29, 0, 0)));
  EXPECT_EQ(m.counters().time_rebases, 1);
  ASSERT_TRUE(m.AddScan(scan(t, 2)));
  EXPECT_NEAR(m.trajectory().back().base_pose.x, 0.28, 1e-9);  // the bridge stays
  EXPECT_LT(m.Map().width * m.Map().height, 1000000);
  EXPECT_EQ(m.counters().beams_beyond_grid_cap, 0);
}

// A sample both corrupt (10 km out) and stamped an hour ahead: its jump bridge leaves with it,
// so the samples that prove it continue where the robot was. Then the odometry's clock and
// counters restart (a reboot): the restart is bridged, not mapped 25 m back.
TEST(OdomMapper, ARebaseUndoesTheDroppedSamplesJumpBridge) {
  OdomMapper m(OdomMapperOptions{});
  Scan s;
  s.angle_min_rad = -1.f;
  s.angle_increment_rad = 0.01f;
  s.range_max_m = 20;
  s.ranges_m.assign(201, 3.f);
  int64_t t = 1000000000;
  double x = 25;  // 25 m from where the odometry started
  for (int k = 0; k < 20; ++k, t += 100000, x += 0.01)
    ASSERT_TRUE(m.AddOdometry(t, Pose2(x, 0, 0)));
  ASSERT_TRUE(m.AddOdometry(t + 3600000000LL, Pose2(1e4, 0, 0)));
  for (int k = 0; k < 5; ++k, t += 100000, x += 0.01) m.AddOdometry(t, Pose2(x, 0, 0));
  EXPECT_EQ(m.counters().time_rebases, 1);
  EXPECT_EQ(m.counters().odom_jumps, 1);  // only the corrupt sample's
  s.utime = t - 100000;
  s.seq = 1;
  ASSERT_TRUE(m.AddScan(s));
  EXPECT_NEAR(m.trajectory().back().base_pose.x, x - 0.01, 1e-9);
  // Reboot: stamps from 1 s again, odometry from 0.
  const double before = x - 0.01;
  for (int k = 0; k < 6; ++k) m.AddOdometry(1000000 + 100000 * k, Pose2(0.01 * k, 0, 0));
  EXPECT_EQ(m.counters().time_rebases, 2);
  EXPECT_EQ(m.counters().odom_jumps, 2);  // the restart, bridged
  s.utime = 1500000;
  s.seq = 2;
  ASSERT_TRUE(m.AddScan(s));
  EXPECT_NEAR(m.trajectory().back().base_pose.x, before + 0.05, 1e-9);
  EXPECT_LT(static_cast<int64_t>(m.Map().width) * m.Map().height, 1000000);
}

// One odometry sample stamped in the past (a late, wrong-looking message) among in-order
// ones: refused and counted, never used to place a scan, and not a re-base or a jump.
TEST(OdomMapper, AStaleOdometrySampleIsCountedAndNotUsed) {
  OdomMapper m(OdomMapperOptions{});
  for (int k = 0; k <= 20; ++k) ASSERT_TRUE(m.AddOdometry(100000 * k, Pose2(0.1 * k, 0, 0)));
  // Stamped between samples 10 and 11, 1 m to the side of where the base was then.
  EXPECT_FALSE(m.AddOdometry(1050000, Pose2(1.05, 1.0, 0.3)));
  EXPECT_EQ(m.counters().odom_out_of_order, 1);
  for (int k = 21; k <= 30; ++k) ASSERT_TRUE(m.AddOdometry(100000 * k, Pose2(0.1 * k, 0, 0)));
  Scan s;
  s.utime = 1050000;
  s.angle_min_rad = -1.f;
  s.angle_increment_rad = 0.01f;
  s.range_max_m = 20;
  s.ranges_m.assign(201, 3.f);
  ASSERT_TRUE(m.AddScan(s));
  const Pose2 p = m.trajectory().back().base_pose;
  EXPECT_NEAR(p.x, 1.05, 1e-9);  // interpolated between the in-order samples
  EXPECT_NEAR(p.y, 0.0, 1e-12);
  EXPECT_NEAR(p.theta, 0.0, 1e-12);
  EXPECT_EQ(m.counters().odom_out_of_order, 1);
  EXPECT_EQ(m.counters().time_rebases, 0);
  EXPECT_EQ(m.counters().odom_jumps, 0);
}

TEST(OdomMapper, TheGridNeverOutgrowsItsCap) {
  OdomMapperOptions o;
  o.max_grid_cells = 1 << 20;  // 51 m x 51 m at 5 cm
  OdomMapper m(o);
  Scan s;
  s.angle_min_rad = -1.f;
  s.angle_increment_rad = 0.01f;
  s.range_max_m = 20;
  s.ranges_m.assign(201, 3.f);
  // Far steps, each under the jump limit, take the robot 300 m out.
  for (int k = 0; k <= 150; ++k) {
    ASSERT_TRUE(m.AddOdometry(100000 * k, Pose2(2.0 * k, 0, 0)));
    s.utime = 100000 * k;
    s.seq = k;
    ASSERT_TRUE(m.AddScan(s));
  }
  EXPECT_GT(m.counters().beams_beyond_grid_cap, 0);
  const io::GridMap g = m.Map();
  EXPECT_LE(static_cast<int64_t>(g.width) * g.height, o.max_grid_cells);
  EXPECT_EQ(m.counters().scans_mapped, 151);
}

}  // namespace
}  // namespace omni::odom_mapper
