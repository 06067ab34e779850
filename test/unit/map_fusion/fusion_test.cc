// Map fusion (SLAMfusion): the vote, the alignment on synthetic and real maps, maps left out,
// the options, the node on memq:// and the map_fusion process.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "../../integration/tools/run.h"
#include "../common/test_paths.h"
#include "omni/bus/bus.h"
#include "omni/bus/convert.h"
#include "omni/common/time.h"
#include "omni/eval/eval.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/carmen.h"
#include "omni/io/grid.h"
#include "omni/io/lcm_log.h"
#include "omni/map_fusion/fusion.h"
#include "omni/map_fusion/map_fusion_node.h"
#include "omni/occupancy_grid_t.hpp"

namespace omni::map_fusion {
namespace {

namespace fs = std::filesystem;

TEST(MapFusionVote, MajorityWinsAndTiesFollowTheRule) {
  auto vote = [](size_t unknown, size_t free, size_t occ, TieRule t, bool* tied = nullptr) {
    const size_t v[3] = {unknown, free, occ};
    return VoteCell(v, t, tied);
  };
  bool tied = true;
  EXPECT_EQ(vote(0, 2, 1, TieRule::kOccupied, &tied), 0);  // two of three say free
  EXPECT_FALSE(tied);
  EXPECT_EQ(vote(1, 0, 2, TieRule::kFree), 1);
  EXPECT_EQ(vote(2, 1, 0, TieRule::kOccupied), -1);
  // All three differ, or two maps disagree: the tie rule (the paper: occupied).
  EXPECT_EQ(vote(1, 1, 1, TieRule::kOccupied, &tied), 1);
  EXPECT_TRUE(tied);
  EXPECT_EQ(vote(0, 1, 1, TieRule::kFree), 0);
  EXPECT_EQ(vote(1, 1, 0, TieRule::kUnknown), -1);
  EXPECT_EQ(vote(0, 0, 1, TieRule::kFree), 1);  // a single voter is unanimous
}

// A floor plan of straight walls inside the rectangle [0, w] x [0, h], rasterised at 5 cm into a
// grid whose frame sits at `frame` in the world (a map made by a mapper that started somewhere
// else). Free inside the outer walls, unknown outside. `blob` adds a phantom obstacle (world
// centre, half size); `gap` erases a wall piece (world rectangle) to free.
struct Plan {
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls = {
      {{0, 0}, {8, 0}},   {{8, 0}, {8, 6}},   {{8, 6}, {0, 6}},  {{0, 6}, {0, 0}},
      {{3, 0}, {3, 2.5}}, {{5, 6}, {5, 3.5}}, {{1, 4}, {2.5, 4}}};
  double w = 8, h = 6;
};

// An office floor of 10 x 10 m: square outer walls, a corridor between two rows of rooms. Turned
// by a quarter turn its outer walls fall on themselves and its inner walls run along the same
// axes: occupied cells overlap well, yet the rooms are in the wrong places.
Plan Office() {
  Plan p;
  p.w = p.h = 10;
  p.walls = {{{0, 0}, {10, 0}},  {{10, 0}, {10, 10}},  {{10, 10}, {0, 10}}, {{0, 10}, {0, 0}},
             {{0, 4}, {8.8, 4}}, {{1.2, 6}, {10, 6}},  {{3, 0}, {3, 4}},    {{6.5, 0}, {6.5, 4}},
             {{4, 6}, {4, 10}},  {{7.5, 6}, {7.5, 10}}};
  return p;
}

struct Corruption {
  Eigen::Vector2d blob{-100, -100};
  double blob_half = 0;
  Eigen::Vector4d gap{-100, -100, -100, -100};  // x0 y0 x1 y1
};

io::GridMap Rasterize(const Plan& plan, const Pose2& frame, const Corruption& c = {}) {
  const double res = 0.05;
  io::GridMap m;
  m.resolution_m = res;
  // Extent: the plan's rectangle in the map frame, with a margin.
  const Pose2 inv = frame.Inverse();
  double x0 = 1e9, y0 = 1e9, x1 = -1e9, y1 = -1e9;
  for (const auto& w : {Eigen::Vector2d(0, 0), Eigen::Vector2d(plan.w, 0),
                        Eigen::Vector2d(0, plan.h), Eigen::Vector2d(plan.w, plan.h)}) {
    const Eigen::Vector2d p = inv.Transform(w);
    x0 = std::min(x0, p.x());
    y0 = std::min(y0, p.y());
    x1 = std::max(x1, p.x());
    y1 = std::max(y1, p.y());
  }
  m.origin_x_m = std::floor((x0 - 0.5) / res) * res;
  m.origin_y_m = std::floor((y0 - 0.5) / res) * res;
  m.width = static_cast<int>(std::ceil((x1 + 0.5 - m.origin_x_m) / res));
  m.height = static_cast<int>(std::ceil((y1 + 0.5 - m.origin_y_m) / res));
  m.cells.assign(static_cast<size_t>(m.width) * m.height, -1);
  for (int row = 0; row < m.height; ++row)
    for (int col = 0; col < m.width; ++col) {
      const Eigen::Vector2d w =
          frame.Transform({m.origin_x_m + (col + 0.5) * res, m.origin_y_m + (row + 0.5) * res});
      if (w.x() < -0.05 || w.y() < -0.05 || w.x() > plan.w + 0.05 || w.y() > plan.h + 0.05)
        continue;
      int8_t v = 0;
      for (const auto& [a, b] : plan.walls) {
        const Eigen::Vector2d d = b - a;
        const double t = std::clamp((w - a).dot(d) / d.squaredNorm(), 0.0, 1.0);
        if ((a + t * d - w).norm() < 0.05) v = 100;
      }
      if ((w - c.blob).cwiseAbs().maxCoeff() < c.blob_half) v = 100;
      if (w.x() > c.gap[0] && w.y() > c.gap[1] && w.x() < c.gap[2] && w.y() < c.gap[3]) v = 0;
      m.at(col, row) = v;
    }
  return m;
}

double Error(const io::GridMap& truth, const io::GridMap& m) {
  eval::MapCompareOptions o;
  o.align = false;
  return eval::CompareMaps(truth, m, o).error;
}

TEST(MapFusion, VotesOutEachMapsOwnErrorAndAlignsTheMapMadeElsewhere) {
  const Plan plan;
  const io::GridMap truth = Rasterize(plan, Pose2());
  Corruption ca, cb, cc;
  ca.blob = {6.0, 1.5};  // a phantom obstacle in map A
  ca.blob_half = 0.3;
  cb.gap = {2.9, 0.5, 3.1, 2.0};  // a missing wall piece in map B
  cc.blob = {1.5, 2.0};           // another phantom, in map C, which is also in another frame
  cc.blob_half = 0.25;
  const Pose2 c_frame(0.4, -0.3, 0.1);
  const io::GridMap a = Rasterize(plan, Pose2(), ca), b = Rasterize(plan, Pose2(), cb);
  const io::GridMap c = Rasterize(plan, c_frame, cc);
  // The paper's rule: a map that has not seen a cell votes "unknown" there.
  FusionOptions o;
  o.unknown_votes = true;
  auto r = Fuse({{"A", a}, {"B", b}, {"C", c}}, o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r->base, "A");
  EXPECT_EQ(r->maps_used, 3u);
  for (const auto& s : r->sources) EXPECT_TRUE(s.used) << s.name << ": " << s.reason;
  // C's alignment takes C's frame to A's: a point p of C's frame lands on c_frame * p.
  const eval::MapAlignment& al = r->sources[2].alignment;
  for (const Eigen::Vector2d& p : {Eigen::Vector2d(1, 1), Eigen::Vector2d(6, 4)}) {
    double x, y;
    al.Apply(p.x(), p.y(), &x, &y);
    const Eigen::Vector2d want = c_frame.Transform(p);
    EXPECT_NEAR(x, want.x(), 0.05);
    EXPECT_NEAR(y, want.y(), 0.05);
  }
  EXPECT_NEAR(al.rotation_rad, 0.1, 0.01);
  // Each map's own error is outvoted: the fused map is better than every input.
  const double ea = Error(truth, a), eb = Error(truth, b);
  const double ec = eval::CompareMaps(truth, c).error;
  const double ef = Error(truth, r->fused);
  RecordProperty("errors_a_b_c_fused", std::to_string(ea) + " " + std::to_string(eb) + " " +
                                           std::to_string(ec) + " " + std::to_string(ef));
  EXPECT_LT(ef, 0.55 * std::min({ea, eb, ec}))  // measured: 12, 7.7, 35 -> 3.9
      << "A " << ea << " B " << eb << " C " << ec << " fused " << ef;
  auto at = [&](const io::GridMap& m, double x, double y) {
    return eval::NormalizedCell(m.at(static_cast<int>(std::floor((x - m.origin_x_m) / 0.05)),
                                     static_cast<int>(std::floor((y - m.origin_y_m) / 0.05))));
  };
  EXPECT_EQ(at(r->fused, 6.0, 1.5), 0);  // A's phantom is gone
  EXPECT_EQ(at(r->fused, 1.5, 2.0), 0);  // C's too
  EXPECT_EQ(at(r->fused, 3.0, 1.2), 1);  // B's missing wall is back
  EXPECT_EQ(at(r->fused, 0.7, 0.7), 0);  // free space stays free
  EXPECT_GT(r->unanimous, 0u);
  EXPECT_GT(r->majority, 0u);
  // The default lets maps abstain where they have not seen a cell: every corruption is still
  // outvoted, but where only the rotated map C has a value (its walls' resampling residue just
  // outside the others' outer walls) that value stands: the price of keeping what only one
  // mapper saw (measured: fused error 20.4 here, against 3.9 with the paper's rule).
  auto abstain = Fuse({{"A", a}, {"B", b}, {"C", c}}, FusionOptions{});
  ASSERT_TRUE(abstain.ok());
  EXPECT_EQ(at(abstain->fused, 6.0, 1.5), 0);
  EXPECT_EQ(at(abstain->fused, 1.5, 2.0), 0);
  EXPECT_EQ(at(abstain->fused, 3.0, 1.2), 1);
  const double eab = Error(truth, abstain->fused);
  RecordProperty("error_fused_abstaining", std::to_string(eab));
  EXPECT_LT(eab, ec);
  EXPECT_GT(eab, ef);
}

TEST(MapFusion, PreviousAlignmentsAreTrackedAndABadOneFallsBackToTheFullSearch) {
  const Plan plan;
  const Pose2 c_frame(0.4, -0.3, 0.1);
  const io::GridMap a = Rasterize(plan, Pose2()), b = Rasterize(plan, c_frame);
  FusionOptions o;
  AlignmentHints hints;
  auto first = Fuse({{"A", a}, {"B", b}}, o, &hints);
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(first->alignments_searched, 1u);
  EXPECT_EQ(first->alignments_tracked, 0u);
  ASSERT_EQ(hints.base, "A");
  ASSERT_EQ(hints.by_name.count("B"), 1u);
  // B has grown (a wider grid: another centre) but not moved: tracked, same transform.
  io::GridMap grown = b;
  grown.origin_x_m -= 1.0;
  grown.width += 20;
  grown.cells.assign(static_cast<size_t>(grown.width) * grown.height, -1);
  for (int row = 0; row < b.height; ++row)
    for (int col = 0; col < b.width; ++col) grown.at(col + 20, row) = b.at(col, row);
  auto second = Fuse({{"A", a}, {"B", grown}}, o, &hints);
  ASSERT_TRUE(second.ok());
  EXPECT_EQ(second->alignments_tracked, 1u);
  EXPECT_EQ(second->alignments_searched, 0u);
  const auto& t1 = first->sources[1].alignment;
  const auto& t2 = second->sources[1].alignment;
  for (const Eigen::Vector2d& p : {Eigen::Vector2d(1, 1), Eigen::Vector2d(6, 4)}) {
    double x1, y1, x2, y2;
    t1.Apply(p.x(), p.y(), &x1, &y1);
    t2.Apply(p.x(), p.y(), &x2, &y2);
    EXPECT_NEAR(x1, x2, 0.03);
    EXPECT_NEAR(y1, y2, 0.03);
  }
  EXPECT_EQ(second->fused.cells, first->fused.cells);
  // A hint that is far off: the small search finds little overlap, the full search runs.
  hints.by_name["B"].rotation_rad += 0.3;
  hints.by_name["B"].dx_m += 1.0;
  auto third = Fuse({{"A", a}, {"B", b}}, o, &hints);
  ASSERT_TRUE(third.ok());
  EXPECT_EQ(third->alignments_searched, 1u);
  EXPECT_NEAR(third->sources[1].alignment.rotation_rad, 0.1, 0.01);
  // Another base: the hints are dropped.
  o.base = "B";
  auto other = Fuse({{"A", a}, {"B", b}}, o, &hints);
  ASSERT_TRUE(other.ok());
  EXPECT_EQ(hints.base, "B");
  EXPECT_EQ(other->alignments_searched, 1u);
}

TEST(MapFusion, MapsThatDoNotAlignOrAreEmptyAreLeftOutWithTheReason) {
  const Plan plan;
  Plan other;
  other.walls = {{{0, 0}, {2, 7}}, {{5, 1}, {9, 1.5}}};  // not the same place
  const io::GridMap a = Rasterize(plan, Pose2()), b = Rasterize(plan, Pose2(0.1, 0, 0));
  io::GridMap empty;
  FusionOptions o;
  auto r =
      Fuse({{"A", a}, {"B", b}, {"other", Rasterize(other, Pose2(3, 2, 1.0))}, {"e", empty}}, o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r->maps_used, 2u);
  EXPECT_FALSE(r->sources[2].used);
  EXPECT_NE(r->sources[2].reason.find("alignment overlap"), std::string::npos);
  EXPECT_FALSE(r->sources[3].used);
  EXPECT_NE(r->sources[3].reason.find("empty"), std::string::npos);
  // Too few left: an error that says why each one was left out.
  o.min_maps = 3;
  std::vector<SourceReport> reports;
  auto bad = Fuse({{"A", a}, {"other", Rasterize(other, Pose2(3, 2, 1.0))}}, o, nullptr, &reports);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("other: alignment overlap"), std::string::npos)
      << bad.error().message;
  // The reports come out with the error too (the node counts what it left out from them).
  ASSERT_EQ(reports.size(), 2u);
  EXPECT_TRUE(reports[0].used);
  EXPECT_FALSE(reports[1].used);
  EXPECT_NE(reports[1].reason.find("alignment overlap"), std::string::npos);
  // A configured base that is not there is an error, not a silent choice.
  o.min_maps = 2;
  o.base = "GRID_PG";
  auto nobase = Fuse({{"A", a}, {"B", b}}, o);
  ASSERT_FALSE(nobase.ok());
  EXPECT_NE(nobase.error().message.find("GRID_PG"), std::string::npos);
  o.base = "B";
  auto on_b = Fuse({{"A", a}, {"B", b}}, o);
  ASSERT_TRUE(on_b.ok());
  EXPECT_EQ(on_b->base, "B");
  EXPECT_EQ(on_b->fused.origin_x_m, b.origin_x_m);
}

TEST(MapFusion, UnknownAbstainsUnlessItVotes) {
  // Map B has seen only half of the floor. With unknown abstaining (the default) A's other half
  // survives; with the paper's rule two maps tie there (unknown vs A's value) and the tie rule
  // decides.
  const Plan plan;
  const io::GridMap a = Rasterize(plan, Pose2());
  io::GridMap b = a;
  for (int row = 0; row < b.height; ++row)
    for (int col = b.width / 2; col < b.width; ++col) b.at(col, row) = -1;
  FusionOptions o;
  o.align.align = false;
  auto abstain = Fuse({{"A", a}, {"B", b}}, o);
  ASSERT_TRUE(abstain.ok());
  EXPECT_EQ(abstain->fused.cells, a.cells);
  o.unknown_votes = true;
  o.tie = TieRule::kUnknown;
  auto voted = Fuse({{"A", a}, {"B", b}}, o);
  ASSERT_TRUE(voted.ok());
  EXPECT_EQ(voted->fused.cells, b.cells);
}

// A map that adds obstacles the base has as free space (a forward camera's 3D map keeps the
// people it saw once, docs/sim.md "People") conflicts one way only: its walls are the base's
// walls. It is not left out like a misaligned map, and with a third map the vote removes what
// only it has.
TEST(MapFusion, AMapWithObstaclesTheOthersLackIsVotedOnNotLeftOut) {
  const Plan office = Office();
  const io::GridMap truth = Rasterize(office, Pose2());
  io::GridMap ghosts = truth;
  // Six trails of people it saw once, 0.3 m wide, in the corridor and the rooms.
  const std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> trails = {
      {{1, 5}, {8, 5}},   {{1, 1}, {2.5, 3}}, {{3.5, 1}, {6, 3}},
      {{7, 1}, {9.5, 3}}, {{1, 7}, {3.5, 9}}, {{4.5, 7}, {9.5, 9.5}}};
  for (int row = 0; row < ghosts.height; ++row)
    for (int col = 0; col < ghosts.width; ++col) {
      const Eigen::Vector2d w(ghosts.origin_x_m + (col + 0.5) * ghosts.resolution_m,
                              ghosts.origin_y_m + (row + 0.5) * ghosts.resolution_m);
      for (const auto& [a, b] : trails) {
        const Eigen::Vector2d d = b - a;
        const double t = std::clamp((w - a).dot(d) / d.squaredNorm(), 0.0, 1.0);
        if ((a + t * d - w).norm() < 0.15) ghosts.at(col, row) = 100;
      }
    }
  const io::GridMap other = Rasterize(office, Pose2(0.3, -0.2, 0.05));
  FusionOptions o;
  auto r = Fuse({{"A", truth}, {"ghosts", ghosts}, {"other", other}}, o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const SourceReport& g = r->sources[1];
  std::printf(
      "ghost trails: conflicts %.3f (its walls on the base's free space %.3f, the base's on "
      "its %.3f)\n",
      g.conflict_fraction, g.walls_on_base_free, g.base_walls_on_free);
  EXPECT_GT(g.conflict_fraction, o.max_conflict_fraction) << "would have been left out before";
  EXPECT_LT(g.base_walls_on_free, 0.01);
  EXPECT_TRUE(g.used) << g.reason;
  EXPECT_EQ(r->maps_used, 3u);
  // Where two maps say free the vote removes the trails: with a third copy of the floor (the
  // maps' own frames, no search) the fused map is the floor itself.
  o.align.align = false;
  auto voted = Fuse({{"A", truth}, {"ghosts", ghosts}, {"again", truth}}, o);
  ASSERT_TRUE(voted.ok());
  EXPECT_TRUE(voted->sources[1].used) << voted->sources[1].reason;
  EXPECT_EQ(voted->fused.cells, truth.cells);
  EXPECT_NE(ReportJson(*r).find("\"walls_on_base_free\""), std::string::npos);
  // With the base alone nothing could outvote its trails (a tie, and `tie: occupied` would keep
  // them): it is left out, and one map is too few to fuse.
  o.align.align = true;
  std::vector<SourceReport> reports;
  auto two = Fuse({{"A", truth}, {"ghosts", ghosts}}, o, nullptr, &reports);
  ASSERT_FALSE(two.ok());
  ASSERT_EQ(reports.size(), 2u);
  EXPECT_FALSE(reports[1].used);
  EXPECT_NE(reports[1].reason.find("too few other maps"), std::string::npos) << reports[1].reason;
  o.min_maps = 1;
  auto alone = Fuse({{"A", truth}, {"ghosts", ghosts}}, o);
  ASSERT_TRUE(alone.ok()) << alone.error().message;
  EXPECT_EQ(alone->maps_used, 1u);
  EXPECT_EQ(alone->fused.cells, truth.cells);
}

// fusion.json names the maps by their files' paths offline: a path with quotes, a backslash or
// a newline, or of any length, still gives well-formed JSON (names used to go through a
// 1024-byte buffer unescaped).
TEST(MapFusion, ReportJsonEscapesNamesAndTakesLongOnes) {
  const io::GridMap a = Rasterize(Plan(), Pose2());
  const std::string odd = "maps/\"odd\"\\name\n.yaml";
  const std::string long_name = std::string(3000, 'x') + ".yaml";
  FusionOptions o;
  o.align.align = false;
  auto r = Fuse({{odd, a}, {long_name, a}}, o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const std::string json = ReportJson(*r);
  EXPECT_NE(json.find("\"base\": \"maps/\\\"odd\\\"\\\\name\\u000a.yaml\""), std::string::npos)
      << json.substr(0, 200);
  EXPECT_NE(json.find("\"name\": \"" + long_name + "\", \"used\": true"), std::string::npos);
  EXPECT_EQ(json.substr(json.size() - 2), "]}");
  EXPECT_EQ(json.find('\n'), std::string::npos);  // no raw newline inside
}

// A mapper that restarted mid-run starts its map frame at the robot's pose of the moment: here
// turned by a quarter turn (outside the rotation search) and shifted. In a rectilinear building
// its walls still overlap the base's well enough for min_overlap_fraction, but its walls cross
// the base's rooms and its rooms the base's walls: the conflict check leaves it out.
TEST(MapFusion, AMapTurnedByAQuarterTurnInARectilinearBuildingIsLeftOut) {
  const Plan office = Office();
  const io::GridMap truth = Rasterize(office, Pose2());
  const io::GridMap turned = Rasterize(office, Pose2(10.6, -0.4, M_PI / 2));
  const io::GridMap other = Rasterize(office, Pose2(0.3, -0.2, 0.05));
  FusionOptions o;
  auto r = Fuse({{"A", truth}, {"turned", turned}, {"other", other}}, o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const SourceReport& t = r->sources[1];
  std::printf(
      "quarter turn: overlap %.2f, conflicts %.3f; the unturned copy: overlap %.2f, "
      "conflicts %.3f\n",
      t.overlap_fraction, t.conflict_fraction, r->sources[2].overlap_fraction,
      r->sources[2].conflict_fraction);
  EXPECT_FALSE(t.used);
  EXPECT_GE(t.overlap_fraction, o.min_overlap_fraction) << "the overlap gate alone lets it in";
  EXPECT_GT(t.conflict_fraction, o.max_conflict_fraction);
  // Both ways: its walls across the base's rooms and the base's across its.
  EXPECT_GT(t.walls_on_base_free, 0.5 * o.max_conflict_fraction);
  EXPECT_GT(t.base_walls_on_free, 0.5 * o.max_conflict_fraction);
  EXPECT_NE(t.reason.find("max_conflict_fraction"), std::string::npos) << t.reason;
  EXPECT_TRUE(r->sources[2].used) << r->sources[2].reason;
  EXPECT_LT(r->sources[2].conflict_fraction, 0.5 * o.max_conflict_fraction);
  EXPECT_EQ(r->maps_used, 2u);
  auto without = Fuse({{"A", truth}, {"other", other}}, o);
  ASSERT_TRUE(without.ok());
  EXPECT_EQ(r->fused.cells, without->fused.cells);
  EXPECT_NE(ReportJson(*r).find("\"conflict_fraction\""), std::string::npos);
  // Alone with the base, the turned map would tie with it on every cell they disagree on, and the
  // tie rule (occupied) would put its walls across the base's rooms: with the check there is too
  // little left to fuse; without it (max_conflict_fraction 1) the fused map is corrupted.
  std::vector<SourceReport> reports;
  auto two = Fuse({{"A", truth}, {"turned", turned}}, o, nullptr, &reports);
  ASSERT_FALSE(two.ok());
  EXPECT_NE(two.error().message.find("turned: conflicts"), std::string::npos)
      << two.error().message;
  o.max_conflict_fraction = 1.0;
  auto corrupted = Fuse({{"A", truth}, {"turned", turned}}, o);
  ASSERT_TRUE(corrupted.ok());
  EXPECT_TRUE(corrupted->sources[1].used);
  const double corrupted_error = Error(truth, corrupted->fused);
  std::printf("quarter turn fused with the base without the check: error %.1f (the base: 0)\n",
              corrupted_error);
  EXPECT_GT(corrupted_error, 20.0);
}

TEST(MapFusion, ConflictsCountOccupiedCellsOnTheOthersFreeSpace) {
  // 1 x 10 cells: the base free except a wall at 2 and unknown at 9; the other map unknown at 2
  // and occupied at 3 (one cell off the base's wall), 7 (on the base's free space) and 9.
  io::GridMap base;
  base.resolution_m = 0.05;
  base.width = 10;
  base.height = 1;
  base.cells = {0, 0, 100, 0, 0, 0, 0, 0, 0, -1};
  io::GridMap moved = base;
  moved.cells = {0, 0, -1, 100, 0, 0, 0, 100, 0, 100};
  // Cells both know: 0,1,3..8. Occupied there: moved's 3 and 7 (base's 2 is unknown to moved,
  // moved's 9 unknown to the base). Conflicts: 7 only (3 is next to the base's wall at 2).
  MapConflicts c = CountConflicts(base, moved, 1);
  EXPECT_EQ(c.occupied, 2u);
  EXPECT_EQ(c.conflicts, 1u);
  EXPECT_DOUBLE_EQ(c.fraction(), 0.5);
  // No tolerance: 3 is a conflict too. The base's wall on the other's free space counts as well.
  EXPECT_EQ(CountConflicts(base, moved, 0).conflicts, 2u);
  moved.cells[2] = 0;
  c = CountConflicts(base, moved, 1);
  EXPECT_EQ(c.occupied, 3u);
  EXPECT_EQ(c.conflicts, 1u);  // 2 has moved's wall at 3 within one cell
  EXPECT_EQ(CountConflicts(base, moved, 0).conflicts, 3u);
  // Grids of different sizes: nothing counted (Fuse resamples first).
  moved.width = 5;
  moved.cells.resize(5);
  EXPECT_EQ(CountConflicts(base, moved, 1).occupied, 0u);
}

TEST(MapFusion, AlignmentRecoversAKnownTransformOfARealMap) {
  // Two maps of the Intel lab from its corrected log: one at the corrected poses, one with every
  // pose moved by a known rigid transform (as a mapper that started elsewhere would give).
  OMNI_REQUIRE_DATASET(path, "carmen-corrected/intel-corrected.log.gz");
  auto log = io::ReadCarmenLog(path);
  ASSERT_TRUE(log.ok()) << log.error().message;
  const Pose2 t(0.6, -0.4, 0.15);
  io::LogOddsGrid g1, g2;
  int n = 0;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    if (++n % 4) continue;  // every fourth scan is plenty for a map
    const auto& l = r.laser;
    g1.IntegrateScan(l.laser_pose, l.ranges_m, l.angle_min_rad, l.angle_increment_rad,
                     l.max_range_m);
    g2.IntegrateScan(t * l.laser_pose, l.ranges_m, l.angle_min_rad, l.angle_increment_rad,
                     l.max_range_m);
  }
  const io::GridMap m1 = g1.ToGridMap(), m2 = g2.ToGridMap();
  eval::MapCompareOptions o;
  const eval::MapAlignment a = eval::AlignMap(m1, m2, o);
  // A point q of m2's frame is t * p for the point p of m1's frame: the alignment must undo t.
  for (const Eigen::Vector2d& p :
       {Eigen::Vector2d(0, 0), Eigen::Vector2d(-10, 5), Eigen::Vector2d(5, -10)}) {
    const Eigen::Vector2d q = t.Transform(p);
    double x, y;
    a.Apply(q.x(), q.y(), &x, &y);
    EXPECT_NEAR(x, p.x(), 0.1) << p.transpose();
    EXPECT_NEAR(y, p.y(), 0.1) << p.transpose();
  }
  EXPECT_NEAR(a.rotation_rad, -0.15, 0.005);
  EXPECT_GT(static_cast<double>(a.overlap) / static_cast<double>(a.occupied), 0.9);
  // The tracking search (what Fuse runs from a previous alignment), started 2 cm / 0.01 rad off,
  // lands on the same transform. (Its time is printed, not asserted.)
  eval::MapAlignment guess = a;
  guess.rotation_rad += 0.01;
  guess.dx_m += 0.02;
  eval::MapCompareOptions near = o;
  near.max_rotation_rad = kTrackRotationRad;
  near.max_shift_m = kTrackShiftM;
  near.coarse_steps = 2;
  near.refine_divisions = 2;
  near.levels = 9;
  const auto t0 = std::chrono::steady_clock::now();
  const eval::MapAlignment full = eval::AlignMap(m1, m2, o);
  const auto t1 = std::chrono::steady_clock::now();
  const eval::MapAlignment tracked = eval::AlignMap(m1, m2, near, &guess);
  const auto t2 = std::chrono::steady_clock::now();
  // The rotations are shared out among threads; the answer must not depend on how many.
  eval::MapCompareOptions one = o;
  one.threads = 1;
  const eval::MapAlignment single = eval::AlignMap(m1, m2, one);
  const auto t3 = std::chrono::steady_clock::now();
  eval::MapCompareOptions three = o;
  three.threads = 3;
  const eval::MapAlignment odd = eval::AlignMap(m1, m2, three);
  for (const eval::MapAlignment* other : {&single, &odd}) {
    EXPECT_EQ(other->rotation_rad, full.rotation_rad);
    EXPECT_EQ(other->dx_m, full.dx_m);
    EXPECT_EQ(other->dy_m, full.dy_m);
    EXPECT_EQ(other->overlap, full.overlap);
  }
  std::printf(
      "AlignMap on the Intel lab (%zu occupied cells): full search %.0f ms (%.0f ms on one "
      "thread), tracking %.0f ms\n",
      full.occupied, std::chrono::duration<double, std::milli>(t1 - t0).count(),
      std::chrono::duration<double, std::milli>(t3 - t2).count(),
      std::chrono::duration<double, std::milli>(t2 - t1).count());
  EXPECT_NEAR(tracked.rotation_rad, full.rotation_rad, 0.003);
  EXPECT_GE(tracked.overlap + tracked.occupied / 100, full.overlap);
}

// A larger building (MIT CSAIL, about 60 m across) against a copy moved by a known transform
// about its centre. With a first rotation step of range / 8 (0.044 rad), its outer walls moved by
// over a metre per step and the search settled 0.17 m off (overlap 0.80, which passes the
// fusion's overlap gate); the step is now also bounded by the map's extent. And the bound on the
// cells scored (map_fusion's `align.max_cells`) finds the same alignment as every cell, reporting
// the overlap over every cell.
TEST(MapFusion, ALargeBuildingIsAlignedWithTheCellsBounded) {
  OMNI_REQUIRE_DATASET(path, "carmen-corrected/csail-corrected.log.gz");
  auto log = io::ReadCarmenLog(path);
  ASSERT_TRUE(log.ok()) << log.error().message;
  io::GridMap base, moved;
  Pose2 t;
  for (int pass = 0; pass < 2; ++pass) {
    io::LogOddsGrid g;
    int n = 0;
    for (const auto& r : log->records) {
      if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
      if (++n % 4) continue;
      const auto& l = r.laser;
      g.IntegrateScan(pass == 0 ? l.laser_pose : t * l.laser_pose, l.ranges_m, l.angle_min_rad,
                      l.angle_increment_rad, l.max_range_m);
    }
    if (pass == 1) {
      moved = g.ToGridMap();
      break;
    }
    base = g.ToGridMap();
    const Pose2 c(base.origin_x_m + base.width * base.resolution_m / 2,
                  base.origin_y_m + base.height * base.resolution_m / 2, 0);
    t = c * Pose2(0.6, -0.4, 0.15) * c.Inverse();
  }
  auto error_m = [&](const eval::MapAlignment& a) {
    double worst = 0;
    for (const Eigen::Vector2d& p :
         {Eigen::Vector2d(base.origin_x_m, base.origin_y_m),
          Eigen::Vector2d(base.origin_x_m + base.width * base.resolution_m,
                          base.origin_y_m + base.height * base.resolution_m)}) {
      const Eigen::Vector2d q = t.Transform(p);
      double x, y;
      a.Apply(q.x(), q.y(), &x, &y);
      worst = std::max(worst, std::hypot(x - p.x(), y - p.y()));
    }
    return worst;
  };
  eval::MapCompareOptions all;
  ASSERT_EQ(all.max_cells, 0);
  const eval::MapAlignment a = eval::AlignMap(base, moved, all);
  const eval::MapCompareOptions bounded = FusionOptions().align;
  ASSERT_GT(bounded.max_cells, 0);
  ASSERT_GT(a.occupied, static_cast<size_t>(bounded.max_cells)) << "the bound must bite";
  const eval::MapAlignment b = eval::AlignMap(base, moved, bounded);
  EXPECT_LT(error_m(a), 0.1);
  EXPECT_LT(error_m(b), 0.1);
  // The data does show the fault: the step of range / coarse_steps alone lands off.
  eval::MapCompareOptions old_step = all;
  old_step.rotation_step_from_extent = false;
  EXPECT_GT(error_m(eval::AlignMap(base, moved, old_step)), 0.1);
  EXPECT_EQ(b.occupied, a.occupied);
  EXPECT_GT(static_cast<double>(a.overlap) / static_cast<double>(a.occupied), 0.95);
  EXPECT_GT(static_cast<double>(b.overlap) / static_cast<double>(b.occupied), 0.95);
  // The reported overlap is a count over every cell at the alignment found.
  eval::MapCompareOptions at_b = all;
  at_b.align = false;
  EXPECT_EQ(eval::AlignMap(base, moved, at_b, &b).overlap, b.overlap);
  std::printf("CSAIL (%zu occupied cells): error %.3f m every cell, %.3f m bounded to %d\n",
              a.occupied, error_m(a), error_m(b), bounded.max_cells);
}

TEST(MapFusionOptions, ShippedConfigLoadsAndMistakesAreErrors) {
  auto r = ConfigReader::FromFile(std::string(OMNI_SOURCE_DIR) + "/config/map_fusion.yaml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  auto o = FusionOptions::Load(*r);
  ASSERT_TRUE(o.ok()) << o.error().message;
  const FusionOptions d;
  EXPECT_EQ(o->grid_channels, d.grid_channels);
  EXPECT_EQ(o->unknown_votes, d.unknown_votes);
  EXPECT_EQ(o->tie, d.tie);
  EXPECT_EQ(o->min_overlap_fraction, d.min_overlap_fraction);
  EXPECT_EQ(o->max_conflict_fraction, d.max_conflict_fraction);
  EXPECT_EQ(o->align.max_shift_m, d.align.max_shift_m);
  EXPECT_EQ(o->align.max_cells, d.align.max_cells);
  auto bad = ConfigReader::FromString(
      "tie: sometimes\nmin_maps: 0\nbase: GRID_X\nmax_conflict_fraction: 1.5\nalign:\n"
      "  max_shfit_m: 3\n",
      "bad.yaml");
  ASSERT_TRUE(bad.ok());
  auto e = FusionOptions::Load(*bad);
  ASSERT_FALSE(e.ok());
  for (const char* key : {"tie", "min_maps", "base", "max_conflict_fraction", "align.max_shfit_m"})
    EXPECT_NE(e.error().message.find(key), std::string::npos) << key << "\n" << e.error().message;
  // More maps wanted than channels listed: on the bus it could never fuse, so it is refused there.
  auto never =
      ConfigReader::FromString("grid_channels: [GRID_PG, GRID_RBPF]\nmin_maps: 3\n", "n.yaml");
  ASSERT_TRUE(never.ok());
  auto n = FusionOptions::Load(*never);
  ASSERT_TRUE(n.ok()) << "offline fusion of three files may use it";
  const Status bus = n->ValidateForBus();
  ASSERT_FALSE(bus.ok());
  EXPECT_NE(bus.message().find("could never fuse"), std::string::npos) << bus.message();
  // A channel listed twice would be two votes of one mapper.
  auto twice = ConfigReader::FromString("grid_channels: [GRID_PG, GRID_PG]\n", "t.yaml");
  ASSERT_TRUE(twice.ok());
  auto t = FusionOptions::Load(*twice);
  ASSERT_FALSE(t.ok());
  EXPECT_NE(t.error().message.find("lists GRID_PG twice"), std::string::npos) << t.error().message;
  // Its own output among its inputs would vote for the last fusion for ever; a size cap below a
  // useful map, or above what the bus can carry, is a mistake.
  auto own = ConfigReader::FromString(
      "grid_channels: [GRID_PG, GRID_FUSED]\nmax_input_cells: 100\n", "o.yaml");
  ASSERT_TRUE(own.ok());
  auto w = FusionOptions::Load(*own);
  ASSERT_FALSE(w.ok());
  EXPECT_NE(w.error().message.find("GRID_FUSED is also in grid_channels"), std::string::npos)
      << w.error().message;
  EXPECT_NE(w.error().message.find("max_input_cells"), std::string::npos) << w.error().message;
}

omni::occupancy_grid_t GridMsg(const io::GridMap& m, int64_t utime, const std::string& source) {
  auto g = bus::ToGridMessage(m, utime, source);
  EXPECT_TRUE(g.ok()) << g.error().message;
  return g.ok() ? *g : omni::occupancy_grid_t{};
}

// A grid whose cells are turned in the map frame (occupancy_grid_t.origin_yaw_rad, a ROS map
// with a yaw) arrives resampled onto the frame's axes, so it lies on the world without any
// alignment; read as if unturned it would be off by the turn.
TEST(MapFusion, AGridTurnedInItsFrameIsResampledOntoTheFramesAxes) {
  const Plan plan;
  const Pose2 turn(0.4, -0.2, 0.3);
  const io::GridMap g = Rasterize(plan, turn);  // cells along the turned frame's axes
  omni::occupancy_grid_t msg = GridMsg(g, 0, "other");
  const Eigen::Vector2d corner = turn.Transform({g.origin_x_m, g.origin_y_m});
  msg.origin_x_m = corner.x();
  msg.origin_y_m = corner.y();
  msg.origin_yaw_rad = turn.theta;
  auto back = bus::FromGridMessage(msg);
  ASSERT_TRUE(back.ok()) << back.error().message;
  const io::GridMap truth = Rasterize(plan, Pose2());
  eval::MapCompareOptions o;
  o.align = false;
  const auto right = eval::CompareMaps(truth, *back, o);
  EXPECT_GT(right.precision, 0.95);
  EXPECT_GT(right.recall, 0.95);
  msg.origin_yaw_rad = 0;  // the turn ignored, as before
  auto wrong = bus::FromGridMessage(msg);
  ASSERT_TRUE(wrong.ok());
  const auto bad = eval::CompareMaps(truth, *wrong, o);
  EXPECT_LT(bad.precision, 0.5);
  EXPECT_LT(right.error, 0.5 * bad.error) << right.error << " vs " << bad.error;
}

// The node fuses on a worker thread and publishes from Tick: ticks until no fusion runs.
void TickUntilIdle(MapFusionNode& node) {
  node.Tick();
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (node.fusing() && std::chrono::steady_clock::now() < until) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    node.Tick();
  }
  EXPECT_FALSE(node.fusing());
}

TEST(MapFusionNode, FusesTheLatestGridsAndCountsBadOnes) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  ManualClock clock(1700000000000000);
  FusionOptions o;
  o.fuse_interval_s = 1.0;
  MapFusionNode node(&b, o, &clock);
  std::vector<omni::occupancy_grid_t> fused;
  int heartbeats = 0;
  bool counters_seen = false;
  b.Subscribe<omni::occupancy_grid_t>(
      "GRID_FUSED", [&](const omni::occupancy_grid_t& g, int64_t) { fused.push_back(g); });
  b.Subscribe<omni::heartbeat_t>("HEARTBEAT", [&](const omni::heartbeat_t& h, int64_t) {
    EXPECT_EQ(h.process, "map_fusion");
    for (const auto& n : h.counter_names) counters_seen |= n == "grids_rejected";
    ++heartbeats;
  });
  auto pump = [&] {
    while (b.HandleTimeout(0) > 0) {
    }
  };
  const Plan plan;
  Corruption cb;
  cb.gap = {2.9, 0.5, 3.1, 2.0};
  // One map only: nothing to fuse yet.
  b.Publish("GRID_PG", GridMsg(Rasterize(plan, Pose2()), clock.NowUtime(), "posegraph"));
  pump();
  TickUntilIdle(node);
  pump();
  EXPECT_TRUE(fused.empty());
  // Bad grids: undecodable, inconsistent, a non-finite turn, another frame. All counted, none
  // held. (A finite turn is resampled onto the frame's axes: FromGridMessage.)
  b.PublishRaw("GRID_RBPF", "junk", 4);
  auto inconsistent = GridMsg(Rasterize(plan, Pose2()), clock.NowUtime(), "rbpf");
  inconsistent.num_cells -= 1;
  b.Publish("GRID_RBPF", inconsistent);
  auto rotated = GridMsg(Rasterize(plan, Pose2()), clock.NowUtime(), "rbpf");
  rotated.origin_yaw_rad = std::nan("");
  b.Publish("GRID_RBPF", rotated);
  auto other = GridMsg(Rasterize(plan, Pose2()), clock.NowUtime(), "rbpf");
  other.frame = "odom";
  b.Publish("GRID_RBPF", other);
  pump();
  TickUntilIdle(node);
  pump();
  EXPECT_TRUE(fused.empty());
  EXPECT_EQ(node.grids_rejected(), 3);
  EXPECT_EQ(b.counters().decode_errors.load(), 1);
  // A second map of another place: it does not align, so with min_maps 2 there is no fusion —
  // and the map left out is counted as such, not only the failed fusion (it used to be counted
  // only when a fusion succeeded without it).
  Plan elsewhere;
  elsewhere.walls = {{{0, 0}, {2, 7}}, {{5, 1}, {9, 1.5}}};
  b.Publish("GRID_RBPF", GridMsg(Rasterize(elsewhere, Pose2(3, 2, 1.0)), clock.NowUtime(), "rbpf"));
  pump();
  clock.Advance(1100000);
  TickUntilIdle(node);
  pump();
  EXPECT_TRUE(fused.empty());
  EXPECT_EQ(node.fusion_failures(), 1);
  EXPECT_EQ(node.sources_rejected(), 1);
  // A second good map (in another frame, with its own error): fused and published.
  b.Publish("GRID_RBPF",
            GridMsg(Rasterize(plan, Pose2(0.3, 0.2, -0.05), cb), clock.NowUtime() + 1000, "rbpf"));
  pump();
  clock.Advance(1100000);
  TickUntilIdle(node);
  pump();
  ASSERT_EQ(fused.size(), 1u);
  EXPECT_EQ(fused[0].source, "fused");
  EXPECT_EQ(node.fusions(), 1);
  ASSERT_TRUE(node.last().has_value());
  EXPECT_EQ(node.last()->maps_used, 2u);
  EXPECT_EQ(node.last()->base, "GRID_PG");
  // Nothing changed: no new fusion, whatever the time.
  clock.Advance(5000000);
  TickUntilIdle(node);
  pump();
  EXPECT_EQ(fused.size(), 1u);
  // A third map: fused again once the interval has passed.
  b.Publish("GRID_OCTO", GridMsg(Rasterize(plan, Pose2()), clock.NowUtime(), "octomap"));
  pump();
  TickUntilIdle(node);
  pump();
  EXPECT_EQ(fused.size(), 2u);
  EXPECT_EQ(node.last()->maps_used, 3u);
  const std::string out = ::testing::TempDir() + "/fusion_node_out";
  ASSERT_TRUE(node.WriteOutputs(out).ok());
  omni::testing::ExpectOnlyListedFiles(out, MapFusionNode::OutputFiles());
  EXPECT_TRUE(fs::exists(out + "/fused_map.pgm"));
  EXPECT_TRUE(fs::exists(out + "/fused_map.yaml"));
  EXPECT_TRUE(fs::exists(out + "/fused_map.png"));
  std::ifstream js(out + "/fusion.json");
  const std::string json((std::istreambuf_iterator<char>(js)), std::istreambuf_iterator<char>());
  EXPECT_NE(json.find("\"name\": \"GRID_OCTO\""), std::string::npos) << json;
  pump();
  EXPECT_GE(heartbeats, 1);
  EXPECT_TRUE(counters_seen);
}

// A fusion of large maps takes longer than the supervisor's heartbeat timeout (6.6 s for 108k
// occupied cells against 5 s): it runs on a worker while the loop keeps heartbeating and
// receiving grids. Here the fusion is held (a test hook around Fuse) until three heartbeats
// came while it ran; heartbeats on the real clock, about a second apart.
TEST(MapFusionNode, KeepsHeartbeatingAndReceivingWhileASlowFusionRuns) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  SystemClock clock;
  FusionOptions o;
  o.fuse_interval_s = 0.05;
  MapFusionNode node(&b, o, &clock);
  std::atomic<bool> release{false};
  std::atomic<int64_t> hold_until_us{0};
  std::atomic<int> fuse_calls{0};
  node.SetFuseFunctionForTest([&](const std::vector<SourceMap>& maps, const FusionOptions& opt,
                                  AlignmentHints* hints, std::vector<SourceReport>* reports) {
    ++fuse_calls;
    while (!release && MonotonicMicros() < hold_until_us)
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    return Fuse(maps, opt, hints, reports);
  });
  struct Beat {
    int64_t mono_us;
    int64_t fusing;
    std::string text;
  };
  std::vector<Beat> beats;
  std::vector<omni::occupancy_grid_t> fused;
  b.Subscribe<omni::heartbeat_t>("HEARTBEAT", [&](const omni::heartbeat_t& h, int64_t) {
    Beat beat{MonotonicMicros(), -1, h.status_text};
    for (size_t i = 0; i < h.counter_names.size(); ++i)
      if (h.counter_names[i] == "fusing") beat.fusing = h.counter_values[i];
    beats.push_back(beat);
  });
  b.Subscribe<omni::occupancy_grid_t>(
      "GRID_FUSED", [&](const omni::occupancy_grid_t& g, int64_t) { fused.push_back(g); });
  auto pump = [&] {
    while (b.HandleTimeout(0) > 0) {
    }
  };
  // The main loop: what RunNodeLoop does, every 20 ms, until `done` or `seconds` passed.
  auto loop = [&](double seconds, const std::function<bool()>& done) {
    const int64_t end = MonotonicMicros() + static_cast<int64_t>(seconds * 1e6);
    while (!done() && MonotonicMicros() < end) {
      pump();
      node.Tick();
      pump();
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  };
  auto fusing_beats = [&] {
    int n = 0;
    for (const auto& beat : beats) n += beat.fusing == 1;
    return n;
  };
  const Plan plan;
  const int64_t t0 = clock.NowUtime();
  hold_until_us = MonotonicMicros() + 8000000;  // released below, or gives up (without the fix)
  b.Publish("GRID_PG", GridMsg(Rasterize(plan, Pose2()), t0, "posegraph"));
  b.Publish("GRID_RBPF", GridMsg(Rasterize(plan, Pose2(0.2, 0.1, 0.03)), t0, "rbpf"));
  loop(6.0, [&] { return fusing_beats() >= 2; });
  // A grid arrives while the fusion runs: received and held (for the next fusion).
  const int64_t grids_before = node.grids_in();
  b.Publish("GRID_OCTO", GridMsg(Rasterize(plan, Pose2()), t0, "octomap"));
  loop(6.0, [&] { return fusing_beats() >= 3; });
  EXPECT_EQ(node.grids_in(), grids_before + 1);
  EXPECT_TRUE(node.fusing());
  EXPECT_EQ(fuse_calls.load(), 1) << "one fusion at a time";
  EXPECT_TRUE(fused.empty());
  ASSERT_GE(fusing_beats(), 3) << "no heartbeat while the fusion ran";
  int64_t max_gap_us = 0;
  for (size_t i = 1; i < beats.size(); ++i)
    max_gap_us = std::max(max_gap_us, beats[i].mono_us - beats[i - 1].mono_us);
  EXPECT_LT(max_gap_us, 2500000) << "heartbeats about once a second (slack for a loaded machine)";
  EXPECT_NE(beats.back().text.find("fusing 2 maps"), std::string::npos) << beats.back().text;
  // Done: published by the next Tick; the grid that came meanwhile is fused next.
  release = true;
  loop(30.0, [&] { return fused.size() >= 2 && !node.fusing(); });
  ASSERT_EQ(fused.size(), 2u);
  EXPECT_EQ(node.fusions(), 2);
  EXPECT_EQ(node.last()->maps_used, 3u);
  EXPECT_EQ(fuse_calls.load(), 2);
  // Shutdown (and MAP_SAVE): a fusion is running when WriteOutputs is called; it waits for it,
  // heartbeating, and writes the fusion of the grids held last.
  release = false;
  hold_until_us = MonotonicMicros() + 3500000;
  b.Publish("GRID_RBPF", GridMsg(Rasterize(plan, Pose2(0.25, 0.1, 0.03)), t0 + 1, "rbpf"));
  pump();
  node.Tick();
  ASSERT_TRUE(node.fusing());
  const size_t beats_before = beats.size();
  const std::string out = ::testing::TempDir() + "/fusion_node_slow_out";
  fs::remove_all(out);
  ASSERT_TRUE(node.WriteOutputs(out).ok());
  EXPECT_FALSE(node.fusing());
  pump();
  EXPECT_GE(beats.size(), beats_before + 2) << "no heartbeat while WriteOutputs waited";
  EXPECT_EQ(fuse_calls.load(), 3) << "the running fusion is the final one: nothing changed since";
  EXPECT_EQ(fused.size(), 3u);
  EXPECT_TRUE(fs::exists(out + "/fused_map.pgm"));
  EXPECT_TRUE(fs::exists(out + "/fusion.json"));
}

TEST(MapFusionNode, AnEmptyGridIsRejectedAndTheChannelKeepsItsLastGoodOne) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  ManualClock clock(1700000000000000);
  FusionOptions o;
  o.fuse_interval_s = 1.0;
  MapFusionNode node(&b, o, &clock);
  auto pump = [&] {
    while (b.HandleTimeout(0) > 0) {
    }
  };
  const Plan plan;
  b.Publish("GRID_PG", GridMsg(Rasterize(plan, Pose2()), clock.NowUtime(), "posegraph"));
  b.Publish("GRID_RBPF", GridMsg(Rasterize(plan, Pose2(0.2, 0.1, 0.03)), clock.NowUtime(), "rbpf"));
  pump();
  TickUntilIdle(node);
  ASSERT_EQ(node.fusions(), 1);
  EXPECT_EQ(node.last()->maps_used, 2u);
  // A mapper that restarted publishes an empty grid (0 x 0), then one it has not seen yet.
  io::GridMap empty;
  empty.resolution_m = 0.05;
  b.Publish("GRID_RBPF", GridMsg(empty, clock.NowUtime(), "rbpf"));
  pump();
  EXPECT_EQ(node.grids_rejected(), 1);
  clock.Advance(1100000);
  TickUntilIdle(node);
  EXPECT_EQ(node.fusions(), 1) << "nothing changed";
  auto r = node.FuseNow();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r->maps_used, 2u);
  io::GridMap unseen = Rasterize(plan, Pose2());
  std::fill(unseen.cells.begin(), unseen.cells.end(), int8_t{-1});
  b.Publish("GRID_RBPF", GridMsg(unseen, clock.NowUtime(), "rbpf"));
  pump();
  EXPECT_EQ(node.grids_rejected(), 2);
  auto again = node.FuseNow();
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_EQ(again->maps_used, 2u);
  EXPECT_EQ(node.fusion_failures(), 0);
}

// A grid larger than max_input_cells is rejected and counted (one absurd message of 2^28 cells
// took gigabytes in the fusion's copies); with `frame: ""` the fused grid goes out in the frame
// its inputs came in, not always "map".
TEST(MapFusionNode, AnOversizedGridIsRejectedAndTheOutputKeepsTheInputsFrame) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  ManualClock clock(1700000000000000);
  const Plan plan;
  const io::GridMap pg = Rasterize(plan, Pose2());
  const io::GridMap rbpf = Rasterize(plan, Pose2(0.2, 0.1, 0.03));
  FusionOptions o;
  o.fuse_interval_s = 1.0;
  o.frame = "";
  o.max_input_cells = static_cast<int64_t>(std::max(pg.cells.size(), rbpf.cells.size())) + 100;
  MapFusionNode node(&b, o, &clock);
  std::vector<std::string> frames;
  b.Subscribe<omni::occupancy_grid_t>(
      "GRID_FUSED", [&](const omni::occupancy_grid_t& g, int64_t) { frames.push_back(g.frame); });
  auto pump = [&] {
    while (b.HandleTimeout(0) > 0) {
    }
  };
  auto in_world = [&](const io::GridMap& m, const std::string& source) {
    omni::occupancy_grid_t g = GridMsg(m, clock.NowUtime(), source);
    g.frame = "world";
    return g;
  };
  io::GridMap big = pg;
  big.width = static_cast<int>(o.max_input_cells / big.height) + 1;
  big.cells.assign(static_cast<size_t>(big.width) * big.height, int8_t{0});
  b.Publish("GRID_OCTO", in_world(big, "octomap"));
  b.Publish("GRID_PG", in_world(pg, "posegraph"));
  b.Publish("GRID_RBPF", in_world(rbpf, "rbpf"));
  pump();
  EXPECT_EQ(node.grids_rejected(), 1);
  clock.Advance(1100000);
  TickUntilIdle(node);
  pump();
  ASSERT_EQ(node.fusions(), 1);
  EXPECT_EQ(node.last()->maps_used, 2u);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0], "world");
}

TEST(MapFusionNode, TheFusedGridIsStampedWithTheNewestGridItUsed) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  ManualClock clock(1700000000000000);
  FusionOptions o;
  o.fuse_interval_s = 1.0;
  MapFusionNode node(&b, o, &clock);
  std::vector<int64_t> stamps;
  b.Subscribe<omni::occupancy_grid_t>(
      "GRID_FUSED", [&](const omni::occupancy_grid_t& g, int64_t) { stamps.push_back(g.utime); });
  auto pump = [&] {
    while (b.HandleTimeout(0) > 0) {
    }
  };
  auto fuse = [&] {
    pump();
    clock.Advance(1100000);
    TickUntilIdle(node);
    pump();
  };
  const Plan plan;
  const int64_t t0 = clock.NowUtime();
  const int64_t future = t0 + 1000000000000;  // 11.6 days ahead: a source clock gone wrong
  b.Publish("GRID_PG", GridMsg(Rasterize(plan, Pose2()), t0, "posegraph"));
  b.Publish("GRID_RBPF", GridMsg(Rasterize(plan, Pose2(0.2, 0.1, 0.03)), future, "rbpf"));
  fuse();
  ASSERT_EQ(stamps.size(), 1u);
  EXPECT_EQ(stamps[0], future);
  // The RBPF's clock is put right: the next fusion is stamped with its grid's time again.
  b.Publish("GRID_RBPF", GridMsg(Rasterize(plan, Pose2(0.2, 0.1, 0.03)), t0 + 2000000, "rbpf"));
  fuse();
  ASSERT_EQ(stamps.size(), 2u);
  EXPECT_EQ(stamps[1], t0 + 2000000);
  // A map that is left out (it does not align) does not stamp the fusion either.
  Plan elsewhere;
  elsewhere.walls = {{{0, 0}, {2, 7}}, {{5, 1}, {9, 1.5}}};
  b.Publish("GRID_OCTO", GridMsg(Rasterize(elsewhere, Pose2(3, 2, 1.0)), future, "octomap"));
  b.Publish("GRID_PG", GridMsg(Rasterize(plan, Pose2()), t0 + 3000000, "posegraph"));
  fuse();
  ASSERT_EQ(stamps.size(), 3u);
  EXPECT_EQ(node.last()->maps_used, 2u);
  EXPECT_EQ(stamps[2], t0 + 3000000);
}

// The quarter-turned map of a restarted mapper is counted as a conflicting source by the node.
TEST(MapFusionNode, CountsAMapLeftOutForConflicts) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  ManualClock clock(1700000000000000);
  MapFusionNode node(&b, FusionOptions{}, &clock);
  const Plan office = Office();
  b.Publish("GRID_PG", GridMsg(Rasterize(office, Pose2()), clock.NowUtime(), "posegraph"));
  b.Publish("GRID_RBPF",
            GridMsg(Rasterize(office, Pose2(10.6, -0.4, M_PI / 2)), clock.NowUtime(), "rbpf"));
  b.Publish("GRID_OCTO",
            GridMsg(Rasterize(office, Pose2(0.3, -0.2, 0.05)), clock.NowUtime(), "octomap"));
  while (b.HandleTimeout(0) > 0) {
  }
  auto r = node.FuseNow();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r->maps_used, 2u);
  EXPECT_FALSE(r->sources[1].used);
  EXPECT_EQ(node.sources_rejected(), 1);
  EXPECT_EQ(node.sources_conflicting(), 1);
}

TEST(MapFusionProcess, FusesMapFilesAndALogAndRejectsBadArguments) {
  const std::string dir = ::testing::TempDir() + "/fusion_process";
  fs::remove_all(dir);
  fs::create_directories(dir);
  const Plan plan;
  Corruption ca, cb;
  ca.blob = {6.0, 1.5};
  ca.blob_half = 0.3;
  cb.gap = {2.9, 0.5, 3.1, 2.0};
  // One frame (the alignment is tested above): each map's error is outvoted.
  const io::GridMap a = Rasterize(plan, Pose2(), ca), b = Rasterize(plan, Pose2(), cb);
  const io::GridMap c = Rasterize(plan, Pose2());
  ASSERT_TRUE(io::WriteMapServer(a, dir + "/a").ok());
  ASSERT_TRUE(io::WriteMapServer(b, dir + "/b").ok());
  ASSERT_TRUE(io::WriteMapServer(c, dir + "/c").ok());
  const std::string bin = testing::Bin("map_fusion");
  auto r = testing::Run(bin + " --fuse " + dir + "/a.yaml " + dir + "/b.yaml " + dir +
                        "/c.yaml --out " + dir + "/out");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("fused 3 maps"), std::string::npos) << r.output;
  auto fused = io::ReadMapServer(dir + "/out/fused_map.yaml");
  ASSERT_TRUE(fused.ok()) << fused.error().message;
  EXPECT_LT(Error(Rasterize(plan, Pose2()), *fused), Error(Rasterize(plan, Pose2()), a));
  // Bad arguments: one map, a base out of range, a missing file, a misspelled config key.
  EXPECT_EQ(testing::Run(bin + " --fuse " + dir + "/a.yaml --out " + dir + "/o2").exit_code, 2);
  EXPECT_EQ(testing::Run(bin + " --fuse " + dir + "/a.yaml " + dir + "/b.yaml --base 3").exit_code,
            2);
  auto missing =
      testing::Run(bin + " --fuse " + dir + "/a.yaml " + dir + "/nope.yaml --out " + dir + "/o3");
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_NE(missing.output.find("nope"), std::string::npos) << missing.output;
  {
    std::ofstream f(dir + "/bad.yaml");
    f << "unknown_vote: true\n";
  }
  auto badcfg = testing::Run(bin + " --config " + dir + "/bad.yaml --fuse " + dir + "/a.yaml " +
                             dir + "/b.yaml");
  EXPECT_EQ(badcfg.exit_code, 1);
  EXPECT_NE(badcfg.output.find("unknown_vote"), std::string::npos) << badcfg.output;

  // On the bus: a log with two mappers' grids (and a truncated one) read through file://.
  const std::string log = dir + "/grids.lcmlog";
  {
    auto w = io::LcmLogWriter::Open(log);
    ASSERT_TRUE(w.ok()) << w.error().message;
    const int64_t t0 = 1700000000000000;
    auto put = [&](int64_t t, const std::string& ch, const omni::occupancy_grid_t& g, bool cut) {
      std::vector<uint8_t> buf(static_cast<size_t>(g.getEncodedSize()));
      g.encode(buf.data(), 0, static_cast<int>(buf.size()));
      if (cut) buf.resize(buf.size() / 2);
      ASSERT_TRUE(w->Write(t, ch, buf.data(), buf.size()).ok());
    };
    put(t0, "GRID_PG", GridMsg(c, t0, "posegraph"), false);
    put(t0 + 1000, "GRID_RBPF", GridMsg(b, t0 + 1000, "rbpf"), true);
    put(t0 + 2000, "GRID_RBPF", GridMsg(b, t0 + 2000, "rbpf"), false);
    put(t0 + 3000, "GRID_OCTO", GridMsg(a, t0 + 3000, "octomap"), false);
    ASSERT_TRUE(w->Close().ok());
  }
  auto live = testing::Run(bin + " --url 'file://" + log + "?speed=0' --out " + dir + "/live");
  ASSERT_EQ(live.exit_code, 0) << live.output;
  EXPECT_NE(live.output.find("1 decode errors"), std::string::npos) << live.output;
  EXPECT_NE(live.output.find("3 maps onto GRID_PG"), std::string::npos) << live.output;
  EXPECT_TRUE(fs::exists(dir + "/live/fused_map.png"));
}

}  // namespace
}  // namespace omni::map_fusion
