// Derivatives and manifolds of the pose-graph back end: every cost function against Ceres'
// GradientChecker (numeric differentiation, with and without the manifolds), the SE(2)/SE(3)
// manifolds against Ceres' manifold invariants, and Ceres' cost against our chi^2 evaluator.
#include <ceres/ceres.h>
#include <ceres/gradient_checker.h>
#include <ceres/manifold_test_utils.h>
#include <gtest/gtest.h>

#include <memory>
#include <random>
#include <vector>

#include "omni/pose_graph_mapper/chi2.h"
#include "omni/pose_graph_mapper/cost_functions.h"
#include "omni/pose_graph_mapper/lie.h"
#include "omni/pose_graph_mapper/manifolds.h"

namespace omni::pgm {
namespace {

Eigen::Matrix3d RandomInfo3(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Eigen::Matrix3d a;
  for (int i = 0; i < 9; ++i) a(i / 3, i % 3) = u(rng);
  return a * a.transpose() + 0.5 * Eigen::Matrix3d::Identity();
}

Eigen::Matrix<double, 6, 6> RandomInfo6(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Eigen::Matrix<double, 6, 6> a;
  for (int i = 0; i < 36; ++i) a(i / 6, i % 6) = u(rng);
  return a * a.transpose() + 0.5 * Eigen::Matrix<double, 6, 6>::Identity();
}

Eigen::Quaterniond RandomQuat(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  return Eigen::Quaterniond(u(rng), u(rng), u(rng), u(rng)).normalized();
}

Eigen::Isometry3d RandomIso(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-3, 3);
  Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
  x.linear() = RandomQuat(rng).toRotationMatrix();
  x.translation() = Eigen::Vector3d(u(rng), u(rng), u(rng));
  return x;
}

void ToParams(const Eigen::Isometry3d& x, double* p) {
  const Eigen::Quaterniond q(x.linear());
  p[0] = x.translation().x(), p[1] = x.translation().y(), p[2] = x.translation().z();
  p[3] = q.x(), p[4] = q.y(), p[5] = q.z(), p[6] = q.w();
}

Eigen::Isometry3d FromParams(const double* p) {
  Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
  x.linear() = Eigen::Quaterniond(p[6], p[3], p[4], p[5]).normalized().toRotationMatrix();
  x.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
  return x;
}

// GradientChecker probes with and without manifolds.
void ExpectGradientsCorrect(const ceres::CostFunction& cost, std::vector<double*> params,
                            const std::vector<const ceres::Manifold*>& manifolds) {
  ceres::NumericDiffOptions nd;
  ceres::GradientChecker::ProbeResults results;
  ceres::GradientChecker plain(
      &cost, static_cast<const std::vector<const ceres::Manifold*>*>(nullptr), nd);
  EXPECT_TRUE(plain.Probe(params.data(), 1e-6, &results)) << results.error_log;
  ceres::GradientChecker on_manifold(&cost, &manifolds, nd);
  EXPECT_TRUE(on_manifold.Probe(params.data(), 1e-6, &results)) << results.error_log;
}

TEST(PoseGraphCostFunctions, RelativePose2PassesGradientChecker) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-3, 3), th(-3.0, 3.0);
  SE2Manifold se2;
  for (int trial = 0; trial < 20; ++trial) {
    const Pose2 z(u(rng), u(rng), th(rng));
    std::unique_ptr<ceres::CostFunction> cost(RelativePose2Cost::Create(z, RandomInfo3(rng)));
    double a[3] = {u(rng), u(rng), th(rng)};
    double b[3] = {u(rng), u(rng), th(rng)};
    // Keep the angular error away from the wrap at +-pi, where e_theta is discontinuous.
    b[2] = WrapAngle(a[2] + z.theta + 0.5 * th(rng));
    ExpectGradientsCorrect(*cost, {a, b}, {&se2, &se2});
  }
}

TEST(PoseGraphCostFunctions, PosePrior2PassesGradientChecker) {
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-3, 3), th(-3.0, 3.0);
  SE2Manifold se2;
  for (int trial = 0; trial < 20; ++trial) {
    const Pose2 z(u(rng), u(rng), th(rng));
    std::unique_ptr<ceres::CostFunction> cost(PosePrior2Cost::Create(z, RandomInfo3(rng)));
    double x[3] = {u(rng), u(rng), WrapAngle(z.theta + 0.5 * th(rng))};
    ExpectGradientsCorrect(*cost, {x}, {&se2});
  }
}

TEST(PoseGraphCostFunctions, RelativePose3PassesGradientChecker) {
  std::mt19937 rng(3);
  SE3Manifold se3;
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Isometry3d z = RandomIso(rng);
    const Eigen::Matrix<double, 6, 6> info = RandomInfo6(rng);
    std::unique_ptr<ceres::CostFunction> analytic(RelativePose3Cost::Create(z, info));
    std::unique_ptr<ceres::CostFunction> autodiff(RelativePose3Functor::Create(z, info));
    double a[7], b[7];
    const Eigen::Isometry3d xa = RandomIso(rng);
    // b near a * z (rotation error well below pi, where the w >= 0 flip happens).
    Eigen::Isometry3d xb = xa * z;
    xb.linear() = xb.linear() * ExpSO3(Eigen::Vector3d(0.3, -0.2, 0.4)).toRotationMatrix();
    xb.translation() += Eigen::Vector3d(0.2, 0.1, -0.3);
    ToParams(xa, a);
    ToParams(xb, b);
    // Half of the trials off the unit sphere: the ambient Jacobians must hold there too.
    if (trial % 2) {
      for (int i = 3; i < 7; ++i) a[i] *= 1.3, b[i] *= 0.8;
    }
    ExpectGradientsCorrect(*analytic, {a, b}, {&se3, &se3});
    ExpectGradientsCorrect(*autodiff, {a, b}, {&se3, &se3});
    // The analytic cost is the automatic-differentiation one, values and Jacobians.
    const double* params[2] = {a, b};
    Eigen::Matrix<double, 6, 1> r1, r2;
    Eigen::Matrix<double, 6, 7, Eigen::RowMajor> ja1, jb1, ja2, jb2;
    double* j1[2] = {ja1.data(), jb1.data()};
    double* j2[2] = {ja2.data(), jb2.data()};
    ASSERT_TRUE(analytic->Evaluate(params, r1.data(), j1));
    ASSERT_TRUE(autodiff->Evaluate(params, r2.data(), j2));
    EXPECT_LT((r1 - r2).norm(), 1e-9 * (1 + r2.norm()));
    EXPECT_LT((ja1 - ja2).norm(), 1e-9 * (1 + ja2.norm()));
    EXPECT_LT((jb1 - jb2).norm(), 1e-9 * (1 + jb2.norm()));
  }
}

TEST(PoseGraphCostFunctions, CeresCostEqualsHalfOurChi2) {
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-3, 3), th(-3.1, 3.1);
  for (int trial = 0; trial < 50; ++trial) {
    const Pose2 z(u(rng), u(rng), th(rng)), a(u(rng), u(rng), th(rng)), b(u(rng), u(rng), th(rng));
    const Eigen::Matrix3d info = RandomInfo3(rng);
    std::unique_ptr<ceres::CostFunction> cost(RelativePose2Cost::Create(z, info));
    double pa[3] = {a.x, a.y, a.theta}, pb[3] = {b.x, b.y, b.theta};
    const double* params[2] = {pa, pb};
    Eigen::Vector3d r;
    ASSERT_TRUE(cost->Evaluate(params, r.data(), nullptr));
    const Eigen::Vector3d e = EdgeError2(z, a, b);
    EXPECT_NEAR(r.squaredNorm(), e.dot(info * e), 1e-9 * (1 + r.squaredNorm()));
  }
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Isometry3d z = RandomIso(rng), a = RandomIso(rng), b = RandomIso(rng);
    const Eigen::Matrix<double, 6, 6> info = RandomInfo6(rng);
    std::unique_ptr<ceres::CostFunction> cost(RelativePose3Cost::Create(z, info));
    double pa[7], pb[7];
    ToParams(a, pa);
    ToParams(b, pb);
    const double* params[2] = {pa, pb};
    Eigen::Matrix<double, 6, 1> r;
    ASSERT_TRUE(cost->Evaluate(params, r.data(), nullptr));
    const Eigen::Matrix<double, 6, 1> e = EdgeError3(z, FromParams(pa), FromParams(pb));
    EXPECT_NEAR(r.squaredNorm(), e.dot(info * e), 1e-9 * (1 + r.squaredNorm()));
  }
}

TEST(PoseGraphCostFunctions, ZeroErrorAtTheMeasurement) {
  const Pose2 a(1, 2, 0.3), z(0.5, -0.2, 2.9);
  const Pose2 b = a * z;
  EXPECT_LT(EdgeError2(z, a, b).norm(), 1e-12);
  std::mt19937 rng(5);
  const Eigen::Isometry3d za = RandomIso(rng), zz = RandomIso(rng);
  EXPECT_LT(EdgeError3(zz, za, za * zz).norm(), 1e-12);
}

TEST(PoseGraphCostFunctions, RelativeInformationIsTheCovarianceOfTheMeasurementsCoordinates) {
  // The odometry sources and matchers give a covariance over (x, y, theta) of b in a's frame;
  // the cost's error is in b's frame. With RelativeInformation, a factor's chi^2 must equal the
  // Mahalanobis distance of the estimate's relative pose from z in z's own coordinates.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int k = 0; k < 20; ++k) {
    const Pose2 z(u(rng), u(rng), 1.5 * u(rng));
    Eigen::Matrix3d l = Eigen::Matrix3d::Zero();
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j <= i; ++j) l(i, j) = (i == j ? 0.2 + std::abs(u(rng)) : 0.3 * u(rng));
    const Eigen::Matrix3d cov = 0.01 * l * l.transpose();  // anisotropic, correlated
    const Eigen::Matrix3d info = RelativeInformation(z, cov, 0.0);
    const Pose2 a(u(rng), u(rng), u(rng));
    const Eigen::Vector3d d(0.05 * u(rng), 0.05 * u(rng), 0.05 * u(rng));
    const Pose2 b = a * Pose2(z.x + d.x(), z.y + d.y(), z.theta + d.z());
    const RelativePose2Cost cost(z, info);
    const double pa[3] = {a.x, a.y, a.theta}, pb[3] = {b.x, b.y, b.theta};
    const double* params[2] = {pa, pb};
    Eigen::Vector3d r;
    ASSERT_TRUE(cost.Evaluate(params, r.data(), nullptr));
    const double mahalanobis = d.dot(cov.inverse() * d);
    EXPECT_NEAR(r.squaredNorm(), mahalanobis, 1e-9 * (1 + mahalanobis)) << k;
    // Taking Sigma^-1 as the information directly is only right when theta_z = 0 or Sigma's xy
    // block is isotropic: here it is neither.
    const RelativePose2Cost naive(z, cov.inverse());
    ASSERT_TRUE(naive.Evaluate(params, r.data(), nullptr));
    if (std::abs(z.theta) > 0.3) {
      EXPECT_GT(std::abs(r.squaredNorm() - mahalanobis), 1e-6) << k;
    }
  }
}

TEST(PoseGraphManifolds, SE2InvariantsHold) {
  using namespace ceres;  // NOLINT: the invariant macro names ceres' matchers unqualified
  SE2Manifold m;
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(-2, 2), th(-1.2, 1.2), d(-0.5, 0.5);
  for (int trial = 0; trial < 20; ++trial) {
    Eigen::Vector3d x(u(rng), u(rng), th(rng)), y(u(rng), u(rng), th(rng));
    Eigen::Vector3d delta(d(rng), d(rng), d(rng));
    constexpr double kTolerance = 1e-9;
    EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(m, x, delta, y, kTolerance);
  }
  // Small rotations (the Taylor branch of Exp/Log).
  Eigen::Vector3d x(0.1, 0.2, 0.3), y(0.4, -0.1, 0.3 + 1e-8), delta(1e-3, -2e-3, 1e-9);
  constexpr double kTolerance = 1e-9;
  EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(m, x, delta, y, kTolerance);
}

TEST(PoseGraphManifolds, SE3InvariantsHold) {
  using namespace ceres;  // NOLINT: the invariant macro names ceres' matchers unqualified
  SE3Manifold m;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> d(-0.5, 0.5);
  for (int trial = 0; trial < 20; ++trial) {
    Eigen::Matrix<double, 7, 1> x, y;
    ToParams(RandomIso(rng), x.data());
    // y within a rotation of less than pi of x so that Minus is the inverse of Plus.
    Eigen::Isometry3d yy = FromParams(x.data());
    yy.linear() =
        yy.linear() * ExpSO3(Eigen::Vector3d(d(rng), d(rng), d(rng)) * 4).toRotationMatrix();
    yy.translation() += Eigen::Vector3d(d(rng), d(rng), d(rng));
    ToParams(yy, y.data());
    // Of the two quaternions of y's rotation, the one Plus(x, Minus(y, x)) returns (q and -q
    // are the same rotation; the manifold's chart picks the one with w(q_x^* q_y) >= 0).
    const Eigen::Quaterniond qx(x[6], x[3], x[4], x[5]), qy(y[6], y[3], y[4], y[5]);
    if ((qx.conjugate() * qy).w() < 0) y.tail<4>() = -y.tail<4>();
    Eigen::Matrix<double, 6, 1> delta;
    for (int i = 0; i < 6; ++i) delta[i] = d(rng);
    constexpr double kTolerance = 1e-9;
    EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(m, x, delta, y, kTolerance);
  }
  // Small rotations (the Taylor branches of V and V^-1).
  Eigen::Matrix<double, 7, 1> x, y;
  ToParams(RandomIso(rng), x.data());
  Eigen::Isometry3d yy = FromParams(x.data());
  yy.linear() = yy.linear() * ExpSO3(Eigen::Vector3d(2e-3, -1e-3, 4e-3)).toRotationMatrix();
  yy.translation() += Eigen::Vector3d(0.3, -0.2, 0.1);
  ToParams(yy, y.data());
  const Eigen::Quaterniond qx(x[6], x[3], x[4], x[5]), qy(y[6], y[3], y[4], y[5]);
  if ((qx.conjugate() * qy).w() < 0) y.tail<4>() = -y.tail<4>();
  Eigen::Matrix<double, 6, 1> delta;
  delta << 0.4, -0.3, 0.2, 1e-3, 3e-3, -2e-3;
  constexpr double kTolerance = 1e-9;
  EXPECT_THAT_MANIFOLD_INVARIANTS_HOLD(m, x, delta, y, kTolerance);
}

// SE(3)'s V(w) and its inverse: inverse of each other, the Taylor branch continuous with the
// closed form at the switch, and Plus a rigid group product x * Exp(d).
TEST(PoseGraphLie, SE3VInverseAndSeriesBranch) {
  const Eigen::Vector3d v(0.7, -1.3, 2.1), axis = Eigen::Vector3d(0.3, -0.5, 0.8).normalized();
  for (double a : {0.0, 1e-9, 1e-4, 9.99e-3, 1.001e-2, 0.3, 2.0, 3.1}) {
    const Eigen::Vector3d w = a * axis;
    EXPECT_LT((SE3VInverse(w, SE3V(w, v)) - v).norm(), 1e-12) << a;
  }
  // Across the series switch (|w|^2 = 1e-4) the two formulas agree.
  const Eigen::Vector3d below = SE3V(0.00999999 * axis, v), above = SE3V(0.01000001 * axis, v);
  EXPECT_LT((below - above).norm(), 1e-9);
  // V(w) v against the translation of exp of the 4x4 twist matrix by its power series.
  const Eigen::Vector3d w(0.4, -0.7, 0.9);
  Eigen::Matrix4d xi = Eigen::Matrix4d::Zero();
  xi.topLeftCorner<3, 3>() << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  xi.topRightCorner<3, 1>() = v;
  Eigen::Matrix4d term = Eigen::Matrix4d::Identity(), sum = Eigen::Matrix4d::Identity();
  for (int k = 1; k < 30; ++k) {
    term = term * xi / k;
    sum += term;
  }
  EXPECT_LT((sum.topRightCorner<3, 1>() - SE3V(w, v)).norm(), 1e-12);
  EXPECT_LT((sum.topLeftCorner<3, 3>() - ExpSO3(w).toRotationMatrix()).norm(), 1e-12);
}

TEST(PoseGraphLie, ExpLogRoundTrip) {
  for (double w : {0.0, 1e-9, 1e-4, 0.5, -2.0, 3.1}) {
    const Eigen::Vector3d t(0.7, -1.3, w);
    const Eigen::Vector3d back = LogSE2(ExpSE2(t));
    EXPECT_LT((back - t).norm(), 1e-9) << w;
    const Eigen::Vector3d r = Eigen::Vector3d(0.3, -0.5, 0.8).normalized() * std::abs(w);
    EXPECT_LT((LogSO3(ExpSO3(r)) - r).norm(), 1e-9) << w;
  }
}

}  // namespace
}  // namespace omni::pgm
