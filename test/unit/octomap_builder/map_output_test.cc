#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <tuple>

#include <gtest/gtest.h>

#include "omni/octomap_builder/depth_io.h"
#include "omni/octomap_builder/key_set_inserter.h"
#include "omni/octomap_builder/map_output.h"
#include "omni/octomap_builder/tree_compare.h"

namespace omni::octo {
namespace {

namespace fs = std::filesystem;

octomap::OcTree MakeTree() {
  octomap::OcTree t(0.1);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-3.f, 3.f);
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < 2000; ++i) pts.emplace_back(u(rng), u(rng), 0.5f * u(rng));
  KeySetOptions o;
  ParallelKeySetInserter(0.1, o).Insert(&t, pts, Eigen::Vector3f(0, 0, 0.2f));
  return t;
}

// Leaves as (key, depth) -> occupied.
std::map<std::tuple<int, int, int, unsigned>, bool> Occupancy(const octomap::OcTree& t) {
  std::map<std::tuple<int, int, int, unsigned>, bool> m;
  for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it) {
    const auto k = it.getKey();
    m[{k[0], k[1], k[2], it.getDepth()}] = t.isNodeOccupied(*it);
  }
  return m;
}

TEST(MapOutput, SavedTreesLoadBackWithTheSameLeaves) {
  const octomap::OcTree t = MakeTree();
  ASSERT_GT(t.getNumLeafNodes(), 100u);
  const std::string dir = testing::TempDir() + "/octo_save";
  fs::create_directories(dir);
  ASSERT_TRUE(SaveTree(t, dir + "/map").ok());
  EXPECT_FALSE(fs::exists(dir + "/map.bt.tmp"));
  EXPECT_FALSE(fs::exists(dir + "/map.ot.tmp"));
  // .ot keeps the log-odds: identical leaves.
  auto ot = LoadTree(dir + "/map.ot");
  ASSERT_TRUE(ot.ok()) << ot.error().message;
  EXPECT_TRUE(SameLeaves(t, **ot));
  // .bt keeps occupied/free per leaf, read by octomap's own reader.
  octomap::OcTree bt(0.1);
  ASSERT_TRUE(bt.readBinary(dir + "/map.bt"));
  EXPECT_EQ(Occupancy(bt), Occupancy(t));
  EXPECT_DOUBLE_EQ(CompareOccupied(bt, t).iou, 1.0);
  // Saving did not change the tree (writeBinaryConst): still probabilistic.
  EXPECT_TRUE(SameLeaves(t, **ot));
  // Corrupt files are errors, not crashes.
  {
    std::ofstream(dir + "/bad.ot") << "# Octomap OcTree file\nid OcTree\nsize 99\nres 0.1\ndata\n";
  }
  EXPECT_FALSE(LoadTree(dir + "/bad.ot").ok());
  EXPECT_FALSE(LoadTree(dir + "/missing.bt").ok());
  // Truncated copies of good files (OctoMap's own reader would recurse on garbage).
  for (const char* ext : {".bt", ".ot"}) {
    std::ifstream good(dir + "/map" + ext, std::ios::binary);
    std::stringstream all;
    all << good.rdbuf();
    const std::string bytes = all.str();
    for (size_t cut : {bytes.size() / 2, bytes.size() - 1}) {
      const std::string bad = dir + "/cut" + ext;
      std::ofstream(bad, std::ios::binary) << bytes.substr(0, cut);
      EXPECT_FALSE(LoadTree(bad).ok()) << ext << " cut at " << cut;
    }
  }
}

// The .bt form is written without OctoMap's writeBinaryConst (which prints " done." on stderr
// after every tree: a log line per OCTOMAP message). It must stay what OctoMap writes: the same
// node data after the header, read back by OctoMap's own reader into the same tree, with the
// resolution exact; and nothing goes to stderr.
TEST(MapOutput, BinaryTreesAreOctomapsFormWithoutItsStderrLine) {
  const octomap::OcTree t = MakeTree();
  testing::internal::CaptureStderr();
  const std::string ours = SerializeTree(t, true);
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
  std::ostringstream theirs_stream(std::ios::binary);
  testing::internal::CaptureStderr();
  ASSERT_TRUE(t.writeBinaryConst(theirs_stream));
  (void)testing::internal::GetCapturedStderr();
  const std::string theirs = theirs_stream.str();
  const size_t ours_data = ours.find("\ndata\n"), theirs_data = theirs.find("\ndata\n");
  ASSERT_NE(ours_data, std::string::npos);
  ASSERT_NE(theirs_data, std::string::npos);
  EXPECT_EQ(ours.substr(ours_data), theirs.substr(theirs_data));
  EXPECT_EQ(ours.substr(0, ours.find('\n')), theirs.substr(0, theirs.find('\n')));
  octomap::OcTree back(0.5);
  std::istringstream in(ours, std::ios::binary);
  testing::internal::CaptureStderr();
  ASSERT_TRUE(back.readBinary(in));
  (void)testing::internal::GetCapturedStderr();
  EXPECT_EQ(back.getResolution(), t.getResolution());
  EXPECT_EQ(back.size(), t.size());
  EXPECT_EQ(Occupancy(back), Occupancy(t));
  // A resolution with more digits than OctoMap's default 6 comes back exactly.
  octomap::OcTree odd(1.0 / 30);
  odd.updateNode(0.5, 0.5, 0.5, true);
  auto parsed = ParseTree(SerializeTree(odd, true), true, "odd");
  ASSERT_TRUE(parsed.ok()) << parsed.error().message;
  EXPECT_EQ((*parsed)->getResolution(), 1.0 / 30);
}

// Found by fuzzing (test/fuzz/bus_messages_fuzz.cc): the byte check passed trees OctoMap then
// refused (a header first line it does not know, a size that disagrees with the nodes), so
// `octomap extract` could pick such a tree over an older readable one. The check now says why.
TEST(MapOutput, TheTreeCheckRefusesWhatOctomapWouldRefuse) {
  octomap::OcTree t(0.1);
  for (int i = 0; i < 10; ++i) t.updateNode(0.1 * i + 0.05, 0.05, 0.05, i % 2 == 0);
  for (bool binary : {true, false}) {
    const std::string good = SerializeTree(t, binary);
    EXPECT_EQ(CheckTreeBytes(good, binary, "OcTree"), "");
    ASSERT_TRUE(ParseTree(good, binary, "good").ok());
    std::string other_first = good;
    other_first[2] = 'o';  // "# octomap ..."
    EXPECT_NE(CheckTreeBytes(other_first, binary, "OcTree").find("first line"), std::string::npos);
    std::string wrong_size = good;
    const size_t at = wrong_size.find("\nsize ");
    ASSERT_NE(at, std::string::npos);
    wrong_size.insert(at + 6, "1");  // "size 1NN": more nodes than the data holds
    EXPECT_NE(CheckTreeBytes(wrong_size, binary, "OcTree").find("the header's size is"),
              std::string::npos)
        << CheckTreeBytes(wrong_size, binary, "OcTree");
    EXPECT_FALSE(ParseTree(wrong_size, binary, "wrong size").ok());
  }
}

// Reading a tree back prints nothing (OctoMap's file readers print "Reading ... octree type" on
// stderr for every tree), gives the same tree in each form, and still refuses a header
// resolution that is not a positive number (0, negative, NaN, inf), as those readers did: the
// node readers it calls now never see the header.
TEST(MapOutput, TreesReadBackQuietlyAndRefuseAResolutionThatIsNotPositive) {
  const octomap::OcTree t = MakeTree();
  octomap::ColorOcTree c(0.05);
  c.updateNode(0.3, 0.2, 0.1, true);
  c.setNodeColor(0.3, 0.2, 0.1, 10, 200, 30);
  c.updateNode(-1.0, 0.7, 0.4, false);
  const std::string bt = SerializeTree(t, true), ot = SerializeTree(t, false);
  const std::string cot = SerializeColorTree(c);
  testing::internal::CaptureStderr();
  auto from_bt = ParseTree(bt, true, "bt");
  auto from_ot = ParseTree(ot, false, "ot");
  auto from_cot = ParseColorTree(cot, "cot");
  auto empty = ParseTree(SerializeTree(octomap::OcTree(0.2), true), true, "empty");
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
  ASSERT_TRUE(from_bt.ok()) << from_bt.error().message;
  ASSERT_TRUE(from_ot.ok()) << from_ot.error().message;
  ASSERT_TRUE(from_cot.ok()) << from_cot.error().message;
  ASSERT_TRUE(empty.ok()) << empty.error().message;
  EXPECT_EQ(Occupancy(**from_bt), Occupancy(t));
  EXPECT_TRUE(SameLeaves(t, **from_ot));
  EXPECT_EQ((*from_bt)->getResolution(), 0.1);
  EXPECT_EQ((*empty)->size(), 0u);
  EXPECT_EQ((*empty)->getResolution(), 0.2);
  EXPECT_EQ((*from_cot)->size(), c.size());
  const octomap::ColorOcTreeNode* n = (*from_cot)->search(0.3, 0.2, 0.1);
  ASSERT_NE(n, nullptr);
  EXPECT_EQ(n->getColor(), octomap::ColorOcTreeNode::Color(10, 200, 30));
  EXPECT_FLOAT_EQ(n->getLogOdds(), c.search(0.3, 0.2, 0.1)->getLogOdds());

  for (const char* res : {"0", "-0.1", "nan", "inf", "x"}) {
    for (bool binary : {true, false}) {
      std::string bad = binary ? bt : ot;
      const size_t at = bad.find("\nres ");
      ASSERT_NE(at, std::string::npos);
      bad.replace(at + 5, bad.find('\n', at + 1) - at - 5, res);
      auto r = ParseTree(bad, binary, "bad");
      ASSERT_FALSE(r.ok()) << res;
      EXPECT_NE(r.error().message.find("resolution"), std::string::npos) << r.error().message;
    }
  }
  std::string no_res = ot;
  const size_t res_line = no_res.find("\nres ");
  no_res.erase(res_line, no_res.find('\n', res_line + 1) - res_line);
  auto r = ParseTree(no_res, false, "no res");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("no 'res' line"), std::string::npos) << r.error().message;
}

TEST(MapOutput, ProjectsTheHeightBand) {
  octomap::OcTree t(0.1);
  // A floor (z = 0.05, below the band), a low box (z = 0.25) and free space above the floor.
  for (double x = 0.05; x < 1.0; x += 0.1)
    for (double y = 0.05; y < 1.0; y += 0.1) {
      t.updateNode(x, y, 0.05, true);
      t.updateNode(x, y, 0.25, x > 0.5 && y > 0.5);  // occupied only in one quadrant
    }
  GridProjectionOptions o;
  o.min_z_m = 0.2;
  o.max_z_m = 1.0;
  auto g = ProjectToGrid(t, o);
  ASSERT_TRUE(g.ok());
  EXPECT_EQ(g->width, 10);
  EXPECT_EQ(g->height, 10);
  EXPECT_NEAR(g->origin_x_m, 0.0, 1e-9);
  EXPECT_EQ(g->at(8, 8), 100);  // the box
  EXPECT_EQ(g->at(2, 2), 0);    // free at box height; the floor below the band is ignored
  o.min_z_m = 1.0;
  o.max_z_m = 0.5;
  EXPECT_FALSE(ProjectToGrid(t, o).ok());
}

// Two voxels 1.5 km apart project onto 30000 x 30000 cells at 5 cm: more than a grid message
// carries (io::kMaxGridCells), so the projection refuses before allocating it.
TEST(MapOutput, RefusesAProjectionNoGridMessageCouldCarry) {
  octomap::OcTree t(0.1);
  t.updateNode(0.05, 0.05, 0.5, true);
  t.updateNode(1500.05, 1500.05, 0.5, true);
  GridProjectionOptions o;
  o.resolution_m = 0.05;
  auto g = ProjectToGrid(t, o);
  ASSERT_FALSE(g.ok());
  EXPECT_NE(g.error().message.find("2^28"), std::string::npos) << g.error().message;
  o.resolution_m = 0.2;  // 7500 x 7500: within the cap
  g = ProjectToGrid(t, o);
  ASSERT_TRUE(g.ok()) << g.error().message;
  EXPECT_EQ(static_cast<int64_t>(g->width) * g->height, int64_t{7501} * 7501);
}

TEST(MapOutput, ProjectsAlongAnotherUpAxis) {
  // A camera-posed world with y down: an obstacle at height 0.5 m is at y = -0.5.
  octomap::OcTree t(0.1);
  t.updateNode(1.05, -0.45, 2.05, true);   // obstacle: x 1.05, height 0.45, z 2.05
  t.updateNode(0.05, -0.45, 0.05, false);  // free at the same height
  t.updateNode(1.05, 0.95, 2.05, true);    // below the floor (height -0.95): outside the band
  GridProjectionOptions o;
  ASSERT_TRUE(UpAxis::Parse("-y", &o.up));
  EXPECT_FALSE(UpAxis::Parse("w", &o.up));
  o.min_z_m = 0.2;
  o.max_z_m = 1.0;
  auto g = ProjectToGrid(t, o);
  ASSERT_TRUE(g.ok());
  // Up -y: grid x = map z, grid y = -(map x).
  EXPECT_EQ(g->width, 21);   // map z 0.0 .. 2.1
  EXPECT_EQ(g->height, 11);  // -(map x) -1.1 .. 0.0
  size_t occ = 0, fr = 0;
  for (int8_t c : g->cells) occ += c == 100, fr += c == 0;
  EXPECT_EQ(occ, 1u);
  EXPECT_EQ(fr, 1u);
  const int col = static_cast<int>((2.05 - g->origin_x_m) / 0.1);
  const int row = static_cast<int>((-1.05 - g->origin_y_m) / 0.1);
  ASSERT_TRUE(g->Contains(col, row));
  EXPECT_EQ(g->at(col, row), 100);
}

TEST(MapOutput, Geb079LoadsAndProjectsToAFloorPlan) {
  const std::string path = std::string(OMNI_DATASETS_DIR) + "/octomap/geb079.bt";
  if (!fs::exists(path)) GTEST_SKIP() << "dataset octomap/geb079.bt absent";
  auto tree = LoadTree(path);
  ASSERT_TRUE(tree.ok()) << tree.error().message;
  const octomap::OcTree& t = **tree;
  EXPECT_DOUBLE_EQ(t.getResolution(), 0.08);
  EXPECT_EQ(t.size(), 532566u);  // SOURCE.md: "size 532566"
  double x0, y0, z0, x1, y1, z1;
  t.getMetricMin(x0, y0, z0);
  t.getMetricMax(x1, y1, z1);
  // A band from 0.5 m above the lowest occupied level to 1.5 m above it: walls, not floor.
  GridProjectionOptions o;
  o.min_z_m = z0 + 0.5;
  o.max_z_m = z0 + 1.5;
  auto g = ProjectToGrid(t, o);
  ASSERT_TRUE(g.ok());
  size_t occ = 0, fr = 0;
  for (int8_t c : g->cells) occ += c == 100, fr += c == 0;
  const double n = static_cast<double>(g->cells.size());
  // A building floor: metres across, mostly free corridors/rooms, walls a small fraction.
  EXPECT_GT(g->width * g->resolution_m, 10.0);
  EXPECT_GT(g->height * g->resolution_m, 5.0);
  EXPECT_GT(fr / n, 0.2);
  EXPECT_GT(occ / n, 0.01);
  EXPECT_LT(occ / n, 0.35);
  EXPECT_GT(fr, 2 * occ);
  // Walls are thin lines: most occupied cells have a free 4-neighbour.
  size_t occ_next_to_free = 0;
  for (int r = 1; r + 1 < g->height; ++r)
    for (int c = 1; c + 1 < g->width; ++c)
      if (g->at(c, r) == 100 && (g->at(c + 1, r) == 0 || g->at(c - 1, r) == 0 ||
                                 g->at(c, r + 1) == 0 || g->at(c, r - 1) == 0))
        ++occ_next_to_free;
  EXPECT_GT(occ_next_to_free, occ / 3);
  const io::Image view = RenderTopView(t);
  EXPECT_GT(view.width, 100);
}

// A map too wide for one pixel per leaf is drawn coarser, not as one grey pixel (it was, above
// 1e8 pixels): two 1 cm voxels 100 m x 50 m apart.
TEST(TopView, AHugeMapIsDrawnCoarserNotDropped) {
  octomap::OcTree t(0.01);
  t.updateNode(octomap::point3d(0.005f, 0.005f, 0.005f), true);
  t.updateNode(octomap::point3d(100.005f, 50.005f, 0.005f), true);
  const io::Image view = RenderTopView(t);
  EXPECT_EQ(view.width, 5001);  // 2 cm pixels over 100.01 m
  EXPECT_EQ(view.height, 2501);
  EXPECT_LE(static_cast<double>(view.width) * view.height, kMaxTopViewPixels);
  auto blue = [&](int c, int r) {
    return view.at(c, r, 0) < 60 && view.at(c, r, 1) < 60 && view.at(c, r, 2) > 200;  // low
  };
  EXPECT_TRUE(blue(0, view.height - 1));  // the voxel at the origin: south-west corner
  EXPECT_TRUE(blue(view.width - 1, 0));   // the far one: north-east
  EXPECT_EQ(view.at(2500, 1250, 0), 40);  // nothing known in between
  EXPECT_EQ(view.at(2500, 1250, 2), 40);
}

TEST(DepthIo, PcdAndPngWriters) {
  const std::string dir = testing::TempDir();
  std::vector<Eigen::Vector3f> pts = {{1, 2, 3}, {-1.5f, 0, 0.25f}};
  ASSERT_TRUE(WritePcd(dir + "/c.pcd", pts, false).ok());
  std::ifstream in(dir + "/c.pcd");
  std::stringstream s;
  s << in.rdbuf();
  EXPECT_NE(s.str().find("POINTS 2\nDATA ascii\n1 2 3\n-1.5 0 0.25\n"), std::string::npos);
  ASSERT_TRUE(WritePcd(dir + "/b.pcd", pts, true).ok());
  EXPECT_EQ(fs::file_size(dir + "/b.pcd"),
            s.str().size() - std::string("1 2 3\n-1.5 0 0.25\n").size() -
                std::string("ascii").size() + std::string("binary").size() + 24);
}

}  // namespace
}  // namespace omni::octo
