// SlipMonitor: the encoders' heading change against the gyro's, window by window, with the
// gyro's bias learned while the base stands still.
#include "omni/base_bridge/slip_monitor.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

namespace omni::base_bridge {
namespace {

// 100 Hz gyro (bias 0.004 rad/s, noise 0.002 rad/s) and 100 Hz odometry: 3 s parked, 3 s
// turning at 0.5 rad/s with the encoders agreeing, 1 s in which the encoders say 0.5 rad/s
// but the base turns at 0.3 (a wheel slipping), 3 s agreeing again, then the gyro falls silent.
TEST(SlipMonitor, FlagsTheWindowsWhereTheEncodersTurnMoreThanTheGyro) {
  SlipMonitor m{SlipOptions{}};
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.002);
  double enc = 0;
  bool slipped_in_phase3 = false, slipping_in_phase2 = false;
  for (int k = 1; k <= 1000; ++k) {
    const int64_t t = 10'000 * int64_t{k};
    const double s = 0.01 * k;
    const double truth = s <= 3.0 ? 0.0 : (s > 6.0 && s <= 7.0) ? 0.3 : 0.5;
    const double wheels = s <= 3.0 ? 0.0 : 0.5;
    ASSERT_TRUE(m.AddGyro(t, truth + 0.004 + noise(rng)));
    enc += wheels * 0.01;
    m.AddOdometry(t, Pose2(0, 0, WrapAngle(enc)));
    if (s > 3.5 && s <= 6.0) slipping_in_phase2 |= m.slipping();
    if (s > 6.0 && s <= 7.3) slipped_in_phase3 |= m.slipping();
    if (s > 7.0 && s < 7.2 && m.slipping()) {
      EXPECT_NE(m.Problem().find("wheels slipping"), std::string::npos) << m.Problem();
    }
  }
  EXPECT_FALSE(slipping_in_phase2);
  EXPECT_TRUE(slipped_in_phase3);
  EXPECT_FALSE(m.slipping());
  EXPECT_EQ(m.Problem(), "");
  const SlipCounters& c = m.counters();
  EXPECT_EQ(c.slip_events, 1);
  EXPECT_GE(c.slip_windows, 2);  // 0.5 s windows every 0.25 s over a 1 s slip
  EXPECT_LE(c.slip_windows, 6);
  EXPECT_NEAR(c.windows, 40, 2);  // 10 s, one every 0.25 s once the first window is full
  // Parked 3 s less 0.2 s at each end: two whole 1 s chunks.
  EXPECT_EQ(m.bias_samples(), 2);
  EXPECT_NEAR(m.gyro_bias(), 0.004, 0.0005);
  // Bad gyro samples are refused and counted.
  EXPECT_FALSE(m.AddGyro(10'000'000, 0.0));
  EXPECT_FALSE(m.AddGyro(20'000'000, std::nan("")));
  EXPECT_EQ(c.gyro_rejected, 2);
}

// Slipping when the gyro falls silent: the verdict does not outlive the data.
TEST(SlipMonitor, ASilentGyroClearsTheVerdict) {
  SlipMonitor m{SlipOptions{}};
  double enc = 0;
  for (int k = 1; k <= 200; ++k) {  // 2 s: encoders 1 rad/s, gyro 0
    const int64_t t = 10'000 * int64_t{k};
    m.AddGyro(t, 0.0);
    enc += 0.01;
    m.AddOdometry(t, Pose2(0, 0, enc));
  }
  EXPECT_TRUE(m.slipping());
  for (int k = 201; k <= 400; ++k) {  // the odometry goes on alone
    enc += 0.01;
    m.AddOdometry(10'000 * int64_t{k}, Pose2(0, 0, enc));
  }
  EXPECT_FALSE(m.slipping());
  EXPECT_EQ(m.counters().slip_events, 1);
}

// The machine's clock set back by 100 s (both streams are stamped by it): the histories start
// over on the new time line and the windows are judged again; a lone gyro sample from the
// past is refused.
TEST(SlipMonitor, StartsOverWhenTheClockGoesBack) {
  SlipMonitor m{SlipOptions{}};
  double enc = 0;
  auto feed = [&](int64_t t0, int n) {
    for (int k = 1; k <= n; ++k) {
      const int64_t t = t0 + 10'000 * int64_t{k};
      m.AddGyro(t, 0.5);
      enc += 0.005;
      m.AddOdometry(t, Pose2(0, 0, WrapAngle(enc)));
    }
  };
  feed(200'000'000, 200);
  const int64_t judged = m.counters().windows;
  EXPECT_GE(judged, 6);
  EXPECT_FALSE(m.AddGyro(100'000'000, 0.5));  // one from the past: refused
  feed(100'000'000, 200);                     // the clock went back for good
  EXPECT_GE(m.counters().windows, judged + 6);
  EXPECT_GE(m.counters().time_rebases, 1);
  EXPECT_EQ(m.counters().slip_windows, 0);
  EXPECT_FALSE(m.slipping());
  // The same time again (a coarse clock) is not the clock going back: counted and ignored.
  const int64_t rebases = m.counters().time_rebases, windows = m.counters().windows;
  const int64_t last = 100'000'000 + 10'000 * 200;
  m.AddOdometry(last, Pose2(0, 0, WrapAngle(enc)));
  EXPECT_EQ(m.counters().time_rebases, rebases);
  EXPECT_EQ(m.counters().odom_duplicates, 1);
  feed(last, 30);  // and the windows go on without a restart
  EXPECT_GT(m.counters().windows, windows);
}

}  // namespace
}  // namespace omni::base_bridge
