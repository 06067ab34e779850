// Sliding-window optimisation with marginalisation: on a linear problem the window's solution
// equals the full graph's; factors to poses that have left the window are refused.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "omni/pose_graph_mapper/window_optimizer.h"

namespace omni::pgm {
namespace {

struct Problem {
  std::vector<Pose2> truth;
  std::vector<Pose2> odometry;  // odometry[i] = measured pose i in the frame of pose i - 1
  std::vector<std::pair<int, Pose2>> absolute;
  std::vector<std::tuple<int, int, Pose2>> loops;
};

// theta = 0 everywhere and measured exactly with a huge information, so the residuals are
// linear in the positions: the "small linear case".
Problem MakeLinearProblem(int n) {
  Problem p;
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0, 0.05);
  for (int i = 0; i < n; ++i) p.truth.emplace_back(0.5 * i, 0.3 * std::sin(0.4 * i), 0.0);
  p.odometry.emplace_back();
  for (int i = 1; i < n; ++i) {
    const Pose2 d = p.truth[i - 1].Between(p.truth[i]);
    p.odometry.emplace_back(d.x + noise(rng), d.y + noise(rng), 0.0);
  }
  for (int i : {0, 7, 13, 18})
    p.absolute.push_back({i, Pose2(p.truth[i].x + noise(rng), p.truth[i].y + noise(rng), 0.0)});
  for (int i = 3; i < n; i += 2) {
    const Pose2 d = p.truth[i - 3].Between(p.truth[i]);
    p.loops.push_back({i - 3, i, Pose2(d.x + noise(rng), d.y + noise(rng), 0.0)});
  }
  return p;
}

void Feed(const Problem& p, SlidingWindowOptimizer* opt) {
  Eigen::Matrix3d info = Eigen::Matrix3d::Identity();
  info(2, 2) = 1e9;
  Pose2 guess;
  for (size_t i = 0; i < p.truth.size(); ++i) {
    const int id = static_cast<int>(i);
    if (i > 0) guess = *opt->Estimate(id - 1) * p.odometry[i];
    ASSERT_TRUE(opt->AddPose(id, guess).ok());
    if (i > 0) {
      ASSERT_TRUE(opt->AddRelative(id - 1, id, p.odometry[i], info).ok());
    }
    for (const auto& [j, z] : p.absolute)
      if (j == id) {
        ASSERT_TRUE(opt->AddAbsolute(id, z, 4.0 * info).ok());
      }
    for (const auto& [a, b, z] : p.loops)
      if (b == id) {
        ASSERT_TRUE(opt->AddRelative(a, b, z, info).ok()) << a << " " << b;
      }
    auto u = opt->Update();
    ASSERT_TRUE(u.ok()) << u.error().message;
  }
}

WindowOptions Tight(int window) {
  WindowOptions o;
  o.window_size = window;
  o.max_iterations = 50;
  o.function_tolerance = 1e-16;
  o.gradient_tolerance = 1e-16;
  o.parameter_tolerance = 1e-16;
  return o;
}

TEST(PoseGraphWindow, MarginalisationGivesTheFullGraphSolutionOnALinearProblem) {
  const Problem p = MakeLinearProblem(20);
  SlidingWindowOptimizer window(Tight(5)), full(Tight(1000));
  Feed(p, &window);
  Feed(p, &full);
  EXPECT_EQ(window.WindowIds().size(), 5u);
  EXPECT_GT(window.prior_size(), 0u);
  EXPECT_EQ(full.prior_size(), 0u);
  for (int id : window.WindowIds()) {
    const Pose2 a = *window.Estimate(id), b = *full.Estimate(id);
    EXPECT_NEAR(a.x, b.x, 1e-6) << id;
    EXPECT_NEAR(a.y, b.y, 1e-6) << id;
  }
}

TEST(PoseGraphWindow, OldFactorsStillShapeTheWindowSolution) {
  // Without the absolute factors on old poses the last poses move: the information the window
  // receives from marginalised poses matters, so the test above is not vacuous.
  Problem p = MakeLinearProblem(20);
  SlidingWindowOptimizer full(Tight(1000));
  Feed(p, &full);
  p.absolute = {{0, p.absolute[0].second}};
  SlidingWindowOptimizer other(Tight(1000));
  Feed(p, &other);
  double diff = 0;
  for (int id = 15; id < 20; ++id)
    diff = std::max(diff,
                    (full.Estimate(id)->translation() - other.Estimate(id)->translation()).norm());
  EXPECT_GT(diff, 1e-3);
}

TEST(PoseGraphWindow, CovarianceEqualsTheFullGraphsOnALinearProblem) {
  // The marginal prior carries the old poses' information: the window's marginal covariances
  // are the full graph's, not those of a window cut loose from its past.
  const Problem p = MakeLinearProblem(20);
  SlidingWindowOptimizer window(Tight(5)), full(Tight(1000));
  Feed(p, &window);
  Feed(p, &full);
  ASSERT_GT(window.prior_size(), 0u);
  for (int id : window.WindowIds()) {
    const auto a = window.Covariance(id), b = full.Covariance(id);
    ASSERT_TRUE(a && b) << id;
    EXPECT_LT(((*a - *b).topLeftCorner<2, 2>()).norm(), 1e-6 * b->norm()) << id;
    EXPECT_GT((*a)(0, 0), 1e-4) << id;  // not the anchor's tiny variance
  }
  EXPECT_FALSE(window.Covariance(0).has_value());   // marginalised
  EXPECT_FALSE(window.Covariance(99).has_value());  // never added
  // Without the old absolute factors the newest pose is less certain: the prior matters.
  Problem loose = p;
  loose.absolute = {loose.absolute[0]};
  SlidingWindowOptimizer other(Tight(5));
  Feed(loose, &other);
  EXPECT_GT((*other.Covariance(19))(0, 0), 1.5 * (*window.Covariance(19))(0, 0));
}

TEST(PoseGraphWindow, CovarianceOfAnOdometryChainIsThePropagatedOne) {
  // Anchored first pose, odometry only, turning: the smoother's marginal of each pose equals
  // Sigma_b = A Sigma_a A^T + B Q B^T, the covariance propagated through the SE(2) composition
  // (A, B its Jacobians), also after the first poses have been marginalised. Linearisation at
  // the exact estimates (no noise), so first order is the whole story.
  SlidingWindowOptimizer w(Tight(3));
  Eigen::Matrix3d q = Eigen::Matrix3d::Zero();
  q.diagonal() << 0.01, 0.004, 0.002;
  q(0, 2) = q(2, 0) = 0.001;
  const Eigen::Matrix3d anchor_cov = 1e-4 * Eigen::Matrix3d::Identity();
  const Pose2 step(0.8, 0.1, 0.35);
  Pose2 pose(1.0, -2.0, 0.5);
  Eigen::Matrix3d sigma = anchor_cov;
  ASSERT_TRUE(w.AddPose(0, pose).ok());
  ASSERT_TRUE(w.AddAbsolute(0, pose, anchor_cov.inverse()).ok());
  ASSERT_TRUE(w.Update().ok());
  for (int id = 1; id < 9; ++id) {
    const double c = std::cos(pose.theta), s = std::sin(pose.theta);
    Eigen::Matrix3d a = Eigen::Matrix3d::Identity();
    a(0, 2) = -s * step.x - c * step.y;
    a(1, 2) = c * step.x - s * step.y;
    // The factor's error is the g2o EDGE_SE2 one, t2v(Z^-1 A^-1 B): noise on the later pose in
    // its own frame, so B rotates by the later pose's heading.
    const double cb = std::cos(pose.theta + step.theta), sb = std::sin(pose.theta + step.theta);
    Eigen::Matrix3d b = Eigen::Matrix3d::Identity();
    b.topLeftCorner<2, 2>() << cb, -sb, sb, cb;
    sigma = a * sigma * a.transpose() + b * q * b.transpose();
    pose = pose * step;
    ASSERT_TRUE(w.AddPose(id, pose).ok());
    ASSERT_TRUE(w.AddRelative(id - 1, id, step, q.inverse()).ok());
    ASSERT_TRUE(w.Update().ok());
    const auto cov = w.Covariance(id);
    ASSERT_TRUE(cov.has_value());
    EXPECT_LT((*cov - sigma).norm(), 1e-6 * sigma.norm()) << "pose " << id << "\n"
                                                          << *cov << "\n"
                                                          << sigma;
  }
  EXPECT_GT(w.prior_size(), 0u);
}

TEST(PoseGraphWindow, FactorsToPosesThatLeftTheWindowAreRefused) {
  SlidingWindowOptimizer w(Tight(3));
  for (int i = 0; i < 6; ++i) {
    ASSERT_TRUE(w.AddPose(i, Pose2(i, 0, 0)).ok());
    if (i > 0) {
      ASSERT_TRUE(w.AddRelative(i - 1, i, Pose2(1, 0, 0), Eigen::Matrix3d::Identity()).ok());
    }
    ASSERT_TRUE(w.Update().ok());
  }
  const Status s = w.AddRelative(0, 5, Pose2(5, 0, 0), Eigen::Matrix3d::Identity());
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("left the window"), std::string::npos) << s.message();
  EXPECT_FALSE(w.AddPose(2, Pose2()).ok());  // ids are unique, even after marginalisation
  EXPECT_TRUE(w.Estimate(0).has_value());    // marginalised poses keep their estimate
  WindowOptions bad;
  bad.window_size = 1;
  SlidingWindowOptimizer b(bad);
  EXPECT_FALSE(b.Update().ok());
}

}  // namespace
}  // namespace omni::pgm
