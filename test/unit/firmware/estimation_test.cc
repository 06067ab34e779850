// Quadrature decoding, speed estimation, and the firmware's float kinematics against the
// common double implementation.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "omni/common/kinematics.h"
#include "omni/firmware/quadrature.h"
#include "omni/firmware/speed_estimator.h"

namespace omni::firmware {
namespace {

TEST(EncoderCounterTest, SurvivesWrapBothWays) {
  EncoderCounter c;
  c.Reset(65530);
  EXPECT_EQ(c.Update(4), 10);  // 65530 -> 4 across the wrap
  EXPECT_EQ(c.position(), 10);
  EXPECT_EQ(c.Update(65000), -540);
  EXPECT_EQ(c.position(), -530);
  // Long run forwards: many wraps of the 16-bit counter.
  uint16_t raw = 65000;
  for (int i = 0; i < 1000; ++i) {
    raw = static_cast<uint16_t>(raw + 1000);
    c.Update(raw);
  }
  EXPECT_EQ(c.position(), -530 + 1000 * 1000);
}

// 2^31 counts in one direction (74 h at the reference base's top speed): the position wraps
// modulo 2^32, as the firmware's feedback and the speed estimator expect, instead of
// overflowing a signed integer (undefined behaviour, which the sanitizer build reports).
TEST(EncoderCounterTest, PositionWrapsPast32Bits) {
  EncoderCounter c;
  c.Reset(0);
  uint16_t raw = 0;
  const int32_t step = 30000;                           // under the 32768 counts one read may see
  const int64_t steps = (int64_t{1} << 31) / step + 1;  // the last one crosses INT32_MAX
  int32_t before = 0;
  for (int64_t i = 0; i < steps; ++i) {
    raw = static_cast<uint16_t>(raw + step);
    before = c.position();
    EXPECT_EQ(c.Update(raw), step);
    if (CountsBetween(before, c.position()) != step) FAIL() << "step " << i;
  }
  EXPECT_LT(c.position(), 0);  // wrapped past INT32_MAX
  EXPECT_GT(before, 0);
  EXPECT_EQ(CountsBetween(before, c.position()), step);
  EXPECT_EQ(static_cast<uint16_t>(c.position()), raw);  // the low 16 bits the feedback sends
}

TEST(QuadratureDecoderTest, CountsX4AndDirection) {
  QuadratureDecoderX4 q;
  q.Reset(false, false);
  const bool seq[4][2] = {{true, false}, {true, true}, {false, true}, {false, false}};  // A leads
  for (int cycle = 0; cycle < 10; ++cycle)
    for (const auto& s : seq) q.Sample(s[0], s[1]);
  EXPECT_EQ(q.count(), 40);  // 4 counts per cycle
  for (int cycle = 0; cycle < 3; ++cycle)
    for (int i = 3; i >= 0; --i) q.Sample(seq[(i + 3) % 4][0], seq[(i + 3) % 4][1]);
  EXPECT_EQ(q.count(), 28);
  EXPECT_EQ(q.errors(), 0u);
  q.Sample(true, true);  // from 00 straight to 11: a missed state
  EXPECT_EQ(q.errors(), 1u);
  EXPECT_EQ(q.count(), 28);
}

// Speeds from standstill to full speed, counts from an exact angle (quantised at 1440/turn).
class SpeedEstimatorTest : public ::testing::TestWithParam<double> {};

TEST_P(SpeedEstimatorTest, TracksConstantSpeed) {
  const double rad_s = GetParam();
  const double ticks_per_rev = 1440.0, dt = 0.001;
  SpeedEstimator est;
  est.Reset(0);
  double angle = 0.3;
  float estimate = 0.f;
  for (int k = 0; k < 500; ++k) {
    angle += rad_s * dt;
    const int32_t counts = static_cast<int32_t>(std::floor(angle / (2 * M_PI) * ticks_per_rev));
    estimate = est.Update(counts) * static_cast<float>(2 * M_PI / (ticks_per_rev * dt));
  }
  const double tol = std::max(0.05 * std::fabs(rad_s), 0.02);
  EXPECT_NEAR(estimate, rad_s, tol);
}
INSTANTIATE_TEST_SUITE_P(Speeds, SpeedEstimatorTest,
                         ::testing::Values(-30.0, -2.0, -0.3, 0.0, 0.2, 0.5, 1.0, 3.0, 8.0, 20.0,
                                           40.0));

TEST(SpeedEstimatorStopTest, DecaysToZeroAfterStop) {
  SpeedEstimator est;
  est.Reset(0);
  int32_t pos = 0;
  for (int k = 0; k < 200; ++k) est.Update(pos += 2);
  EXPECT_NEAR(est.counts_per_period(), 2.f, 1e-3f);
  float prev = est.counts_per_period();
  for (int k = 0; k < 70; ++k) {
    const float s = est.Update(pos);
    EXPECT_LE(s, prev + 1e-6f);  // monotone decay, never a jump up
    prev = s;
  }
  EXPECT_EQ(est.counts_per_period(), 0.f);
}

// The same speed measured across the position's 32-bit wrap.
TEST(SpeedEstimatorStopTest, SameSpeedAcrossThePositionWrap) {
  for (const int32_t per_period : {7, -7, 1, -1}) {
    SpeedEstimator plain, wrapping;
    int32_t pos = 0;
    const int32_t origin = per_period > 0 ? INT32_MAX - 150 : INT32_MIN + 150;
    plain.Reset(pos);
    wrapping.Reset(origin);
    for (int k = 0; k < 200; ++k) {
      pos += (per_period == 1 || per_period == -1) ? (k % 3 == 0 ? per_period : 0) : per_period;
      const int32_t wrapped =
          static_cast<int32_t>(static_cast<uint32_t>(origin) + static_cast<uint32_t>(pos));
      EXPECT_EQ(plain.Update(pos), wrapping.Update(wrapped)) << per_period << " at " << k;
    }
    EXPECT_NE(plain.counts_per_period(), 0.f);
  }
}

TEST(KinematicsFloatTest, FirmwareFloatMatchesCommonDouble) {
  using namespace omni::kinematics;
  const auto gd = SymmetricGeometry(0.15, 0.05);
  const OmniGeometry<float> gf{2.0943951f, 0.15f, 0.05f};
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  for (int i = 0; i < 1000; ++i) {
    const BodyTwist<double> td{u(rng), u(rng), 2 * u(rng)};
    const BodyTwist<float> tf{static_cast<float>(td.vx_m_s), static_cast<float>(td.vy_m_s),
                              static_cast<float>(td.omega_rad_s)};
    const auto wd = BodyToWheels(gd, td);
    const auto wf = BodyToWheels(gf, tf);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(wf.v_m_s[k], wd.v_m_s[k], 1e-5);
    BodyTwist<float> back;
    ASSERT_TRUE(WheelsToBody(gf, wf, &back));
    EXPECT_NEAR(back.vx_m_s, td.vx_m_s, 1e-5);
    EXPECT_NEAR(back.vy_m_s, td.vy_m_s, 1e-5);
    EXPECT_NEAR(back.omega_rad_s, td.omega_rad_s, 1e-4);
    // Eq. (3) = eq. (1) after eq. (2)^-1, in float too.
    const float theta = static_cast<float>(u(rng));
    const WorldVelocity<float> world = BodyToWorld(theta, tf);
    const auto w3 = WorldToWheels(gf, theta, world);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(w3.v_m_s[k], wf.v_m_s[k], 2e-5);
  }
}

}  // namespace
}  // namespace omni::firmware
