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
std::pair<double, double> WallExtent(float sweep_s, float scan_time_told, OdomMapperCounters* c) {
  OdomMapper m(OdomMapperOptions{});
  for (int k = 0; k <= 300; ++k) {
    const int64_t t = 10000 * k;
    EXPECT_TRUE(m.AddOdometry(t, Pose2(1e-6 * static_cast<double>(t), 0, 0)));
  }
  Scan s;
  s.utime = 1000000;
  s.angle_min_rad = static_cast<float>(-M_PI / 4);
  s.angle_increment_rad = static_cast<float>(M_PI / 2 / 180);
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

}  // namespace
}  // namespace omni::odom_mapper
