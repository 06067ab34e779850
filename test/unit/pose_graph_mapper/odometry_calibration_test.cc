// Odometry self-calibration: the error model and its inverse, the fit recovering a known
// systematic error from noisy matches, gating and clamping, the residual-based noise scale, and
// the odometry source composing calibrated steps.
#include <gtest/gtest.h>

#include <random>

#include "omni/common/odometry_calibration.h"
#include "omni/pose_graph_mapper/continuous_source.h"

namespace omni::pgm {
namespace {

// Roughly the error the slam-noisy-odom logs were made with (their README): 3 % scale, 1 %
// lateral creep, 2 % heading scale, 0.015 rad per metre.
OdometryCalibration KnownError() {
  OdometryCalibration c;
  c.x_scale = 0.03;
  c.y_per_x = 0.01;
  c.theta_scale = 0.02;
  c.theta_per_x = 0.015;
  return c;
}

// A keyframe-sized true step: 0.3-0.7 m forward, a little sideways, up to 0.35 rad of turn.
Pose2 RandomStep(std::mt19937& rng) {
  std::uniform_real_distribution<double> fwd(0.3, 0.7), side(-0.05, 0.05), turn(-0.35, 0.35);
  return Pose2(fwd(rng), side(rng), turn(rng));
}

TEST(OdometryCalibration, CorrectInvertsDistort) {
  const OdometryCalibration c = KnownError();
  std::mt19937 rng(1);
  for (int i = 0; i < 100; ++i) {
    const Pose2 t = RandomStep(rng);
    const Pose2 back = c.Correct(c.Distort(t));
    EXPECT_NEAR(back.x, t.x, 1e-12);
    EXPECT_NEAR(back.y, t.y, 1e-12);
    EXPECT_NEAR(back.theta, t.theta, 1e-12);
  }
  const Pose2 raw = c.Distort(Pose2(1.0, 0.0, 0.0));
  EXPECT_NEAR(raw.x, 1.03, 1e-12);  // the model, spelled out once
  EXPECT_NEAR(raw.y, 0.01, 1e-12);
  EXPECT_NEAR(raw.theta, 0.015, 1e-12);
  EXPECT_TRUE(OdometryCalibration().IsIdentity());
  EXPECT_FALSE(c.IsIdentity());
}

TEST(OdometryCalibrator, RecoversAKnownErrorFromNoisyMatches) {
  OdometryCalibratorOptions o;
  o.min_pairs = 15;
  o.min_forward_m = 5.0;
  OdometryCalibrator cal(o);
  const OdometryCalibration truth = KnownError();
  std::mt19937 rng(7);
  std::normal_distribution<double> xy(0.0, 0.02), th(0.0, 0.01);  // the matches' own error
  for (int i = 0; i < 400; ++i) {
    const Pose2 t = RandomStep(rng);
    const Pose2 matched(t.x + xy(rng), t.y + xy(rng), t.theta + th(rng));
    EXPECT_TRUE(cal.AddPair(truth.Distort(t), matched));
    if (i + 1 < o.min_pairs) {
      EXPECT_FALSE(cal.active()) << i;
    }
  }
  ASSERT_TRUE(cal.active());
  const OdometryCalibration& c = cal.calibration();
  EXPECT_NEAR(c.x_scale, truth.x_scale, 0.006);
  EXPECT_NEAR(c.y_per_x, truth.y_per_x, 0.006);
  EXPECT_NEAR(c.theta_scale, truth.theta_scale, 0.01);
  EXPECT_NEAR(c.theta_per_x, truth.theta_per_x, 0.004);
  EXPECT_EQ(cal.pairs_used(), 400);
  EXPECT_EQ(cal.pairs_gated(), 0);
  EXPECT_GE(cal.updates(), 30);  // refitted every 10 pairs after the first
  // Without adapt_noise the noise is left as configured.
  EXPECT_EQ(cal.noise_scale(), 1.0);
}

TEST(OdometryCalibrator, GatesOutliersAndBadInputAndClamps) {
  OdometryCalibratorOptions o;
  o.min_pairs = 5;
  o.min_forward_m = 1.0;
  o.max_abs_scale = 0.01;  // the true 3 % scale must come out clamped
  OdometryCalibrator cal(o);
  const OdometryCalibration truth = KnownError();
  std::mt19937 rng(3);
  for (int i = 0; i < 50; ++i) {
    const Pose2 t = RandomStep(rng);
    cal.AddPair(truth.Distort(t), t);
  }
  ASSERT_TRUE(cal.active());
  EXPECT_DOUBLE_EQ(cal.calibration().x_scale, 0.01);
  const int64_t used = cal.pairs_used();
  // A wrong match 1 m off, a heading 0.5 rad off, NaN, and a non-positive-definite covariance.
  EXPECT_FALSE(cal.AddPair(Pose2(0.5, 0, 0), Pose2(1.5, 0, 0)));
  EXPECT_FALSE(cal.AddPair(Pose2(0.5, 0, 0.5), Pose2(0.5, 0, 0)));
  EXPECT_FALSE(cal.AddPair(Pose2(std::nan(""), 0, 0), Pose2(0.5, 0, 0)));
  EXPECT_FALSE(cal.AddPair(Pose2(0.5, 0, 0), Pose2(0.5, 0, 0), -Eigen::Matrix3d::Identity()));
  EXPECT_EQ(cal.pairs_gated(), 4);
  EXPECT_EQ(cal.pairs_used(), used);
}

TEST(OdometryCalibrator, NoiseScaleFromResiduals) {
  // The odometry's real noise is 0.1 x the configured model: the suggested scale is about 0.1,
  // and applied only with adapt_noise (clamped to its bounds).
  const Eigen::Matrix3d model = Eigen::Vector3d(1e-2, 1e-2, 1e-3).asDiagonal();
  for (bool adapt : {false, true}) {
    OdometryCalibratorOptions o;
    o.adapt_noise = adapt;
    o.min_noise_scale = 0.2;
    OdometryCalibrator cal(o);
    std::mt19937 rng(11);
    std::normal_distribution<double> n01(0.0, 1.0);
    const Eigen::Vector3d sd = (0.1 * model.diagonal()).cwiseSqrt();
    for (int i = 0; i < 2000; ++i) {
      const Pose2 t = RandomStep(rng);
      const Pose2 noisy = t * Pose2(sd(0) * n01(rng), sd(1) * n01(rng), sd(2) * n01(rng));
      ASSERT_TRUE(cal.AddPair(noisy, t, model));
    }
    EXPECT_NEAR(cal.suggested_noise_scale(), 0.1, 0.02);
    EXPECT_DOUBLE_EQ(cal.noise_scale(), adapt ? 0.2 : 1.0);
  }
}

TEST(OdometryCalibration, SourceComposesCalibratedSteps) {
  // Raw odometry made by distorting every true 20 ms step; with the error set, Between gives
  // the true motion; the noise scale multiplies the covariance.
  const OdometryCalibration err = KnownError();
  OdometrySource odo;
  Pose2 truth, raw;
  std::vector<Pose2> true_poses;
  for (int k = 0; k <= 200; ++k) {
    ASSERT_TRUE(odo.AddSample(20'000 * k, raw));
    true_poses.push_back(truth);
    const Pose2 step(0.01, 0.0005, 0.004 * std::cos(0.05 * k));
    truth = truth * step;
    raw = raw * err.Distort(step);
  }
  const auto uncalibrated = odo.Between(0, 4'000'000);
  ASSERT_TRUE(uncalibrated);
  const Pose2 want = true_poses.front().Between(true_poses.back());
  EXPECT_GT(std::hypot(uncalibrated->delta.x - want.x, uncalibrated->delta.y - want.y), 0.03);
  odo.SetCalibration(err);
  const auto m = odo.Between(0, 4'000'000);
  ASSERT_TRUE(m);
  EXPECT_NEAR(m->delta.x, want.x, 1e-9);
  EXPECT_NEAR(m->delta.y, want.y, 1e-9);
  EXPECT_NEAR(WrapAngle(m->delta.theta - want.theta), 0.0, 1e-9);
  odo.SetNoiseScale(0.25);
  const auto scaled = odo.Between(0, 4'000'000);
  ASSERT_TRUE(scaled);
  EXPECT_TRUE(scaled->covariance.isApprox(0.25 * m->covariance, 1e-9));
}

// The shared config reader: every key for the pose graph, min <= max noise scale; without the
// graph's keys (the RBPF) setting one of them is an unknown-key error, not a silent no-op.
TEST(OdometryCalibrator, ConfigKeysAreCheckedPerMapper) {
  auto read = [](const std::string& yaml, bool graph_keys, OdometryCalibratorOptions* o) {
    auto r = ConfigReader::FromString(yaml, "t.yaml");
    EXPECT_TRUE(r.ok());
    ConfigReader section = r->Section("odometry_calibration");
    ReadOdometryCalibratorOptions(section, o, graph_keys);
    return r->Finish();
  };
  OdometryCalibratorOptions o;
  EXPECT_TRUE(read("odometry_calibration:\n  min_pairs: 7\n  adapt_noise: true\n", true, &o).ok());
  EXPECT_EQ(o.min_pairs, 7);
  EXPECT_TRUE(o.adapt_noise);
  const Status swapped =
      read("odometry_calibration:\n  min_noise_scale: 5\n  max_noise_scale: 0.1\n", true, &o);
  ASSERT_FALSE(swapped.ok());
  EXPECT_NE(swapped.message().find("max_noise_scale"), std::string::npos) << swapped.message();
  OdometryCalibratorOptions r;
  EXPECT_TRUE(read("odometry_calibration:\n  min_pairs: 9\n", false, &r).ok());
  EXPECT_EQ(r.min_pairs, 9);
  const Status graph_only = read("odometry_calibration:\n  adapt_noise: true\n", false, &r);
  ASSERT_FALSE(graph_only.ok());
  EXPECT_NE(graph_only.message().find("adapt_noise"), std::string::npos) << graph_only.message();
}

}  // namespace
}  // namespace omni::pgm
