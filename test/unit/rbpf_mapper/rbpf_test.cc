// Unit tests of the RBPF library: motion model moments, Neff, low-variance resampling,
// copy-on-write map sharing, the scan matcher on real corrected scans, determinism and bad
// input handling.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <limits>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "../common/test_paths.h"
#include "omni/common/config.h"
#include "omni/io/carmen.h"
#include "omni/rbpf_mapper/motion_model.h"
#include "omni/rbpf_mapper/proposal.h"
#include "omni/rbpf_mapper/rbpf.h"
#include "omni/rbpf_mapper/scan_matcher.h"
#include "omni/rbpf_mapper/thread_pool.h"
#include "omni/rbpf_mapper/tiled_grid.h"

namespace omni::rbpf {
namespace {

TEST(MotionModel, SampleMomentsMatchTheModel) {
  MotionNoise noise;
  OmniMotionModel model(noise);
  const Pose2 delta(0.8, 0.3, 0.25);  // forward, sideways (omni) and turning at once
  const MotionSigma sigma = model.Sigma(delta);
  EXPECT_NEAR(sigma.x, noise.min_xy_m + noise.a_xx * 0.8 + noise.a_xy * 0.3 + noise.a_xt * 0.25,
              1e-12);
  EXPECT_NEAR(sigma.y, noise.min_xy_m + noise.a_yx * 0.8 + noise.a_yy * 0.3 + noise.a_yt * 0.25,
              1e-12);
  std::mt19937_64 rng(42);
  const int n = 40000;
  double sx = 0, sy = 0, st = 0, sxx = 0, syy = 0, stt = 0, sxy = 0;
  for (int i = 0; i < n; ++i) {
    const Pose2 p = model.Sample(Pose2(), delta, rng);  // from the origin: p is the noisy delta
    const double dx = p.x - delta.x, dy = p.y - delta.y, dt = WrapAngle(p.theta - delta.theta);
    sx += dx;
    sy += dy;
    st += dt;
    sxx += dx * dx;
    syy += dy * dy;
    stt += dt * dt;
    sxy += dx * dy;
  }
  const double se = 4.0 / std::sqrt(static_cast<double>(n));  // ~4 standard errors
  EXPECT_NEAR(sx / n, 0.0, se * sigma.x);
  EXPECT_NEAR(sy / n, 0.0, se * sigma.y);
  EXPECT_NEAR(st / n, 0.0, se * sigma.theta);
  EXPECT_NEAR(std::sqrt(sxx / n), sigma.x, 0.03 * sigma.x);
  EXPECT_NEAR(std::sqrt(syy / n), sigma.y, 0.03 * sigma.y);
  EXPECT_NEAR(std::sqrt(stt / n), sigma.theta, 0.03 * sigma.theta);
  EXPECT_NEAR(sxy / n / (sigma.x * sigma.y), 0.0, 0.03);  // independent axes
}

TEST(MotionModel, PureSidewaysMotionHasLateralSlip) {
  OmniMotionModel model;
  const MotionSigma s = model.Sigma(Pose2(0, 1.0, 0));
  EXPECT_GT(s.y, s.x);  // slip grows along the direction of travel, forward or sideways
  EXPECT_GT(s.theta, model.noise().min_theta_rad);
}

TEST(MotionModel, ImuFusionPullsHeadingTowardsTheGyro) {
  OmniMotionModel model;
  double sigma = 0;
  const Pose2 fused = model.FuseImuYaw(Pose2(0.5, 0, 0.30), 0.20, &sigma);
  EXPECT_LT(fused.theta, 0.30);
  EXPECT_GT(fused.theta, 0.20);
  EXPECT_LT(sigma, model.Sigma(Pose2(0.5, 0, 0.30)).theta);
}

TEST(MotionModel, LogDensityIsTheSamplersDensity) {
  OmniMotionModel model;
  const Pose2 from(1.0, -2.0, 0.7), delta(0.3, 0.1, 0.2);
  const MotionSigma s = model.Sigma(delta);
  // At the mean: the peak of three independent Gaussians.
  const double peak = -std::log(s.x * s.y * s.theta) - 1.5 * std::log(2 * M_PI);
  EXPECT_NEAR(model.LogDensity(from, delta, from * delta), peak, 1e-9);
  // One sigma off on each axis of the increment (in `from`'s frame): 1.5 nats lower.
  const Pose2 off(delta.x + s.x, delta.y - s.y, delta.theta + s.theta);
  EXPECT_NEAR(model.LogDensity(from, delta, from * off), peak - 1.5, 1e-9);
  // The gyro narrows the heading: the density at the fused heading's peak is higher.
  double fused_sigma = 0;
  const Pose2 fused = model.FuseImuYaw(delta, 0.21, &fused_sigma);
  EXPECT_LT(fused_sigma, s.theta);
  EXPECT_GT(model.LogDensity(from, delta, from * fused, 0.21), peak);
}

// log N(x; mu, cov) + c for the proposal tests.
double LogGaussian(const Eigen::Vector3d& x, const Eigen::Vector3d& mu, const Eigen::Matrix3d& cov,
                   double c) {
  const Eigen::Vector3d e = x - mu;
  return c - 0.5 * e.dot(cov.inverse() * e) -
         0.5 * std::log(std::pow(2 * M_PI, 3) * cov.determinant());
}

Eigen::Matrix3d TestCovariance() {
  const Eigen::Vector3d sd(0.02, 0.015, 0.01);
  Eigen::Matrix3d corr;
  corr << 1.0, 0.5, 0.3, 0.5, 1.0, -0.2, 0.3, -0.2, 1.0;
  return sd.asDiagonal() * corr * sd.asDiagonal();
}

TEST(RbpfProposal, FitRecoversAGaussianTargetAndItsIntegral) {
  const Pose2 center(3.0, -1.0, 3.1);  // near +pi: the heading offsets must not wrap
  const Eigen::Vector3d mu_off(0.005, -0.003, 0.004);
  const Eigen::Matrix3d cov = TestCovariance();
  const double c = -7.5;  // log of the target's integral
  ProposalGridOptions o;
  o.steps = 6;  // +-3 sigma at 0.5 sigma spacing
  o.step_xy_m = 0.01;
  o.step_theta_rad = 0.005;
  const GaussianProposal g = FitGaussianProposal(center, o, [&](const Pose2& x) {
    const Eigen::Vector3d d(x.x - center.x, x.y - center.y, WrapAngle(x.theta - center.theta));
    return LogGaussian(d, mu_off, cov, c);
  });
  EXPECT_EQ(g.points, 13 * 13 * 13);
  EXPECT_NEAR(g.mean.x, center.x + mu_off.x(), 1e-3);
  EXPECT_NEAR(g.mean.y, center.y + mu_off.y(), 1e-3);
  EXPECT_NEAR(WrapAngle(g.mean.theta - center.theta), mu_off.z(), 1e-3);
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(g.cov(r, k), cov(r, k), 0.1 * std::sqrt(cov(r, r) * cov(k, k))) << r << k;
  // The normaliser is the sum times the volume per point: the target's integral.
  EXPECT_NEAR(g.log_normalizer, c, 0.05);
}

TEST(RbpfProposal, DrawnPosesHaveTheFittedMeanAndCovariance) {
  GaussianProposal g;
  g.mean = Pose2(1.0, 2.0, -3.13);  // draws cross -pi and wrap
  g.cov = TestCovariance();
  std::mt19937_64 rng(5);
  const int n = 40000;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sq = Eigen::Matrix3d::Zero();
  for (int i = 0; i < n; ++i) {
    const Pose2 p = DrawPose(g, rng);
    ASSERT_LE(std::abs(p.theta), M_PI);
    const Eigen::Vector3d d(p.x - g.mean.x, p.y - g.mean.y, WrapAngle(p.theta - g.mean.theta));
    sum += d;
    sq += d * d.transpose();
  }
  const Eigen::Vector3d mean = sum / n;
  const Eigen::Matrix3d cov = sq / n - mean * mean.transpose();
  for (int r = 0; r < 3; ++r) {
    EXPECT_NEAR(mean(r), 0.0, 4 * std::sqrt(g.cov(r, r) / n)) << r;
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(cov(r, k), g.cov(r, k), 0.04 * std::sqrt(g.cov(r, r) * g.cov(k, k))) << r << k;
  }
  // A degenerate fit (one point) draws its mean.
  GaussianProposal point;
  point.mean = Pose2(1, 2, 3);
  const Pose2 p = DrawPose(point, rng);
  EXPECT_NEAR(p.x, 1.0, 1e-6);
  EXPECT_NEAR(p.theta, 3.0, 1e-6);
}

TEST(Resampling, EffectiveSampleSize) {
  EXPECT_NEAR(EffectiveSampleSize(std::vector<double>(10, 0.1)), 10.0, 1e-9);
  EXPECT_NEAR(EffectiveSampleSize({1.0, 0, 0, 0}), 1.0, 1e-12);
  EXPECT_NEAR(EffectiveSampleSize({0.5, 0.5, 0, 0}), 2.0, 1e-12);
}

TEST(Resampling, LowVarianceIsUnbiasedAndLowVariance) {
  const std::vector<double> w = {0.05, 0.40, 0.15, 0.0, 0.30, 0.10};
  const int n = 20;
  std::mt19937_64 rng(3);
  std::vector<double> mean_count(w.size(), 0.0);
  const int trials = 20000;
  for (int t = 0; t < trials; ++t) {
    std::vector<int> count(w.size(), 0);
    for (int i : LowVarianceResample(w, n, rng)) ++count[static_cast<size_t>(i)];
    for (size_t i = 0; i < w.size(); ++i) {
      // Systematic resampling: each count is floor or ceil of n * w.
      EXPECT_GE(count[i], static_cast<int>(std::floor(n * w[i] - 1e-9)));
      EXPECT_LE(count[i], static_cast<int>(std::ceil(n * w[i] + 1e-9)));
      mean_count[i] += count[i];
    }
  }
  for (size_t i = 0; i < w.size(); ++i) EXPECT_NEAR(mean_count[i] / trials, n * w[i], 0.02);
  EXPECT_EQ(mean_count[3], 0.0);  // a zero weight is never drawn
}

TEST(TiledGrid, CopiesOnlyTheTileThatIsWritten) {
  TiledGrid a;
  // Write cells in three different tiles.
  const int64_t s = TiledGrid::kTileSize;
  a.Update(1, 1, 1.0f);
  a.Update(s + 1, 1, 1.0f);
  a.Update(1, s + 1, 1.0f);
  ASSERT_EQ(a.num_tiles(), 3u);
  TiledGrid b = a;  // a particle copy: shares every tile
  EXPECT_TRUE(a.SharesTileWith(b, 0, 0));
  EXPECT_TRUE(a.SharesTileWith(b, 1, 0));
  EXPECT_TRUE(a.SharesTileWith(b, 0, 1));
  EXPECT_EQ(a.num_unique_tiles(), 0u);
  b.Update(2, 2, 2.0f);  // tile (0, 0)
  EXPECT_FALSE(a.SharesTileWith(b, 0, 0));
  EXPECT_TRUE(a.SharesTileWith(b, 1, 0));
  EXPECT_TRUE(a.SharesTileWith(b, 0, 1));
  EXPECT_EQ(b.num_unique_tiles(), 1u);
  EXPECT_FLOAT_EQ(a.LogOdds(2, 2), 0.0f);  // the original is untouched
  EXPECT_FLOAT_EQ(b.LogOdds(2, 2), 2.0f);
  EXPECT_FLOAT_EQ(b.LogOdds(1, 1), 1.0f);  // the copy carries the old contents
  b.Update(3, 3, 1.0f);                    // sole owner now: no further copy
  EXPECT_EQ(b.num_unique_tiles(), 1u);
  // Negative coordinates and growth keep working.
  b.Update(-5 * s, -3 * s, 1.0f);
  EXPECT_FLOAT_EQ(b.LogOdds(-5 * s, -3 * s), 1.0f);
  EXPECT_FLOAT_EQ(b.LogOdds(2, 2), 2.0f);
  EXPECT_TRUE(a.SharesTileWith(b, 1, 0));
}

// Log odds are integers in thousandths: the configured increments add up exactly, so a cell
// that sums to a threshold is on the documented side of it.
TEST(TiledGrid, LogOddsAreExactThousandths) {
  TiledGrid g;  // hit 0.85, miss -0.4, clamp [-2, 3.5], occupied > 0.5, free < -0.3
  for (int i = 0; i < 2; ++i) g.Update(0, 0, g.options().hit_log_odds);
  for (int i = 0; i < 3; ++i) g.Update(0, 0, g.options().miss_log_odds);
  EXPECT_EQ(g.LogOdds(0, 0), 0.5f);  // 1.7 - 1.2: exactly the threshold
  EXPECT_FALSE(g.Occupied(0, 0));    // "above" the threshold only
  g.Update(0, 0, g.options().hit_log_odds);
  EXPECT_EQ(g.LogOdds(0, 0), 1.35f);
  EXPECT_TRUE(g.Occupied(0, 0));
  for (int i = 0; i < 10; ++i) g.Update(1, 0, g.options().hit_log_odds);
  EXPECT_EQ(g.LogOdds(1, 0), 3.5f);  // clamped
  for (int i = 0; i < 10; ++i) g.Update(2, 0, g.options().miss_log_odds);
  EXPECT_EQ(g.LogOdds(2, 0), -2.0f);
  EXPECT_TRUE(g.Free(2, 0));
  // A cell observed to exactly even odds still reads as observed, not unknown.
  GridOptions even;
  even.hit_log_odds = 0.4f;
  TiledGrid h(even);
  h.Update(5, 5, 0.4f);
  h.Update(5, 5, -0.4f);
  EXPECT_NE(h.LogOdds(5, 5), 0.f);
  EXPECT_EQ(h.ToGridMap().at(0, 0), 50);
  // Increments finer than the unit are rounded to it.
  h.Update(6, 6, 0.0014f);
  EXPECT_EQ(h.LogOdds(6, 6), 0.001f);
  h.Update(7, 7, 0.0016f);
  EXPECT_EQ(h.LogOdds(7, 7), 0.002f);
  // A cell that reaches even odds by a hit is just above it (it can still become occupied).
  GridOptions fine;
  fine.hit_log_odds = 0.001f;
  fine.miss_log_odds = -0.001f;
  fine.occupied_threshold = 0.001f;
  TiledGrid f(fine);
  f.Update(0, 0, -0.001f);
  f.Update(0, 0, 0.001f);
  EXPECT_EQ(f.LogOdds(0, 0), 0.001f);
  f.Update(0, 0, 0.001f);
  EXPECT_TRUE(f.Occupied(0, 0));  // with -1 at even odds it would stay at -1 for ever
  // The matcher's bit masks (what Occupied(), Free() and Known() read) follow the log odds.
  for (int64_t cx = 0; cx < 4; ++cx) {
    const TiledGrid::Tile* t = g.TileAt(0, 0);
    ASSERT_NE(t, nullptr);
    const float l = g.LogOdds(cx, 0);
    EXPECT_EQ(((t->occupied_bits[0] >> cx) & 1) != 0, l > g.options().occupied_threshold) << cx;
    EXPECT_EQ(((t->free_bits[0] >> cx) & 1) != 0, l < g.options().free_threshold) << cx;
    EXPECT_EQ(((t->known_bits[0] >> cx) & 1) != 0, l != 0.f) << cx;
    EXPECT_EQ(g.Occupied(cx, 0), l > g.options().occupied_threshold) << cx;
    EXPECT_EQ(g.Free(cx, 0), l < g.options().free_threshold) << cx;
    EXPECT_EQ(g.Known(cx, 0), cx < 3) << cx;  // cells 0-2 written above, 3 never
  }
  // The widest options: sums beyond int16 are clamped before they are stored.
  GridOptions wide;
  wide.hit_log_odds = 30.f;
  wide.max_log_odds = 30.f;
  wide.min_log_odds = -30.f;
  TiledGrid w(wide);
  for (int i = 0; i < 3; ++i) w.Update(0, 0, 30.f);
  EXPECT_EQ(w.LogOdds(0, 0), 30.f);
  for (int i = 0; i < 3; ++i) w.Update(0, 0, -30.f);
  EXPECT_EQ(w.LogOdds(0, 0), -30.f);
}

TEST(TiledGrid, IntegrateScanMarksFreeAndOccupied) {
  TiledGrid g;
  std::vector<Eigen::Vector2d> pts = {{2.0, 0.0}, {0.0, 1.0}};
  g.IntegrateScan(Pose2(0.02, 0.02, 0), pts, {1, 0});
  EXPECT_TRUE(g.Occupied(g.CellX(2.02), g.CellY(0.02)));
  EXPECT_TRUE(g.Free(g.CellX(1.0), g.CellY(0.02)) || g.LogOdds(g.CellX(1.0), g.CellY(0.02)) < 0);
  EXPECT_LT(g.LogOdds(g.CellX(0.02), g.CellY(0.5)), 0.f);  // no-return beam: free only
  EXPECT_FALSE(g.Occupied(g.CellX(0.02), g.CellY(1.02)));
  const io::GridMap m = g.ToGridMap();
  EXPECT_GT(m.width, 30);
}

// Scans of the corrected Intel log: FLASER poses are the corrected poses.
struct CorrectedScan {
  Pose2 pose;
  std::vector<Eigen::Vector2d> points;
  std::vector<uint8_t> hit;
};

std::vector<CorrectedScan> LoadCorrected(const std::string& path, size_t count) {
  std::vector<CorrectedScan> out;
  auto log = io::ReadCarmenLog(path);
  if (!log.ok()) return out;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    CorrectedScan s;
    s.pose = r.laser.laser_pose;
    for (size_t i = 0; i < r.laser.ranges_m.size(); ++i) {
      const double a = r.laser.angle_min_rad + i * r.laser.angle_increment_rad;
      const double range = r.laser.ranges_m[i];
      if (!(range > 0 && range < r.laser.max_range_m)) continue;
      s.points.emplace_back(range * std::cos(a), range * std::sin(a));
      s.hit.push_back(1);
    }
    out.push_back(std::move(s));
    if (out.size() >= count) break;
  }
  return out;
}

// The packed form on runs of every length class (1, 127, 128 and the whole tile) and the
// extreme values, without a dataset: a tile written cell by cell, packed once idle, reads back.
TEST(TiledGrid, PackedRunsOfEveryLengthReadBack) {
  GridOptions o;
  o.hit_log_odds = 30.f;
  o.miss_log_odds = -30.f;
  o.max_log_odds = 30.f;
  o.min_log_odds = -30.f;
  o.pack_idle_scans = 2;
  const int64_t n = TiledGrid::kTileSize;
  // Tile (0, 0): runs of 1, 127, 128, then runs of 5 of varied values; tile (1, 0): one value;
  // tile (2, 0): every cell different from its neighbour (packs no smaller: stays unpacked).
  TiledGrid g(o);
  std::vector<float> want(static_cast<size_t>(3 * n * n), 0.f);
  auto set = [&](int64_t cx, int64_t cy, float v) {
    g.Update(cx, cy, v - g.LogOdds(cx, cy));
    want[static_cast<size_t>(cy * 3 * n + cx)] = g.LogOdds(cx, cy);
  };
  int64_t k = 0;
  for (int64_t len : {1, 127, 128, 1, 2, 300}) {
    const float v = (k % 2 == 0) ? 30.f : -30.f;
    for (int64_t j = 0; j < len; ++j, ++k) set(k % n, k / n, v);
  }
  for (; k < n * n; ++k) set(k % n, k / n, 0.001f * static_cast<float>((k / 5) % 997 + 1));
  for (int64_t c = 0; c < n * n; ++c) set(n + c % n, c / n, -0.5f);
  for (int64_t c = 0; c < n * n; ++c)
    set(2 * n + c % n, c / n, (c % 2 ? 1.f : -1.f) * (c + 1) / 1000.f);
  for (int i = 0; i < 3; ++i) g.IntegrateScan(Pose2(), {}, {});  // idle for three scans
  EXPECT_EQ(g.PackIdleTiles(), 2u);
  EXPECT_TRUE(g.TileAt(0, 0)->is_packed());
  EXPECT_TRUE(g.TileAt(1, 0)->is_packed());
  EXPECT_FALSE(g.TileAt(2, 0)->is_packed());
  EXPECT_LT(g.TileAt(1, 0)->bytes(), g.TileAt(2, 0)->bytes() / 5);
  for (int64_t cy = 0; cy < n; ++cy)
    for (int64_t cx = 0; cx < 3 * n; ++cx)
      ASSERT_EQ(g.LogOdds(cx, cy), want[static_cast<size_t>(cy * 3 * n + cx)]) << cx << " " << cy;
}

// A tile not written for pack_idle_scans scans is packed (run-length coded) and everything
// reads the same: the Intel lab's corrected scans into a packing grid and a grid that never
// packs, compared cell by cell after each scan; a write unpacks; a tile another grid shares is
// not packed.
TEST(TiledGrid, IdleTilesArePackedAndReadTheSame) {
  OMNI_REQUIRE_DATASET(path, "carmen-corrected/intel-corrected.log.gz");
  const auto scans = LoadCorrected(path, 300);
  ASSERT_EQ(scans.size(), 300u);
  GridOptions packing, plain;
  packing.pack_idle_scans = 3;
  plain.pack_idle_scans = 0;
  TiledGrid g(packing), ref(plain);
  size_t most_packed = 0;
  // The maps and the matcher's bits; `exact`: each cell's log odds too (slow: each read of a
  // packed cell unpacks its tile).
  auto same_everywhere = [&](const TiledGrid& a, const TiledGrid& b, bool exact) {
    const io::GridMap ma = a.ToGridMap(), mb = b.ToGridMap();
    if (ma.width != mb.width || ma.height != mb.height || ma.origin_x_m != mb.origin_x_m ||
        ma.origin_y_m != mb.origin_y_m || ma.cells != mb.cells)
      return ::testing::AssertionFailure() << "maps differ";
    const int64_t x0 = b.CellX(ma.origin_x_m + 1e-9), y0 = b.CellY(ma.origin_y_m + 1e-9);
    for (int64_t y = y0 - 1; y <= y0 + mb.height; ++y)
      for (int64_t x = x0 - 1; x <= x0 + mb.width; ++x)
        if (a.Occupied(x, y) != b.Occupied(x, y) || a.Free(x, y) != b.Free(x, y) ||
            a.Known(x, y) != b.Known(x, y) ||
            (exact &&
             (a.LogOdds(x, y) != b.LogOdds(x, y) || a.Known(x, y) != (b.LogOdds(x, y) != 0.f))))
          return ::testing::AssertionFailure() << "cell " << x << " " << y;
    return ::testing::AssertionSuccess();
  };
  for (size_t i = 0; i < scans.size(); ++i) {
    g.IntegrateScan(scans[i].pose, scans[i].points, scans[i].hit);
    ref.IntegrateScan(scans[i].pose, scans[i].points, scans[i].hit);
    most_packed = std::max(most_packed, g.num_packed_tiles());
    // Only idle tiles are packed: every tile this scan wrote an end point into is not.
    for (const Eigen::Vector2d& pt : scans[i].points) {
      const Eigen::Vector2d w = scans[i].pose.Transform(pt);
      const TiledGrid::Tile* t =
          g.TileAt(g.CellX(w.x()) >> TiledGrid::kTileBits, g.CellY(w.y()) >> TiledGrid::kTileBits);
      ASSERT_TRUE(t != nullptr && !t->is_packed()) << "scan " << i;
    }
    if (i % 50 == 49) {
      ASSERT_TRUE(same_everywhere(g, ref, i + 1 == scans.size())) << "after scan " << i;
    }
  }
  EXPECT_EQ(ref.num_packed_tiles(), 0u);
  ASSERT_GT(most_packed, 5u);
  ASSERT_GT(g.num_packed_tiles(), 0u);
  // Packed tiles hold a fraction of the memory.
  std::vector<const TiledGrid::Tile*> tg, tr;
  g.CollectTiles(&tg);
  ref.CollectTiles(&tr);
  size_t bytes_g = 0, bytes_r = 0;
  for (const auto* t : tg) bytes_g += t->bytes();
  for (const auto* t : tr) bytes_r += t->bytes();
  EXPECT_LT(bytes_g, bytes_r * 3 / 4) << bytes_g << " " << bytes_r;
  // A write into a packed tile unpacks it with its contents.
  int64_t ptx = 0, pty = 0;
  bool found = false;
  for (int64_t ty = -40; ty < 40 && !found; ++ty)
    for (int64_t tx = -40; tx < 40 && !found; ++tx)
      if (const TiledGrid::Tile* t = g.TileAt(tx, ty); t && t->is_packed()) {
        ptx = tx;
        pty = ty;
        found = true;
      }
  ASSERT_TRUE(found);
  const int64_t cx = ptx * TiledGrid::kTileSize + 7, cy = pty * TiledGrid::kTileSize + 9;
  const size_t packed_before = g.num_packed_tiles();
  g.Update(cx, cy, 0.85f);
  ref.Update(cx, cy, 0.85f);
  EXPECT_FALSE(g.TileAt(ptx, pty)->is_packed());
  EXPECT_EQ(g.num_packed_tiles(), packed_before - 1);
  EXPECT_EQ(g.LogOdds(cx, cy), ref.LogOdds(cx, cy));
  EXPECT_TRUE(same_everywhere(g, ref, false));
  // A grid that shares its tiles (a resampled particle's copy) keeps them unpacked while shared;
  // once the copy is gone they pack.
  TiledGrid fresh(packing);
  for (size_t i = 0; i < 20; ++i) fresh.IntegrateScan(scans[i].pose, scans[i].points, scans[i].hit);
  const size_t packed_alone = fresh.num_packed_tiles();
  {
    TiledGrid copy = fresh;
    for (size_t i = 20; i < 60; ++i)
      fresh.IntegrateScan(scans[i].pose, scans[i].points, scans[i].hit);
    fresh.PackIdleTiles();  // whatever fresh holds alone and is idle
    EXPECT_EQ(fresh.PackIdleTiles(), 0u);
    size_t copy_packed = 0, shared_unpacked = 0;
    std::vector<const TiledGrid::Tile*> held;
    copy.CollectTiles(&held);
    for (const auto* t : held) copy_packed += t->is_packed();
    EXPECT_EQ(copy_packed, packed_alone);  // only what was packed before the copy
    for (int64_t ty = -40; ty < 40; ++ty)
      for (int64_t tx = -40; tx < 40; ++tx)
        if (fresh.SharesTileWith(copy, tx, ty) && !fresh.TileAt(tx, ty)->is_packed())
          ++shared_unpacked;  // idle for 40 scans, but shared
    EXPECT_GT(shared_unpacked, 0u);
  }
  EXPECT_GT(fresh.PackIdleTiles(), 0u);  // now held alone
  EXPECT_EQ(fresh.PackIdleTiles(), 0u);
  TiledGrid never(plain);
  never.IntegrateScan(scans[0].pose, scans[0].points, scans[0].hit);
  for (int i = 0; i < 10; ++i) never.IntegrateScan(scans[299].pose, {}, {});
  EXPECT_EQ(never.PackIdleTiles(), 0u);  // pack_idle_scans 0: never
}

namespace {
bool SamePoses(const std::vector<Pose2>& a, const std::vector<Pose2>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (a[i].x != b[i].x || a[i].y != b[i].y || a[i].theta != b[i].theta) return false;
  return true;
}
Pose2 Numbered(int i) { return Pose2(i, -i, 0.001 * i); }
}  // namespace

TEST(ParticlePath, CopiesShareTheirPastAndGoOnApart) {
  ParticlePath a;
  EXPECT_EQ(a.Last(), nullptr);
  std::vector<Pose2> expect_a;
  for (int i = 0; i < 10; ++i) {
    a.Append(Numbered(i));
    expect_a.push_back(Numbered(i));
  }
  EXPECT_EQ(a.segments(), 1u);  // a sole owner appends in place
  ParticlePath b = a;           // a resampling's child
  EXPECT_TRUE(a.SameAs(b));
  b.Append(Numbered(100));
  EXPECT_FALSE(a.SameAs(b));
  EXPECT_EQ(b.segments(), 2u);  // the shared segment is not written
  EXPECT_TRUE(SamePoses(a.Poses(), expect_a));
  a.Append(Numbered(200));  // a's segment is b's parent now: a goes on in its own
  EXPECT_EQ(a.segments(), 2u);
  std::vector<Pose2> expect_b = expect_a;
  expect_b.push_back(Numbered(100));
  expect_a.push_back(Numbered(200));
  EXPECT_TRUE(SamePoses(a.Poses(), expect_a));
  EXPECT_TRUE(SamePoses(b.Poses(), expect_b));
  ASSERT_NE(b.BeforeLast(), nullptr);  // across the segment boundary
  EXPECT_EQ(b.BeforeLast()->x, 9.0);
  EXPECT_EQ(b.Last()->x, 100.0);
  EXPECT_EQ(b.size(), 11u);
  {
    ParticlePath c = b;  // a copy that dies before b moves: b still appends in place
    c.Append(Numbered(300));
  }
  b.Append(Numbered(101));
  EXPECT_EQ(b.segments(), 2u);
  // A long path is cut into segments of kMaxSegment poses, in order.
  ParticlePath d;
  std::vector<Pose2> expect_d;
  const int n = static_cast<int>(ParticlePath::kMaxSegment) * 2 + 5;
  for (int i = 0; i < n; ++i) {
    d.Append(Numbered(i));
    expect_d.push_back(Numbered(i));
  }
  EXPECT_EQ(d.segments(), 3u);
  EXPECT_TRUE(SamePoses(d.Poses(), expect_d));
  d.Freeze();
  EXPECT_TRUE(SamePoses(d.Poses(), expect_d));
  ParticlePath e = std::move(d);
  EXPECT_TRUE(SamePoses(e.Poses(), expect_d));
  EXPECT_EQ(d.size(), 0u);  // NOLINT(bugprone-use-after-move): a moved-from path is empty
  d.Append(Numbered(7));
  EXPECT_TRUE(SamePoses(d.Poses(), {Numbered(7)}));
  EXPECT_EQ(d.segments(), 1u);
}

// Thirty particles appending on two threads between resamplings, against plain copied vectors;
// then a path with a resampling after every update (one segment per update) is released
// without recursing down the chain.
TEST(ParticlePath, ParallelAppendsBetweenResamplingsKeepEveryPath) {
  constexpr int kParticles = 30;
  std::vector<ParticlePath> paths(kParticles);
  std::vector<std::vector<Pose2>> expect(kParticles);
  ThreadPool pool(2);
  std::mt19937_64 rng(7);
  int k = 0;
  for (int round = 0; round < 400; ++round) {
    pool.ParallelFor(kParticles, [&](int i) {
      const Pose2 p = Numbered(round * kParticles + i);
      paths[static_cast<size_t>(i)].Append(p);
      expect[static_cast<size_t>(i)].push_back(p);
    });
    if (round % 7 == 3) {  // resample: random parents, some picked several times
      std::uniform_int_distribution<int> pick(0, kParticles / 3);
      std::vector<ParticlePath> next;
      std::vector<std::vector<Pose2>> next_expect;
      for (int j = 0; j < kParticles; ++j) {
        const int src = pick(rng);
        paths[static_cast<size_t>(src)].Freeze();
        next.push_back(paths[static_cast<size_t>(src)]);
        next_expect.push_back(expect[static_cast<size_t>(src)]);
      }
      paths = std::move(next);
      expect = std::move(next_expect);
      ++k;
    }
  }
  ASSERT_GT(k, 50);
  for (int i = 0; i < kParticles; ++i) {
    EXPECT_TRUE(SamePoses(paths[static_cast<size_t>(i)].Poses(), expect[static_cast<size_t>(i)]))
        << i;
    EXPECT_EQ(paths[static_cast<size_t>(i)].size(), 400u);
  }
  ParticlePath chain;
  for (int i = 0; i < 300000; ++i) {
    ParticlePath sibling = chain;  // shared at every update: each append opens a segment
    chain.Append(Numbered(i));
  }
  EXPECT_EQ(chain.segments(), 300000u);
  chain = ParticlePath();  // would overflow the stack if released recursively
}

TEST(ScanMatcher, RecoversAKnownOffsetBetweenTwoCorrectedScans) {
  OMNI_REQUIRE_DATASET(path, "carmen-corrected/intel-corrected.log.gz");
  const auto scans = LoadCorrected(path, 40);
  ASSERT_GE(scans.size(), 40u);
  MatcherOptions mo;
  ScanMatcher matcher(mo);
  int checked = 0;
  // Consecutive scans (pairs that are not corridor-degenerate: along a bare corridor a single
  // scan cannot fix the position along it).
  for (size_t a : {5u, 15u, 20u, 25u, 35u}) {
    const size_t b = a + 1;
    TiledGrid grid;
    grid.IntegrateScan(scans[a].pose, scans[a].points, scans[a].hit);
    const MatchScan ms = MakeMatchScan(scans[b].points, scans[b].hit, Pose2(), 0.05, mo);
    const Pose2 truth = scans[b].pose;
    for (const Pose2& off : {Pose2(0.15, -0.10, 0.05), Pose2(-0.2, 0.1, -0.08)}) {
      const Pose2 start(truth.x + off.x, truth.y + off.y, WrapAngle(truth.theta + off.theta));
      const MatchResult m = matcher.Match(grid, start, ms);
      ++checked;
      EXPECT_TRUE(m.ok) << "scan " << a << " -> " << b;
      EXPECT_NEAR(m.pose.x, truth.x, 0.05) << "scan " << a << " -> " << b;
      EXPECT_NEAR(m.pose.y, truth.y, 0.05) << "scan " << a << " -> " << b;
      EXPECT_NEAR(WrapAngle(m.pose.theta - truth.theta), 0.0, 0.02) << "scan " << a;
      // The matched pose explains the scan better than the offset start.
      EXPECT_GT(m.score.score, matcher.Score(grid, start, ms).score);
    }
  }
  EXPECT_EQ(checked, 10);
}

// A closed room of straight walls at angles off the grid axes, and a 360-beam scan of it from a
// pose (exact ranges): ground truth for matcher precision, which real logs cannot give below
// the jitter of their reference poses.
struct Room {
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls;
  Room() {
    const std::vector<Eigen::Vector2d> c = {{-3.1, -2.3}, {3.4, -2.9}, {4.2, 1.7}, {1.3, 2.6},
                                            {0.9, 4.1},   {-2.7, 3.3}, {-3.6, 0.4}};
    for (size_t i = 0; i < c.size(); ++i) walls.emplace_back(c[i], c[(i + 1) % c.size()]);
  }
  void Scan(const Pose2& p, std::vector<Eigen::Vector2d>* pts, std::vector<uint8_t>* hit) const {
    pts->clear();
    hit->clear();
    for (int b = 0; b < 360; ++b) {
      const double a = -M_PI + b * (2 * M_PI / 360);
      const Eigen::Vector2d d(std::cos(p.theta + a), std::sin(p.theta + a)), o(p.x, p.y);
      double best = 1e9;
      for (const auto& w : walls) {
        const Eigen::Vector2d e = w.second - w.first;
        const double den = d.x() * e.y() - d.y() * e.x();
        if (std::abs(den) < 1e-12) continue;
        const Eigen::Vector2d q = w.first - o;
        const double t = (q.x() * e.y() - q.y() * e.x()) / den;
        const double u = (q.x() * d.y() - q.y() * d.x()) / den;
        if (t > 0 && u >= 0 && u <= 1) best = std::min(best, t);
      }
      pts->emplace_back(best * std::cos(a), best * std::sin(a));
      hit->push_back(1);
    }
  }
};

TEST(ScanMatcher, IsSubCentimetreOnAnExactRoomDespiteTheFiveCentimetreGrid) {
  // Ground truth below the reference logs' own jitter: map a room of off-axis walls from a few
  // poses, then match scans from other poses starting a few centimetres off. The beam score
  // measures distances to cell centres, but averaged over 360 beams the quantisation cancels.
  const Room room;
  MatcherOptions mo;
  ScanMatcher matcher(mo);
  std::vector<Eigen::Vector2d> pts;
  std::vector<uint8_t> hit;
  TiledGrid grid;
  for (const Pose2& p : {Pose2(0, 0, 0), Pose2(0.5, 0.2, 0.3), Pose2(-1.0, 0.5, -0.4),
                         Pose2(1.5, -0.8, 1.0), Pose2(-0.4, 1.6, 2.0)}) {
    room.Scan(p, &pts, &hit);
    grid.IntegrateScan(p, pts, hit);
  }
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  double sq = 0, sqt = 0, sq_start = 0;
  const int n = 30;
  for (int k = 0; k < n; ++k) {
    const Pose2 truth(0.8 * u(rng), 0.6 * u(rng), M_PI * u(rng));
    room.Scan(truth, &pts, &hit);
    const MatchScan ms = MakeMatchScan(pts, hit, Pose2(), grid.resolution(), mo);
    const Pose2 start(truth.x + 0.04 * u(rng), truth.y + 0.04 * u(rng),
                      truth.theta + 0.02 * u(rng));
    const MatchResult m = matcher.Match(grid, start, ms);
    EXPECT_TRUE(m.ok);
    sq += std::pow(m.pose.x - truth.x, 2) + std::pow(m.pose.y - truth.y, 2);
    sq_start += std::pow(start.x - truth.x, 2) + std::pow(start.y - truth.y, 2);
    sqt += std::pow(WrapAngle(m.pose.theta - truth.theta), 2);
  }
  const double rms = std::sqrt(sq / n), rms_t = std::sqrt(sqt / n);
  RecordProperty("rms_xy_m", std::to_string(rms));
  RecordProperty("rms_theta_rad", std::to_string(rms_t));
  EXPECT_LT(rms, 0.01) << "start error " << std::sqrt(sq_start / n);  // measured 4.1 mm
  EXPECT_LT(rms_t, 0.004);                                            // measured 1.75 mrad
}

TEST(ScanMatcher, GaussianProposalDrawsAroundTheMatchAndWeighsByTheNormaliser) {
  OMNI_REQUIRE_DATASET(path, "carmen-corrected/intel-corrected.log.gz");
  const auto scans = LoadCorrected(path, 40);
  ASSERT_GE(scans.size(), 40u);
  MatcherOptions mo;
  ScanMatcher matcher(mo);
  OmniMotionModel motion;
  const CorrectedScan &a = scans[20], &b = scans[21];
  TiledGrid grid;
  grid.IntegrateScan(a.pose, a.points, a.hit);
  const MatchScan ms = MakeMatchScan(b.points, b.hit, Pose2(), 0.05, mo);
  const Pose2 delta = a.pose.Between(b.pose);
  const Pose2 start(b.pose.x + 0.1, b.pose.y - 0.05, WrapAngle(b.pose.theta + 0.03));
  const MatchResult m = matcher.Match(grid, start, ms);
  ASSERT_TRUE(m.ok);
  const double gain = 0.33;
  ProposalGridOptions o;  // 27 points, 1 cm / 0.005 rad apart
  std::mt19937_64 rng(3);
  const ProposalDraw d = DrawImprovedProposal(matcher, motion, grid, ms, a.pose, delta,
                                              std::nullopt, m.pose, gain, o, rng);
  EXPECT_EQ(d.gaussian.points, 27);
  // The weight is eta = sum_k likelihood^gain * prior (times the volume per point).
  double eta = 0;
  for (int ix = -1; ix <= 1; ++ix)
    for (int iy = -1; iy <= 1; ++iy)
      for (int it = -1; it <= 1; ++it) {
        const Pose2 x(m.pose.x + 0.01 * ix, m.pose.y + 0.01 * iy,
                      WrapAngle(m.pose.theta + 0.005 * it));
        eta += std::exp(gain * matcher.Score(grid, x, ms).log_likelihood +
                        motion.LogDensity(a.pose, delta, x));
      }
  EXPECT_NEAR(d.log_weight, std::log(eta * 0.01 * 0.01 * 0.005), 1e-9);
  EXPECT_EQ(d.log_weight, d.gaussian.log_normalizer);
  // The Gaussian sits on the optimum and is not a point: draws differ from the optimum and
  // from each other, within a few sigma of the mean.
  EXPECT_LT(std::hypot(d.gaussian.mean.x - m.pose.x, d.gaussian.mean.y - m.pose.y), 0.015);
  EXPECT_GT(d.gaussian.cov(0, 0), 1e-6);
  EXPECT_GT(d.gaussian.cov(2, 2), 1e-7);
  const ProposalDraw d2 = DrawImprovedProposal(matcher, motion, grid, ms, a.pose, delta,
                                               std::nullopt, m.pose, gain, o, rng);
  EXPECT_NE(d.pose.x, d2.pose.x);
  EXPECT_NE(d.pose.x, m.pose.x);
  EXPECT_LT(std::abs(d.pose.x - d.gaussian.mean.x), 5 * std::sqrt(d.gaussian.cov(0, 0)));
  EXPECT_EQ(d.log_weight, d2.log_weight);  // same points, same normaliser
  // A particle whose odometry disagrees with the match (its previous pose 4 sigma back along
  // the motion) gets a far smaller weight from the motion prior (by about 4^2 / 2 nats).
  const Pose2 off_from = a.pose * Pose2(-4 * motion.Sigma(delta).x, 0, 0);
  const ProposalDraw far = DrawImprovedProposal(matcher, motion, grid, ms, off_from, delta,
                                                std::nullopt, m.pose, gain, o, rng);
  EXPECT_LT(far.log_weight, d.log_weight - 5.0);
}

TEST(ThreadPool, RunsEveryItemOnce) {
  ThreadPool pool(3);
  std::vector<int> hits(1000, 0);
  for (int rep = 0; rep < 20; ++rep)
    pool.ParallelFor(1000, [&](int i) { ++hits[static_cast<size_t>(i)]; });
  for (int h : hits) EXPECT_EQ(h, 20);
}

ScanInput ToInput(const io::CarmenLaser& l) {
  ScanInput s;
  s.utime = SecondsToUtime(l.timestamp_s);
  s.sensor_in_base = l.robot_pose.Between(l.laser_pose);
  s.angle_min_rad = l.angle_min_rad;
  s.angle_increment_rad = l.angle_increment_rad;
  s.range_max_m = l.max_range_m;
  s.ranges_m = l.ranges_m;
  s.odom = l.robot_pose;
  return s;
}

struct PrefixRun {
  std::vector<EstimatedPose> trajectory;
  RbpfCounters counters;
  ResolutionChoice choice;
  double resolution_m = 0;
  double likelihood_gain = 0;
};

// `on_scan` (optional) sees the filter and AddScan's result after every scan.
PrefixRun RunPrefixWith(
    const std::string& path, size_t scans, const RbpfOptions& o,
    const std::function<void(const RbpfSlam&, const ScanResult&)>& on_scan = nullptr) {
  RbpfSlam slam(o);
  auto log = io::ReadCarmenLog(path);
  EXPECT_TRUE(log.ok());
  size_t n = 0;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    const ScanResult res = slam.AddScan(ToInput(r.laser));
    if (on_scan) on_scan(slam, res);
    if (++n >= scans) break;
  }
  return {slam.BestTrajectory(), slam.counters(), slam.resolution_choice(),
          slam.options().grid.resolution_m, slam.options().likelihood_gain};
}

void ExpectSameTrajectory(const std::vector<EstimatedPose>& a,
                          const std::vector<EstimatedPose>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].scan_index, b[i].scan_index);
    EXPECT_EQ(a[i].pose.x, b[i].pose.x) << i;
    EXPECT_EQ(a[i].pose.y, b[i].pose.y) << i;
    EXPECT_EQ(a[i].pose.theta, b[i].pose.theta) << i;
  }
}

std::vector<EstimatedPose> RunPrefix(const std::string& path, size_t scans, int threads,
                                     uint64_t seed, RbpfCounters* counters = nullptr,
                                     ProposalKind proposal = ProposalKind::kMatch) {
  RbpfOptions o;
  o.proposal = proposal;
  o.particles = 8;
  o.threads = threads;
  o.seed = seed;
  PrefixRun run = RunPrefixWith(path, scans, o);
  if (counters) *counters = run.counters;
  return std::move(run.trajectory);
}

TEST(RbpfSlam, SameSeedSameResultWhateverTheThreadCount) {
  OMNI_REQUIRE_DATASET(path, "slam-noisy-odom/intel.noisy.clf.gz");
  RbpfCounters c1;
  const auto a = RunPrefix(path, 80, 1, 7, &c1);
  const auto b = RunPrefix(path, 80, 2, 7);
  ASSERT_GT(a.size(), 70u);
  EXPECT_GT(c1.scans_processed, 20);
  ExpectSameTrajectory(a, b);
  const auto c = RunPrefix(path, 80, 2, 8);  // another seed: another sample path
  bool differs = false;
  for (size_t i = 0; i < std::min(a.size(), c.size()); ++i)
    differs |= a[i].pose.x != c[i].pose.x || a[i].pose.theta != c[i].pose.theta;
  EXPECT_TRUE(differs);
  // The Gaussian proposal draws from each particle's own RNG too: same result on 1 or 2
  // threads, and not the match proposal's path.
  const auto g1 = RunPrefix(path, 80, 1, 7, nullptr, ProposalKind::kGaussian);
  const auto g2 = RunPrefix(path, 80, 2, 7, nullptr, ProposalKind::kGaussian);
  ASSERT_EQ(g1.size(), g2.size());
  ASSERT_EQ(g1.size(), a.size());
  bool differs_from_match = false;
  for (size_t i = 0; i < g1.size(); ++i) {
    EXPECT_EQ(g1[i].pose.x, g2[i].pose.x) << i;
    EXPECT_EQ(g1[i].pose.theta, g2[i].pose.theta) << i;
    differs_from_match |= g1[i].pose.x != a[i].pose.x;
  }
  EXPECT_TRUE(differs_from_match);
}

// Intel noisy has one scan per 0.5-0.7 m: after the first 20 m the filter starts again on the
// coarse grid with the sparse likelihood gain, and the result is the run that had both from the
// first scan. (The default sparse gain is the dense one; a different one is set here to show
// that it is switched too.)
TEST(RbpfSlam, SparseScansAreMappedAgainOnTheCoarseGrid) {
  OMNI_REQUIRE_DATASET(path, "slam-noisy-odom/intel.noisy.clf.gz");
  RbpfOptions o;
  o.particles = 8;
  o.threads = 2;
  o.sparse_likelihood_gain = 0.33;
  ASSERT_EQ(o.grid.resolution_m, 0.025);
  const PrefixRun a = RunPrefixWith(path, 60, o);
  EXPECT_TRUE(a.choice.decided);
  EXPECT_TRUE(a.choice.switched);
  EXPECT_GE(a.choice.travel_m, 20.0);
  EXPECT_GT(a.choice.spacing_m(), 0.4);
  EXPECT_EQ(a.resolution_m, 0.05);
  EXPECT_EQ(a.likelihood_gain, o.sparse_likelihood_gain);
  ASSERT_NE(o.likelihood_gain, o.sparse_likelihood_gain);
  RbpfOptions coarse = o;
  coarse.grid.resolution_m = 0.05;
  coarse.likelihood_gain = o.sparse_likelihood_gain;
  coarse.sparse_scan_spacing_m = 0;  // no choice: 5 cm and the sparse gain throughout
  const PrefixRun b = RunPrefixWith(path, 60, coarse);
  EXPECT_FALSE(b.choice.switched);
  ExpectSameTrajectory(a.trajectory, b.trajectory);
  // The gain is part of the switch: 5 cm with the dense gain is another run.
  RbpfOptions coarse_dense_gain = coarse;
  coarse_dense_gain.likelihood_gain = o.likelihood_gain;
  const PrefixRun d = RunPrefixWith(path, 60, coarse_dense_gain);
  EXPECT_NE(d.counters.resamplings, b.counters.resamplings);
  // Counted once, as if the inputs had been seen once.
  EXPECT_EQ(a.counters.scans_in, 60);
  EXPECT_EQ(a.counters.scans_in, b.counters.scans_in);
  EXPECT_EQ(a.counters.scans_processed, b.counters.scans_processed);
  EXPECT_EQ(a.counters.resamplings, b.counters.resamplings);
  EXPECT_EQ(a.counters.odom_in, b.counters.odom_in);
}

// intel-raw has one scan per 0.26 m: the fine grid stays, nothing is run again.
TEST(RbpfSlam, DenseScansKeepTheFineGrid) {
  OMNI_REQUIRE_DATASET(path, "intel-raw/intel.clf");
  RbpfOptions o;
  o.particles = 8;
  o.threads = 2;
  const PrefixRun a = RunPrefixWith(path, 250, o);
  EXPECT_TRUE(a.choice.decided);
  EXPECT_FALSE(a.choice.switched);
  EXPECT_LT(a.choice.spacing_m(), 0.4);
  EXPECT_GT(a.choice.spacing_m(), 0.1);
  EXPECT_EQ(a.resolution_m, 0.025);
  EXPECT_EQ(a.likelihood_gain, o.likelihood_gain);
  RbpfOptions fixed = o;
  fixed.sparse_scan_spacing_m = 0;
  ExpectSameTrajectory(a.trajectory, RunPrefixWith(path, 250, fixed).trajectory);
}

// With flat weights the heaviest particle (by final_particle's weight, the whole ancestry's by
// default) changes often; the reported one (the pose AddScan returns, the process's POSE_RBPF)
// changes lineage only past report_switch_log_margin. The filter itself, and so the final
// trajectory, is the same whatever the margin.
TEST(RbpfSlam, TheReportedParticleChangesOnlyPastTheMargin) {
  OMNI_REQUIRE_DATASET(path, "intel-raw/intel.clf");
  auto run = [&](double margin) {
    RbpfOptions o;
    o.particles = 8;
    o.threads = 2;
    o.report_switch_log_margin = margin;
    return RunPrefixWith(path, 300, o, [](const RbpfSlam& slam, const ScanResult& res) {
      if (!res.processed) return;
      const Pose2& reported = slam.particles()[static_cast<size_t>(slam.reported_index())].pose;
      EXPECT_EQ(res.pose.x, reported.x);
      EXPECT_EQ(res.pose.theta, reported.theta);
    });
  };
  const PrefixRun a = run(0.0);
  const PrefixRun b = run(3.0);
  const int64_t always_best = a.counters.reported_switches;
  const int64_t sticky = b.counters.reported_switches;
  EXPECT_GT(always_best, 10);
  EXPECT_LT(sticky * 3, always_best) << sticky << " against " << always_best;
  ExpectSameTrajectory(a.trajectory, b.trajectory);
}

// With final_particle: ancestry the reported particle is judged by the same weight as the final
// one, the weight summed over its whole ancestry: after every update no particle's exceeds the
// reported one's by more than the margin, and with margin 0 the reported particle is the final.
TEST(RbpfSlam, TheReportedParticleFollowsTheWholePathsWeight) {
  OMNI_REQUIRE_DATASET(path, "intel-raw/intel.clf");
  for (const double margin : {0.0, 3.0}) {
    RbpfOptions o;
    o.particles = 8;
    o.threads = 2;
    o.report_switch_log_margin = margin;
    ASSERT_EQ(o.final_particle, FinalParticle::kAncestry);
    int updates = 0, behind = 0;
    const PrefixRun run =
        RunPrefixWith(path, 300, o, [&](const RbpfSlam& slam, const ScanResult& r) {
          if (!r.processed) return;
          ++updates;
          const auto& ps = slam.particles();
          const double reported = ps[static_cast<size_t>(slam.reported_index())].path_log_weight;
          const double top = ps[static_cast<size_t>(slam.final_index())].path_log_weight;
          EXPECT_LE(top - reported, margin + 1e-9) << r.scan_index;
          behind += top > reported;
          if (margin == 0.0) {
            EXPECT_EQ(top, reported) << r.scan_index;
          }
        });
    EXPECT_GT(updates, 50);
    EXPECT_GT(run.counters.reported_switches, 0);
    if (margin > 0) {
      EXPECT_GT(behind, 0);  // the margin holds a lineage some of the time
    }
  }
}

// After an update that resampled every weight is equal; the best particle is then the child of
// the update's heaviest, which is also the reported one when the margin is 0.
TEST(RbpfSlam, TheBestParticleSurvivesAResamplingAsItsChild) {
  OMNI_REQUIRE_DATASET(path, "intel-raw/intel.clf");
  RbpfOptions o;
  o.particles = 8;
  o.threads = 2;
  o.report_switch_log_margin = 0.0;
  o.resample_threshold = 1.0;  // resample after (nearly) every update
  o.final_particle = FinalParticle::kCurrent;
  int not_first = 0;
  ScanResult last;
  const PrefixRun run = RunPrefixWith(path, 150, o, [&](const RbpfSlam& slam, const ScanResult& r) {
    if (!r.processed) return;
    last = r;
    EXPECT_EQ(slam.best_index(), slam.reported_index()) << r.scan_index;
    const Pose2& best = slam.particles()[static_cast<size_t>(slam.best_index())].pose;
    EXPECT_EQ(best.x, r.pose.x) << r.scan_index;
    EXPECT_EQ(best.theta, r.pose.theta) << r.scan_index;
    not_first += slam.best_index() != 0;
  });
  EXPECT_GT(run.counters.resamplings, 20);
  // Particle 0 is the first parent's child, not the best's, in most updates.
  EXPECT_GT(not_first, 10);
  ASSERT_TRUE(last.processed);
  const EstimatedPose& end = run.trajectory.back();
  ASSERT_EQ(end.scan_index, last.scan_index);
  EXPECT_EQ(end.pose.x, last.pose.x);
  EXPECT_EQ(end.pose.theta, last.pose.theta);
}

// The final estimate is the particle whose whole ancestry weighs most: a resampling hands its
// path weight to every child, and without resamplings it is the heaviest since the start.
TEST(RbpfSlam, TheFinalParticleIsTheHeaviestOverItsWholeAncestry) {
  OMNI_REQUIRE_DATASET(path, "intel-raw/intel.clf");
  RbpfOptions o;
  o.particles = 8;
  o.threads = 2;
  o.resample_threshold = 0.0;  // never resample: both weights sum the same factors
  int updates = 0;
  RbpfSlam::PathMemory paths;
  RunPrefixWith(path, 80, o, [&](const RbpfSlam& slam, const ScanResult& r) {
    if (!r.processed) return;
    ++updates;
    EXPECT_EQ(slam.final_index(), slam.best_index()) << r.scan_index;
    paths = slam.path_memory();
  });
  EXPECT_GT(updates, 20);
  // Without resamplings every particle has its own path, one segment each.
  EXPECT_EQ(paths.poses, static_cast<size_t>(8 * updates));
  EXPECT_EQ(paths.segments, 8u);
  EXPECT_GE(paths.bytes, paths.poses * sizeof(Pose2));

  o.resample_threshold = 1.0;  // resample after (nearly) every update
  int differs = 0, sibling_pairs = 0;
  int64_t last_processed = -1;
  Pose2 final_pose;  // the final particle's pose after the last update
  RbpfSlam::PathMemory run_paths;
  int run_updates = 0;
  const PrefixRun run = RunPrefixWith(path, 150, o, [&](const RbpfSlam& slam, const ScanResult& r) {
    if (!r.processed) return;
    last_processed = r.scan_index;
    const auto& ps = slam.particles();
    double heaviest = -std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < ps.size(); ++i) {
      heaviest = std::max(heaviest, ps[i].path_log_weight);
      for (size_t j = i + 1; j < ps.size(); ++j)
        if (ps[i].log_weight == 0 && ps[i].path.SameAs(ps[j].path)) {  // children of one parent
          ++sibling_pairs;
          EXPECT_EQ(ps[i].path_log_weight, ps[j].path_log_weight) << r.scan_index;
        }
    }
    EXPECT_EQ(ps[static_cast<size_t>(slam.final_index())].path_log_weight, heaviest);
    differs += slam.final_index() != slam.best_index();
    final_pose = ps[static_cast<size_t>(slam.final_index())].pose;
    run_paths = slam.path_memory();
    ++run_updates;
  });
  EXPECT_GT(run.counters.resamplings, 20);
  EXPECT_GT(sibling_pairs, 5);
  // Resampled lineages share their past: fewer poses than particles x updates.
  EXPECT_LT(run_paths.poses, static_cast<size_t>(8 * run_updates));
  EXPECT_GE(run_paths.poses, static_cast<size_t>(run_updates));
  EXPECT_GT(differs, 5);  // the weight since the last resampling is one update's
  // The final trajectory is the final particle's path: its pose at the last update.
  ASSERT_GT(last_processed, 0);
  ASSERT_GT(run.trajectory.size(), static_cast<size_t>(last_processed));
  const EstimatedPose& at = run.trajectory[static_cast<size_t>(last_processed)];
  EXPECT_EQ(at.scan_index, last_processed);
  EXPECT_EQ(at.pose.x, final_pose.x);
  EXPECT_EQ(at.pose.theta, final_pose.theta);
}

// A base that never moves: the inputs held for the choice stop at kMaxPreludeScans, and the
// choice (no travel: dense) is made then.
TEST(RbpfSlam, TheHeldInputsAreBoundedWhenTheBaseStandsStill) {
  RbpfOptions o;
  o.particles = 2;
  o.threads = 1;
  RbpfSlam slam(o);
  int64_t t = 1000000;
  for (int64_t k = 0; k < RbpfSlam::kMaxPreludeScans; ++k, t += 100000) {
    EXPECT_FALSE(slam.resolution_choice().decided) << k;
    ScanInput s;
    s.utime = t;
    s.angle_min_rad = static_cast<float>(-M_PI / 2);
    s.angle_increment_rad = static_cast<float>(M_PI / 180);
    s.range_max_m = 20;
    s.ranges_m.assign(181, 3.f);
    s.odom = Pose2(0.001 * static_cast<double>(k % 2), 0, 0);  // jitter below 1 cm
    EXPECT_TRUE(slam.AddScan(s).accepted);
  }
  EXPECT_TRUE(slam.resolution_choice().decided);
  EXPECT_FALSE(slam.resolution_choice().switched);
  EXPECT_EQ(slam.resolution_choice().moving_scans, 0);
  EXPECT_EQ(slam.options().grid.resolution_m, 0.025);
  EXPECT_EQ(slam.counters().scans_in, RbpfSlam::kMaxPreludeScans);
}

// Odometry and no scans (a lidar that never came up): the held inputs stop at
// kMaxPreludeEvents too.
TEST(RbpfSlam, TheHeldInputsAreBoundedWithoutScans) {
  RbpfOptions o;
  o.particles = 2;
  o.threads = 1;
  RbpfSlam slam(o);
  for (size_t k = 0; k < RbpfSlam::kMaxPreludeEvents; ++k) {
    ASSERT_FALSE(slam.resolution_choice().decided) << k;
    ASSERT_TRUE(slam.AddOdometry(1000000 + 10000 * static_cast<int64_t>(k), Pose2(0, 0, 0)));
  }
  EXPECT_FALSE(slam.resolution_choice().decided);
  EXPECT_TRUE(slam.AddImuYawRate(1000000 + 10000 * 100001, 0.0));
  EXPECT_TRUE(slam.resolution_choice().decided);
  EXPECT_FALSE(slam.resolution_choice().switched);
  EXPECT_EQ(slam.counters().odom_in, static_cast<int64_t>(RbpfSlam::kMaxPreludeEvents));
  EXPECT_EQ(slam.counters().imu_in, 1);
}

// With use_imu the gyro's bias is learned while the odometry stands still (the estimator is
// omni/common/gyro_bias.h): 6 s parked, a gyro reading 0.004 rad/s at rest at 100 Hz, odometry
// at 50 Hz. 1 s chunks less 0.2 s at each end: five samples; without use_imu, none.
TEST(RbpfSlam, LearnsTheGyroBiasWhileTheOdometryStandsStill) {
  for (const bool use_imu : {true, false}) {
    SCOPED_TRACE(use_imu ? "use_imu" : "no imu");
    RbpfOptions o;
    o.particles = 2;
    o.threads = 1;
    o.use_imu = use_imu;
    o.imu_bias_rad_s = 0.001;
    RbpfSlam slam(o);
    for (int k = 0; k <= 600; ++k) {
      const int64_t t = 1'000'000 + 10'000 * int64_t{k};
      ASSERT_TRUE(slam.AddImuYawRate(t, 0.004));
      if (k % 2 == 0) {
        ASSERT_TRUE(slam.AddOdometry(t, Pose2(1, 2, 0.3)));
      }
    }
    EXPECT_EQ(slam.counters().imu_bias_samples, use_imu ? 5 : 0);
    EXPECT_EQ(slam.counters().imu_bias_refused, 0);
    EXPECT_NEAR(slam.imu_bias_rad_s(), use_imu ? 0.004 : 0.001, 1e-12);
  }
}

// A spinning lidar's sweep: the base turns at 0.8 rad/s in the off-axis room while each scan's
// beams are measured over 0.1 s (0.08 rad of turn). Told the sweep's duration, the filter undoes
// the turn from odometry and keeps the heading; told nothing, the distorted scans pull it off,
// against exact odometry.
TEST(RbpfSlam, UndoesTheLidarSweepFromOdometry) {
  const Room room;
  const double omega = 0.8, sweep_s = 0.1;
  const Pose2 mount(0.1, 0.0, 0.0);
  auto truth_at = [&](double t) { return Pose2(0.2, -0.1, omega * t); };
  double err[2];
  for (int told = 0; told < 2; ++told) {
    RbpfOptions o;
    o.particles = 1;  // the sweep correction alone, not which of several particles is best
    o.threads = 1;
    RbpfSlam slam(o);
    const int64_t t0 = 1700000000000000;
    for (int k = 0; k <= 400; ++k)  // odometry at 100 Hz for 4 s: exact
      slam.AddOdometry(t0 + k * 10000, truth_at(k * 0.01));
    for (int scan = 0; scan < 30; ++scan) {
      const double ts = scan * 0.12;
      ScanInput s;
      s.utime = t0 + std::llround(ts * 1e6);
      s.sensor_in_base = mount;
      s.angle_min_rad = static_cast<float>(-M_PI);
      s.angle_increment_rad = static_cast<float>(2 * M_PI / 360);
      s.range_max_m = 30.f;
      s.scan_time_s = told ? static_cast<float>(sweep_s * 359 / 360) : 0.f;
      std::vector<Eigen::Vector2d> pts;
      std::vector<uint8_t> hit;
      for (int b = 0; b < 360; ++b) {
        // Beam b from where the laser is at its time; its range as the laser saw it.
        const Pose2 laser = truth_at(ts + sweep_s * b / 360.0) * mount;
        room.Scan(laser, &pts, &hit);
        s.ranges_m.push_back(static_cast<float>(pts[static_cast<size_t>(b)].norm()));
      }
      slam.AddScan(s);
    }
    // The filter's frame starts at the first scan's pose (heading 0 here, as the truth's).
    const auto traj = slam.BestTrajectory();
    ASSERT_EQ(traj.size(), 30u);
    double worst = 0;
    for (size_t k = 0; k < traj.size(); ++k)
      worst = std::max(worst, std::abs(WrapAngle(traj[k].pose.theta - truth_at(k * 0.12).theta)));
    err[told] = worst;
    if (told) {
      EXPECT_GT(slam.counters().sweeps_corrected, 5);
      EXPECT_EQ(slam.counters().sweeps_uncorrected, 0);
    }
  }
  // Measured: 2.6 mrad undone, 32 mrad not (worst scan). (With 4 particles and the dense
  // stream's flat weights the reported particle is picked less sharply: 6.9 against 31 mrad.)
  EXPECT_LT(err[1], 0.005) << "sweep undone " << err[1] << " rad, not undone " << err[0];
  EXPECT_GT(err[0], 0.02) << "sweep undone " << err[1] << " rad, not undone " << err[0];
}

ScanInput SyntheticScan(int64_t utime, const Pose2& odom) {
  // A robot in a 10 m x 10 m square room centred on the origin, 180 beams.
  ScanInput s;
  s.utime = utime;
  s.odom = odom;
  s.angle_min_rad = static_cast<float>(-M_PI / 2);
  s.angle_increment_rad = static_cast<float>(M_PI / 180);
  s.range_max_m = 30.f;
  for (int i = 0; i < 180; ++i) {
    const double a = odom.theta + s.angle_min_rad + i * s.angle_increment_rad;
    const double c = std::cos(a), sn = std::sin(a);
    double t = 1e9;
    if (c > 1e-9) t = std::min(t, (5 - odom.x) / c);
    if (c < -1e-9) t = std::min(t, (-5 - odom.x) / c);
    if (sn > 1e-9) t = std::min(t, (5 - odom.y) / sn);
    if (sn < -1e-9) t = std::min(t, (-5 - odom.y) / sn);
    s.ranges_m.push_back(static_cast<float>(t));
  }
  return s;
}

TEST(RbpfSlam, BadInputIsRejectedAndCounted) {
  RbpfOptions o;
  o.particles = 4;
  o.threads = 2;
  RbpfSlam slam(o);
  int64_t t = 1000000;
  EXPECT_TRUE(slam.AddScan(SyntheticScan(t, Pose2(0, 0, 0))).processed);
  // NaN / inf / negative beams: counted, the rest of the scan is used.
  ScanInput s = SyntheticScan(t += 100000, Pose2(0.3, 0, 0));
  s.ranges_m[3] = std::nanf("");
  s.ranges_m[4] = INFINITY;
  s.ranges_m[5] = -1.f;
  EXPECT_TRUE(slam.AddScan(s).processed);
  EXPECT_GE(slam.counters().invalid_beams, 3);
  // Too few valid beams.
  ScanInput empty = SyntheticScan(t += 100000, Pose2(0.6, 0, 0));
  for (auto& r : empty.ranges_m) r = std::nanf("");
  EXPECT_FALSE(slam.AddScan(empty).processed);
  EXPECT_EQ(slam.counters().scans_too_few_beams, 1);
  // Time going backwards.
  EXPECT_FALSE(slam.AddScan(SyntheticScan(t - 500000, Pose2(0.6, 0, 0))).accepted);
  EXPECT_EQ(slam.counters().scans_time_backwards, 1);
  // An odometry jump of 50 m: counted, the filter does not move the particles by it.
  const ScanResult jump = slam.AddScan(SyntheticScan(t += 100000, Pose2(50.6, 0, 0)));
  EXPECT_EQ(slam.counters().odom_jumps, 1);
  EXPECT_LT(std::abs(jump.pose.x), 2.0);
  // Non-finite odometry and geometry.
  ScanInput bad = SyntheticScan(t += 100000, Pose2(0.6, 0, 0));
  bad.odom = Pose2(NAN, 0, 0);
  EXPECT_FALSE(slam.AddScan(bad).accepted);
  EXPECT_EQ(slam.counters().odom_invalid, 1);
  ScanInput bad_angle = SyntheticScan(t += 100000, Pose2(0.6, 0, 0));
  bad_angle.angle_increment_rad = NAN;
  EXPECT_FALSE(slam.AddScan(bad_angle).accepted);
  EXPECT_FALSE(slam.AddOdometry(t, Pose2(INFINITY, 0, 0)));
  EXPECT_FALSE(slam.AddImuYawRate(t, NAN));
  // The map is still a room: the estimate stays near the odometry of the clean scans.
  const io::GridMap map = slam.BestMap();
  const double width_m = map.width * map.resolution_m, height_m = map.height * map.resolution_m;
  EXPECT_GT(width_m, 4.75);  // the room's front half (beams cover -90..90 deg)
  EXPECT_LT(width_m, 8.0);
  EXPECT_GT(height_m, 9.5);
  EXPECT_LT(height_m, 13.0);
  for (const auto& p : slam.BestTrajectory()) EXPECT_LT(std::abs(p.pose.x), 2.0);
}

TEST(RbpfSlam, OutOfOrderOdometryIsCountedAndNotUsed) {
  // Scans that carry no odometry of their own take it from the WHEEL_ODOM buffer; a stale
  // sample arriving after a newer one must be counted and must not bend the interpolation.
  RbpfOptions o;
  o.particles = 4;
  o.threads = 1;
  RbpfSlam slam(o);
  const int64_t t0 = 1000000;
  EXPECT_TRUE(slam.AddOdometry(t0, Pose2(0, 0, 0)));
  EXPECT_TRUE(slam.AddOdometry(t0 + 100000, Pose2(0.1, 0, 0)));
  EXPECT_FALSE(slam.AddOdometry(t0 + 50000, Pose2(2.0, 0, 0)));  // older than the newest
  EXPECT_EQ(slam.counters().odom_out_of_order, 1);
  ScanInput first = SyntheticScan(t0, Pose2(0, 0, 0));
  first.odom.reset();
  EXPECT_TRUE(slam.AddScan(first).processed);
  // Between the stale sample's stamp and the newest: interpolated from the in-order samples.
  ScanInput second = SyntheticScan(t0 + 75000, Pose2(0.075, 0, 0));
  second.odom.reset();
  const ScanResult r = slam.AddScan(second);
  EXPECT_TRUE(r.accepted);
  EXPECT_FALSE(r.processed);  // below the update distance: placed by odometry
  EXPECT_NEAR(r.pose.x, 0.075, 1e-6);
  EXPECT_NEAR(r.pose.y, 0.0, 1e-6);
  EXPECT_EQ(slam.counters().odom_jumps, 0);
  EXPECT_EQ(slam.counters().scans_no_odom, 0);
}

// The odometry jump rule judges the WHEEL_ODOM samples step by step: a lidar away for 8 s
// while the base drove 4 m (over the 3 m limit between two scans) is no jump, and a real jump
// among those samples is left out while the driving around it is kept.
TEST(RbpfSlam, ALidarAwayWhileTheBaseDroveIsNoOdometryJump) {
  for (const double jump_m : {0.0, 20.0}) {
    SCOPED_TRACE(jump_m);
    RbpfOptions o;
    o.particles = 4;
    o.threads = 1;
    RbpfSlam slam(o);
    const auto truth_x = [](double t) { return -4.0 + 0.5 * t; };
    const auto at = [](double t) { return 1000000 + static_cast<int64_t>(std::llround(t * 1e6)); };
    ScanResult before, after;         // the scans before and after the lidar's absence
    for (int k = 0; k <= 180; ++k) {  // odometry at 20 Hz, scans at 10 Hz but from 1 s to 9 s
      const double t = 0.05 * k;
      const double raw_x = truth_x(t) + (t >= 5.0 ? jump_m : 0.0);
      ASSERT_TRUE(slam.AddOdometry(at(t), Pose2(raw_x, 0, 0)));
      if (k % 2 != 0 || (t > 1.0 && t < 9.0)) continue;
      ScanInput s = SyntheticScan(at(t), Pose2(truth_x(t), 0, 0));
      s.odom.reset();
      const ScanResult r = slam.AddScan(s);
      ASSERT_TRUE(r.accepted) << t;
      (k == 20 ? before : after) = r;
    }
    EXPECT_EQ(slam.counters().odom_jumps, jump_m > 0 ? 1 : 0);
    // Measured: 4.003 m either way (the whole 4 m was taken for a jump before).
    EXPECT_NEAR(after.pose.x - before.pose.x, 4.0, 0.1);
    EXPECT_NEAR(after.pose.y - before.pose.y, 0.0, 0.1);
  }
}

// Scans before the filter's first update (the first returns were all NaN: a lidar spinning up)
// have no map pose yet: the result says so, for the node not to publish the raw odometry as a
// map pose (it sat 12 m from the origin the first update then set). From the first update on,
// poses are in the map frame, anchored there.
TEST(RbpfSlam, ScansBeforeTheFirstUpdateHaveNoMapPose) {
  RbpfOptions o;
  o.particles = 4;
  o.threads = 1;
  RbpfSlam slam(o);
  const Pose2 odom0(12.0, -4.0, 2.0);
  for (int k = 0; k < 10; ++k) {
    const int64_t t = 1000000 + k * 100000;
    ScanInput s = SyntheticScan(t, Pose2());
    s.odom = odom0;
    if (k < 5) std::fill(s.ranges_m.begin(), s.ranges_m.end(), NAN);
    const ScanResult r = slam.AddScan(s);
    ASSERT_TRUE(r.accepted) << k;
    EXPECT_EQ(r.in_map_frame, k >= 5) << k;
    if (k >= 5) {
      EXPECT_LT(std::hypot(r.pose.x, r.pose.y), 0.05) << k;
    }
  }
}

// Resampling copies a particle's map by sharing its tiles; the steep gain resamples often, so
// after 120 scans most tiles are shared. (With the default flat weights the filter resamples
// rarely and 30 diverging maps share fewer: the memory that costs is in the benchmark.)
TEST(RbpfSlam, MapsShareTilesAcrossParticles) {
  OMNI_REQUIRE_DATASET(path, "slam-noisy-odom/intel.noisy.clf.gz");
  RbpfOptions o;
  o.particles = 30;
  o.threads = 2;
  o.sparse_likelihood_gain = 0.33;
  RbpfSlam slam(o);
  auto log = io::ReadCarmenLog(path);
  ASSERT_TRUE(log.ok());
  size_t n = 0;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    slam.AddScan(ToInput(r.laser));
    if (++n >= 120) break;
  }
  // 30 particles' maps cost far less than 30 full maps: most tiles are shared.
  EXPECT_GT(slam.total_tile_refs(), 30u * 20u);
  EXPECT_LT(slam.distinct_tiles() * 2, slam.total_tile_refs())
      << slam.distinct_tiles() << " distinct tiles for " << slam.total_tile_refs() << " refs";
}

// The noisy-odometry logs were made with 3 % scale, 1 % creep, 2 % heading scale and
// 0.015 rad/m drift (their README). Fitted to the best particle's matches on 150 scans of CSAIL
// (about 140 m), the calibration finds them; left off, it stays the identity.
TEST(RbpfSlam, CalibratesTheOdometryFromTheBestParticlesMatches) {
  OMNI_REQUIRE_DATASET(path, "slam-noisy-odom/csail.noisy.clf.gz");
  auto log = io::ReadCarmenLog(path);
  ASSERT_TRUE(log.ok());
  for (const bool enabled : {true, false}) {
    RbpfOptions o;
    o.particles = 8;
    o.odometry_calibration.enabled = enabled;
    RbpfSlam slam(o);
    size_t n = 0;
    for (const auto& r : log->records) {
      if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
      slam.AddScan(ToInput(r.laser));
      if (++n >= 150) break;
    }
    const OdometryCalibrator& oc = slam.odometry_calibrator();
    const OdometryCalibration& c = oc.calibration();
    if (!enabled) {
      EXPECT_FALSE(oc.active());
      EXPECT_TRUE(c.IsIdentity());
      continue;
    }
    ASSERT_TRUE(oc.active());
    EXPECT_GT(oc.pairs_used(), 100);
    EXPECT_NEAR(c.x_scale, 0.03, 0.01);
    EXPECT_NEAR(c.y_per_x, 0.01, 0.005);
    EXPECT_NEAR(c.theta_scale, 0.02, 0.01);
    EXPECT_NEAR(c.theta_per_x, 0.015, 0.005);
  }
}

// Scans between filter updates are placed from the best particle by the *calibrated* odometry
// step since the last update (and so, by BestTrajectory, at the end).
TEST(RbpfSlam, ScansBetweenUpdatesFollowTheCalibratedOdometry) {
  OMNI_REQUIRE_DATASET(path, "slam-noisy-odom/intel.noisy.clf.gz");
  auto log = io::ReadCarmenLog(path);
  ASSERT_TRUE(log.ok());
  RbpfOptions o;
  o.particles = 4;
  o.linear_update_m = 1.0;  // most scans fall between updates
  o.angular_update_rad = 0.5;
  o.odometry_calibration.min_pairs = 3;
  o.odometry_calibration.min_forward_m = 1.0;
  RbpfSlam slam(o);
  Pose2 anchor_odom;
  int checked = 0, corrected = 0;
  size_t n = 0;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    const ScanInput in = ToInput(r.laser);
    const ScanResult res = slam.AddScan(in);
    if (res.processed) {
      anchor_odom = *in.odom;
    } else if (res.accepted && slam.odometry_calibrator().active()) {
      const Pose2 raw = anchor_odom.Between(*in.odom);
      const Pose2 step = slam.odometry_calibrator().calibration().Correct(raw);
      const Pose2 want = slam.ReportedPose() * step;
      EXPECT_NEAR(res.pose.x, want.x, 1e-9) << n;
      EXPECT_NEAR(res.pose.y, want.y, 1e-9) << n;
      EXPECT_NEAR(res.pose.theta, want.theta, 1e-9) << n;
      ++checked;
      corrected += std::hypot(step.x - raw.x, step.y - raw.y) > 0.005;
    }
    if (++n >= 300) break;
  }
  EXPECT_EQ(slam.counters().odom_jumps, 0);
  EXPECT_GT(checked, 50);
  EXPECT_GT(corrected, 10);  // the calibration moved those poses by more than 5 mm
}

TEST(RbpfOptions, ShippedConfigLoadsAndTyposAreErrors) {
  const std::string path = std::string(OMNI_SOURCE_DIR) + "/config/rbpf_mapper.yaml";
  auto reader = ConfigReader::FromFile(path);
  ASSERT_TRUE(reader.ok()) << reader.error().message;
  auto opt = RbpfOptions::Load(*reader);
  ASSERT_TRUE(opt.ok()) << opt.error().message;
  EXPECT_GE(opt->particles, 1);
  EXPECT_TRUE(opt->odometry_calibration.enabled);
  // The file's grid choice is the built-in default.
  const RbpfOptions defaults;
  EXPECT_EQ(opt->grid.resolution_m, defaults.grid.resolution_m);
  EXPECT_EQ(opt->sparse_resolution_m, defaults.sparse_resolution_m);
  EXPECT_EQ(opt->sparse_scan_spacing_m, defaults.sparse_scan_spacing_m);
  EXPECT_EQ(opt->spacing_decision_m, defaults.spacing_decision_m);
  EXPECT_EQ(opt->likelihood_gain, defaults.likelihood_gain);
  EXPECT_EQ(opt->report_switch_log_margin, defaults.report_switch_log_margin);
  EXPECT_EQ(opt->sparse_likelihood_gain, defaults.sparse_likelihood_gain);
  auto sparse_typo = ConfigReader::FromString("grid:\n  sparse_resolution: 0.05\n", "t.yaml");
  ASSERT_TRUE(sparse_typo.ok());
  auto st = RbpfOptions::Load(*sparse_typo);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("grid.sparse_resolution"), std::string::npos)
      << st.error().message;
  auto cal = ConfigReader::FromString("odometry_calibration:\n  enabled: false\n  min_pairs: 30\n",
                                      "t.yaml");
  ASSERT_TRUE(cal.ok());
  auto co = RbpfOptions::Load(*cal);
  ASSERT_TRUE(co.ok()) << co.error().message;
  EXPECT_FALSE(co->odometry_calibration.enabled);
  EXPECT_EQ(co->odometry_calibration.min_pairs, 30);
  // The pose graph's own calibration keys are unknown here, not silently ignored.
  auto graph_key =
      ConfigReader::FromString("odometry_calibration:\n  adapt_noise: true\n", "t.yaml");
  ASSERT_TRUE(graph_key.ok());
  auto gk = RbpfOptions::Load(*graph_key);
  ASSERT_FALSE(gk.ok());
  EXPECT_NE(gk.error().message.find("odometry_calibration.adapt_noise"), std::string::npos)
      << gk.error().message;
  // The grid stores log odds in thousandths within +-30.
  RbpfOptions nan_grid;
  nan_grid.grid.hit_log_odds = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(nan_grid.Validate().ok());  // options built in code are checked too
  auto wide = ConfigReader::FromString("grid:\n  max_log_odds: 40\n", "t.yaml");
  ASSERT_TRUE(wide.ok());
  auto wo = RbpfOptions::Load(*wide);
  ASSERT_FALSE(wo.ok());
  EXPECT_NE(wo.error().message.find("grid.max_log_odds"), std::string::npos) << wo.error().message;
  auto typo = ConfigReader::FromString("particles: 30\nmatcher:\n  kernel_cell: 1\n", "t.yaml");
  ASSERT_TRUE(typo.ok());
  auto r = RbpfOptions::Load(*typo);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("matcher.kernel_cell"), std::string::npos) << r.error().message;
  auto gauss = ConfigReader::FromString(
      "proposal: gaussian\nproposal_steps: 2\nproposal_draw: false\n", "t.yaml");
  ASSERT_TRUE(gauss.ok());
  auto g = RbpfOptions::Load(*gauss);
  ASSERT_TRUE(g.ok()) << g.error().message;
  EXPECT_EQ(g->proposal, ProposalKind::kGaussian);
  EXPECT_EQ(g->proposal_grid.steps, 2);
  EXPECT_FALSE(g->proposal_draw);
  auto bad_kind = ConfigReader::FromString("proposal: gausian\n", "t.yaml");
  ASSERT_TRUE(bad_kind.ok());
  EXPECT_FALSE(RbpfOptions::Load(*bad_kind).ok());
  auto range = ConfigReader::FromString("particles: 0\n", "t.yaml");
  ASSERT_TRUE(range.ok());
  EXPECT_FALSE(RbpfOptions::Load(*range).ok());
}

}  // namespace
}  // namespace omni::rbpf
