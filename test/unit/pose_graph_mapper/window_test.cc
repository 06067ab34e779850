// Sliding-window optimisation with marginalisation: on a linear problem the window's solution
// equals the full graph's; factors to poses that have left the window are refused.
#include <gtest/gtest.h>

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
