// StillGyroBias (omni/common/gyro_bias.h): a gyro's bias learned from the stretches in which the
// wheel odometry stands still, as both mappers that fuse the gyro use it.
#include "omni/common/gyro_bias.h"

#include <cmath>
#include <optional>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace omni {
namespace {

// The estimate is the samples' running mean, then (past memory_s of them) an exponential
// average; the odometry's own turn is not bias; a turn the wheels did not see is refused.
TEST(StillGyroBias, RunningMeanThenExponentialAverageAndRefusals) {
  GyroBiasOptions o;
  o.memory_s = 3.0;
  StillGyroBias b(o, 0.01);  // the configured bias, wrong
  EXPECT_EQ(b.bias(), 0.01);
  EXPECT_TRUE(b.Learn(1.0, 0.004, 0.0));
  EXPECT_NEAR(b.bias(), 0.004, 1e-15);      // the first sample replaces the configured one
  EXPECT_TRUE(b.Learn(1.0, 0.004, 0.001));  // the odometry turned by 1 mrad meanwhile
  EXPECT_NEAR(b.bias(), 0.0035, 1e-15);     // mean of 0.004 and 0.003
  EXPECT_TRUE(b.Learn(1.0, 0.004, 0.0));
  EXPECT_NEAR(b.bias(), 0.011 / 3, 1e-15);
  // Past memory_s of still time each 1 s sample weighs 1/3: a drifted bias is followed.
  for (int k = 0; k < 5; ++k) EXPECT_TRUE(b.Learn(1.0, 0.006, 0.0));
  EXPECT_NEAR(b.bias(), 0.006 - (0.006 - 0.011 / 3) * std::pow(2.0 / 3.0, 5), 1e-15);
  const double before = b.bias();
  EXPECT_FALSE(b.Learn(1.0, 0.004, -0.05));  // 0.054 rad/s: turned without its wheels
  EXPECT_FALSE(b.Learn(1.0, std::nan(""), 0.0));
  EXPECT_FALSE(b.Learn(0.0, 0.0, 0.0));
  EXPECT_EQ(b.bias(), before);
  EXPECT_EQ(b.samples(), 8);
  EXPECT_EQ(b.refused(), 3);
}

// The stretches: odometry at 50 Hz standing still from 0 to 5 s (with an encoder tick of
// jitter), moving 5-6 s, still again 6-10 s; a gyro of constant raw rate 0.003 rad/s whose
// samples lag the odometry by 0.5 s. Chunks of 1 s, 0.2 s left out at each end of a stretch.
TEST(StillGyroBias, SamplesWholeChunksOfStillStretchesOnceTheGyroCoversThem) {
  StillGyroBias b;
  int64_t gyro_newest = 0;
  std::vector<std::pair<int64_t, int64_t>> asked;
  const StillGyroBias::RawYaw gyro = [&](int64_t t0, int64_t t1) -> std::optional<double> {
    if (t1 > gyro_newest) return std::nullopt;
    asked.emplace_back(t0, t1);
    return 0.003 * 1e-6 * static_cast<double>(t1 - t0);
  };
  Pose2 pose(1, 2, 3.1);  // near +-pi: the stretch's headings must not wrap
  for (int k = 0; k <= 500; ++k) {
    const int64_t t = 20'000 * int64_t{k};
    gyro_newest = t - 500'000;
    if (k > 250 && k <= 300) pose = pose * Pose2(0.01, 0, 0.01);
    const double tick = k % 7 == 0 ? 2e-4 : 0.0;
    b.AddOdometry(t, Pose2(pose.x + tick, pose.y, WrapAngle(pose.theta + 0.05 + tick)), gyro);
  }
  // Stretch 1 (0-5 s): chunks [0.2, 1.2] ... [3.2, 4.2] (the next would end 0.2 s before 5.4).
  // Stretch 2 (from 6 s, the last moving pose, to 10 s): [6.2, 7.2] ... [8.2, 9.2]; [9.2,
  // 10.2] is not yet over. The gyro lags by 0.5 s: [3.2, 4.2] still comes (asked at 4.7 s).
  ASSERT_EQ(asked.size(), 7u);
  EXPECT_EQ(asked[0], std::make_pair(int64_t{200'000}, int64_t{1'200'000}));
  EXPECT_EQ(asked[3], std::make_pair(int64_t{3'200'000}, int64_t{4'200'000}));
  EXPECT_EQ(asked[4], std::make_pair(int64_t{6'200'000}, int64_t{7'200'000}));
  EXPECT_EQ(b.samples(), 7);
  // The ticks move the odometry's heading by up to 0.2 mrad within a chunk.
  EXPECT_NEAR(b.bias(), 0.003, 2.5e-4);
  // Off: nothing is learned.
  GyroBiasOptions off;
  off.estimate = false;
  StillGyroBias none(off, 0.001);
  for (int k = 0; k <= 200; ++k) none.AddOdometry(20'000 * int64_t{k}, Pose2(), gyro);
  EXPECT_EQ(none.samples(), 0);
  EXPECT_EQ(none.bias(), 0.001);
}

// A gyro that starts 3 s after the odometry (the IMU driver came up late) while the base stands
// still for a minute: the chunks before its first sample are waited for kMaxGyroWaitS, then
// skipped, and the rest of the stop is learned. No gyro at all: every chunk is skipped and the
// stretch's poses stay bounded.
TEST(StillGyroBias, AGyroThatStartsLateOrNeverIsWaitedForThenSkipped) {
  const int64_t first_gyro = 3'000'000;
  const StillGyroBias::RawYaw late = [&](int64_t t0, int64_t t1) -> std::optional<double> {
    if (t0 < first_gyro) return std::nullopt;  // before its first sample: never covered
    return 0.002 * 1e-6 * static_cast<double>(t1 - t0);
  };
  const StillGyroBias::RawYaw never = [](int64_t, int64_t) { return std::nullopt; };
  StillGyroBias b, n;
  for (int k = 0; k <= 3000; ++k) {  // 60 s at 50 Hz
    const int64_t t = 20'000 * int64_t{k};
    b.AddOdometry(t, Pose2(1, 2, 0.5), late);
    n.AddOdometry(t, Pose2(1, 2, 0.5), never);
  }
  // [0.2, 1.2], [1.2, 2.2] and [2.2, 3.2] skipped; [3.2, 4.2] ... [58.2, 59.2] learned.
  EXPECT_EQ(b.uncovered(), 3);
  EXPECT_EQ(b.samples(), 56);
  EXPECT_NEAR(b.bias(), 0.002, 1e-12);
  EXPECT_EQ(n.samples(), 0);
  EXPECT_GE(n.uncovered(), 50);
  // Kept: the poses since the oldest chunk still waited for (5 s + a chunk + the edge).
  EXPECT_LT(n.held_poses(), 400u);
}

}  // namespace
}  // namespace omni
