// Removing a node from a 2D pose graph (node_removal.h): a chain node gives the exact
// composition of its two factors, a node with loops leaves a tree whose graph keeps the full
// graph's solution, merged parallel factors keep the sum of their costs, and a node its factors
// do not determine is refused.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <map>
#include <random>

#include "omni/pose_graph_mapper/batch_optimizer.h"
#include "omni/pose_graph_mapper/chi2.h"
#include "omni/pose_graph_mapper/node_removal.h"

namespace omni::pgm {
namespace {

double Distance(const Pose2& a, const Pose2& b) { return std::hypot(a.x - b.x, a.y - b.y); }

double Chi2(const RelativeFactor2& f, const Pose2& a, const Pose2& b) {
  const Eigen::Vector3d e = EdgeError2(f.z, a, b);
  return e.dot(f.information * e);
}

Eigen::Matrix3d Info(double xy_sd, double th_sd) {
  return Eigen::Vector3d(1 / (xy_sd * xy_sd), 1 / (xy_sd * xy_sd), 1 / (th_sd * th_sd))
      .asDiagonal();
}

// EdgeError2's error is the perturbation d in a (+) b = z (+) d, in the frame at z's end. For
// T_02 = T_01 d1 T_12 d2, first order: d = Ad(T_12^-1) d1 + d2 with
// Ad(T^-1) = [R^T, R^T J t; 0, 1] and J the 90-degree rotation (derived by hand, not by the code
// under test).
Eigen::Matrix3d ComposedCovariance(const Pose2& z12, const Eigen::Matrix3d& c01,
                                   const Eigen::Matrix3d& c12) {
  const double c = std::cos(z12.theta), s = std::sin(z12.theta);
  Eigen::Matrix2d rt;
  rt << c, s, -s, c;
  Eigen::Matrix3d ad = Eigen::Matrix3d::Identity();
  ad.topLeftCorner<2, 2>() = rt;
  ad.block<2, 1>(0, 2) = rt * Eigen::Vector2d(-z12.y, z12.x);
  return ad * c01 * ad.transpose() + c12;
}

TEST(NodeRemoval, AChainNodeIsTheExactCompositionOfItsTwoFactors) {
  const Pose2 z01(1.0, 0.2, 0.3), z12(0.8, -0.4, -0.5);
  const Eigen::Matrix3d i01 = Info(0.05, 0.02), i12 = Info(0.1, 0.01);
  // The middle estimate 2 cm and 0.01 rad off its measurements: the result still measures
  // z01 (+) z12, the removed factors' own mean, not the estimates' relative pose.
  const Pose2 x0(2, 1, 0.4), x1 = x0 * z01 * Pose2(0.02, -0.01, 0.01), x2 = x0 * z01 * z12;
  const std::vector<RelativeFactor2> fs{{0, 1, z01, i01}, {1, 2, z12, i12}};
  const auto tree = MarginalizeNode(1, fs, {{0, x0}, {1, x1}, {2, x2}}, {{0, 0}, {1, 1}, {2, 2}});
  ASSERT_TRUE(tree.ok()) << tree.error().message;
  ASSERT_EQ(tree->size(), 1u);
  const RelativeFactor2& f = tree->front();
  EXPECT_EQ(f.from, 0);
  EXPECT_EQ(f.to, 2);
  const Pose2 z02 = z01 * z12;
  EXPECT_NEAR(f.z.x, z02.x, 1e-3);
  EXPECT_NEAR(f.z.y, z02.y, 1e-3);
  EXPECT_NEAR(f.z.theta, z02.theta, 1e-4);
  // Linearised at the middle estimate, so equal to first order in its 2 cm offset.
  const Eigen::Matrix3d want = ComposedCovariance(z12, i01.inverse(), i12.inverse());
  const Eigen::Matrix3d got = f.information.inverse();
  EXPECT_LT((got - want).norm(), 2e-2 * want.norm()) << got << "\n\n" << want;

  // The same chain written the other way round (2 -> 1 and 1 -> 0) gives the same factor.
  const std::vector<RelativeFactor2> back{{1, 0, z01.Inverse(), Info(0.05, 0.02)},
                                          {2, 1, z12.Inverse(), Info(0.1, 0.01)}};
  const Pose2 y1 = x0 * z01;
  const auto tree2 =
      MarginalizeNode(1, back, {{0, x0}, {1, y1}, {2, x2}}, {{0, 0}, {1, 1}, {2, 2}});
  ASSERT_TRUE(tree2.ok());
  ASSERT_EQ(tree2->size(), 1u);
  EXPECT_EQ(tree2->front().from, 0);
  EXPECT_NEAR(tree2->front().z.x, z02.x, 1e-6);
  EXPECT_NEAR(tree2->front().z.theta, z02.theta, 1e-9);
}

TEST(NodeRemoval, ALeafLeavesNothingAndAnUndeterminedNodeIsRefused) {
  const Pose2 z(1, 0, 0);
  auto leaf =
      MarginalizeNode(1, {{0, 1, z, Info(0.1, 0.1)}}, {{0, Pose2()}, {1, z}}, {{0, 0}, {1, 1}});
  ASSERT_TRUE(leaf.ok());
  EXPECT_TRUE(leaf->empty());
  // Factors that say nothing about the node's heading: no marginal.
  Eigen::Matrix3d flat = Info(0.1, 0.1);
  flat(2, 2) = 0;
  const auto refused =
      MarginalizeNode(1, {{0, 1, z, flat}, {1, 2, z, flat}}, {{0, Pose2()}, {1, z}, {2, z * z}},
                      {{0, 0}, {1, 1}, {2, 2}});
  EXPECT_FALSE(refused.ok());
  // A factor that does not touch the node is a caller's error.
  EXPECT_FALSE(
      MarginalizeNode(1, {{0, 2, z, Info(0.1, 0.1)}}, {{0, Pose2()}, {2, z}}, {{0, 0}, {2, 2}})
          .ok());
}

TEST(NodeRemoval, MergedParallelFactorsKeepTheSumOfTheirCosts) {
  const Pose2 a(0.5, -1, 0.2), b = a * Pose2(1.0, 0.3, 0.4);
  const RelativeFactor2 f1{0, 1, a.Between(b) * Pose2(0.03, -0.02, 0.01), Info(0.05, 0.02)};
  const RelativeFactor2 f2{0, 1, a.Between(b) * Pose2(-0.01, 0.04, -0.02), Info(0.08, 0.01)};
  const RelativeFactor2 m = MergeRelativeFactors(f1, f2, a, b);
  // Up to a constant, near the estimates.
  const double base = Chi2(f1, a, b) + Chi2(f2, a, b) - Chi2(m, a, b);
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0, 0.01);
  for (int i = 0; i < 20; ++i) {
    const Pose2 bb = b * Pose2(n(rng), n(rng), n(rng));
    const double sum = Chi2(f1, a, bb) + Chi2(f2, a, bb);
    EXPECT_NEAR(sum - Chi2(m, a, bb), base, 0.02 * sum + 1e-6) << i;
  }
}

// A loop walked four times with noisy odometry and loop factors, solved with the Cauchy loss
// as the mapper's global optimisation is: the graph's optimum, then nodes of the later passes
// (each with loops to the first) removed one after another, the graph re-solved after each, as
// the mapper does (factors weighted by the loss when marginalised, the folded ones solved without
// it). The kept nodes stay at the full graph's optimum; dropping the loops instead, or applying
// the loss to the folded factors a second time, moves them.
TEST(NodeRemoval, TheReducedGraphKeepsTheFullGraphsSolution) {
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0, 1);
  const int per_lap = 24, laps = 4, total = per_lap * laps;
  std::vector<Pose2> truth;
  Pose2 x;
  for (int i = 0; i < total; ++i) {
    truth.push_back(x);
    x = x * Pose2(0.5, 0, 2 * M_PI / per_lap);
  }
  const Eigen::Matrix3d odo = Info(0.02, 0.01), loop = Info(0.03, 0.01);
  io::PoseGraph g;
  Pose2 dead;
  for (int i = 0; i < total; ++i) {
    g.vertices2.push_back({i, dead});
    if (i + 1 < total)
      dead = dead * truth[i].Between(truth[i + 1]) *
             Pose2(0.02 * n(rng), 0.02 * n(rng), 0.01 * n(rng));
  }
  auto noisy = [&](int a, int b, double xy, double th) {
    return truth[static_cast<size_t>(a)].Between(truth[static_cast<size_t>(b)]) *
           Pose2(xy * n(rng), xy * n(rng), th * n(rng));
  };
  for (int i = 0; i + 1 < total; ++i)
    g.edges2.push_back({i, i + 1, noisy(i, i + 1, 0.02, 0.01), odo, 0});
  for (int i = per_lap; i < total; ++i)  // each later node to the first lap, and its neighbour
    for (int d : {0, 1})
      g.edges2.push_back({(i + d) % per_lap, i, noisy((i + d) % per_lap, i, 0.03, 0.01), loop, 0});
  BatchOptions bo;
  bo.initialization = Initialization::kNone;
  bo.function_tolerance = 1e-14;
  bo.max_iterations = 100;
  bo.loss = "cauchy";
  ASSERT_TRUE(OptimizeGraph(&g, bo).ok());
  std::map<int, Pose2> full;
  for (const auto& v : g.vertices2) full[v.id] = v.pose;

  // Every later-pass node but one in six is removed, in time order.
  std::map<int, int64_t> order;
  for (int i = 0; i < total; ++i) order[i] = i;
  size_t kept_factors = 0;
  enum class Mode { kTree, kDropLoops, kLossTwice };
  auto reduce = [&](Mode mode) {
    std::map<int, Pose2> est = full;
    std::vector<RelativeFactor2> plain, folded;
    for (const auto& e : g.edges2) plain.push_back({e.from, e.to, e.measurement, e.information});
    for (int r = per_lap; r < total - 1; ++r) {
      if (r % 6 == 0) continue;
      std::vector<RelativeFactor2> touching;
      for (auto* list : {&plain, &folded}) {
        std::vector<RelativeFactor2> rest;
        for (const auto& f : *list) {
          if (f.from != r && f.to != r) {
            rest.push_back(f);
            continue;
          }
          if (mode == Mode::kDropLoops && std::min(f.from, f.to) < per_lap) continue;
          const Eigen::Vector3d e = EdgeError2(f.z, est.at(f.from), est.at(f.to));
          const double w =
              list == &folded ? 1.0 : LossWeight(bo.loss, 1.0, e.dot(f.information * e));
          touching.push_back({f.from, f.to, f.z, w * f.information});
        }
        list->swap(rest);
      }
      auto tree = MarginalizeNode(r, touching, est, order);
      EXPECT_TRUE(tree.ok()) << r << ": " << tree.error().message;
      if (!tree.ok()) return est;
      for (const auto& t : *tree) {
        auto same = std::find_if(folded.begin(), folded.end(), [&](const RelativeFactor2& f) {
          return f.from == t.from && f.to == t.to;
        });
        if (same == folded.end())
          folded.push_back(t);
        else
          *same = MergeRelativeFactors(*same, t, est.at(t.from), est.at(t.to));
      }
      est.erase(r);
      io::PoseGraph h;
      for (const auto& [id, p] : est) h.vertices2.push_back({id, p});
      for (const auto* list : {&plain, &folded})
        for (const auto& f : *list) h.edges2.push_back({f.from, f.to, f.z, f.information, 0});
      BatchOptions b = bo;
      b.first_plain_edge2 = mode == Mode::kLossTwice ? SIZE_MAX : plain.size();
      EXPECT_TRUE(OptimizeGraph(&h, b).ok());
      for (const auto& v : h.vertices2) est[v.id] = v.pose;
    }
    kept_factors = plain.size() + folded.size();
    return est;
  };
  const std::map<int, Pose2> reduced = reduce(Mode::kTree);
  const size_t reduced_factors = kept_factors;
  const std::map<int, Pose2> dropped = reduce(Mode::kDropLoops);
  const std::map<int, Pose2> twice = reduce(Mode::kLossTwice);
  // 24 first-lap nodes, 12 later ones (one in six) and the last.
  ASSERT_EQ(reduced.size(), 37u);
  ASSERT_EQ(dropped.size(), 37u);
  ASSERT_EQ(twice.size(), 37u);
  double worst = 0, worst_dropped = 0, worst_twice = 0, se_full = 0, se_reduced = 0;
  for (const auto& [id, p] : reduced) {
    const Pose2& t = truth[static_cast<size_t>(id)];  // vertex 0 is held at the origin
    worst = std::max(worst, Distance(p, full.at(id)));
    worst_dropped = std::max(worst_dropped, Distance(dropped.at(id), full.at(id)));
    worst_twice = std::max(worst_twice, Distance(twice.at(id), full.at(id)));
    se_full += std::pow(Distance(full.at(id), t), 2);
    se_reduced += std::pow(Distance(p, t), 2);
  }
  const double n_kept = static_cast<double>(reduced.size());
  const double rmse_full = std::sqrt(se_full / n_kept),
               rmse_reduced = std::sqrt(se_reduced / n_kept);
  std::printf(
      "kept 37 of %d nodes, %zu factors (of %zu); error to the truth RMSE: full graph %.4f m, "
      "reduced %.4f m; from the full graph's solution at most: reduced %.4f m, loops dropped "
      "%.4f m, loss applied twice %.4f m\n",
      total, reduced_factors, g.edges2.size(), rmse_full, rmse_reduced, worst, worst_dropped,
      worst_twice);
  EXPECT_LT(worst, 0.01);
  EXPECT_GT(worst_dropped, 3 * worst);
  EXPECT_GT(worst_twice, 2 * worst);
  EXPECT_LT(rmse_reduced, 1.1 * rmse_full);
}

}  // namespace
}  // namespace omni::pgm
