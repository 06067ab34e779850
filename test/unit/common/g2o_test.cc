#include "omni/io/g2o.h"

#include <sstream>

#include <gtest/gtest.h>

#include "test_paths.h"

namespace omni::io {
namespace {

struct Expected {
  const char* file;
  size_t vertices, edges;
  bool is3d;
};

TEST(G2o, DatasetCounts) {
  const Expected all[] = {
      {"intel.g2o", 1728, 2512, false},       {"M3500.g2o", 3500, 5453, false},
      {"city10000.g2o", 10000, 20687, false}, {"FR079.g2o", 989, 1217, false},
      {"MITb.g2o", 808, 827, false},          {"parking-garage.g2o", 1661, 6275, true},
      {"sphere2500.g2o", 2500, 4949, true}};
  OMNI_REQUIRE_DATASET(dir, "pose-graphs");
  for (const auto& e : all) {
    auto g = ReadPoseGraph(dir + "/" + e.file);
    ASSERT_TRUE(g.ok()) << g.error().message;
    EXPECT_EQ(g->is_3d(), e.is3d) << e.file;
    EXPECT_EQ(e.is3d ? g->vertices3.size() : g->vertices2.size(), e.vertices) << e.file;
    EXPECT_EQ(e.is3d ? g->edges3.size() : g->edges2.size(), e.edges) << e.file;
    EXPECT_FALSE(g->vertices_implicit) << e.file;
  }
}

TEST(G2o, EdgeOnlyFileHasImplicitVertices) {
  OMNI_REQUIRE_DATASET(path, "pose-graphs/CSAIL.g2o");
  auto g = ReadPoseGraph(path);
  ASSERT_TRUE(g.ok()) << g.error().message;
  EXPECT_TRUE(g->vertices_implicit);
  EXPECT_EQ(g->edges2.size(), 1172u);
  EXPECT_GT(g->vertices2.size(), 1000u);
}

TEST(G2o, UnknownTagNamesLine) {
  std::istringstream in("VERTEX_SE2 0 0 0 0\nVERTEX_XYZ 1 0 0 0\n");
  auto g = ParsePoseGraph(in, "graph.g2o");
  ASSERT_FALSE(g.ok());
  EXPECT_NE(g.error().message.find("graph.g2o:2"), std::string::npos) << g.error().message;
  EXPECT_NE(g.error().message.find("VERTEX_XYZ"), std::string::npos);
}

TEST(G2o, EdgeToMissingVertexNamesLine) {
  std::istringstream in("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 7 1 0 0 1 0 0 1 0 1\n");
  auto g = ParsePoseGraph(in, "graph.g2o");
  ASSERT_FALSE(g.ok());
  EXPECT_NE(g.error().message.find("graph.g2o:3"), std::string::npos) << g.error().message;
}

TEST(G2o, NonPositiveDefiniteInformationRejected) {
  std::istringstream in(
      "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n");
  auto g = ParsePoseGraph(in, "graph.g2o");
  ASSERT_FALSE(g.ok());
  EXPECT_NE(g.error().message.find("graph.g2o:3"), std::string::npos);
  EXPECT_NE(g.error().message.find("positive definite"), std::string::npos);
}

TEST(G2o, ToroAndRoundTrip) {
  std::istringstream in("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0.1\nEDGE2 0 1 1 0 0.1 10 1 20 30 2 3\n");
  auto g = ParsePoseGraph(in, "toro.graph");
  ASSERT_TRUE(g.ok()) << g.error().message;
  const auto& info = g->edges2[0].information;
  EXPECT_EQ(info(0, 0), 10);
  EXPECT_EQ(info(0, 1), 1);
  EXPECT_EQ(info(1, 1), 20);
  EXPECT_EQ(info(2, 2), 30);
  EXPECT_EQ(info(0, 2), 2);
  EXPECT_EQ(info(1, 2), 3);
  const std::string out = omni::testing::TempDir() + "/rt.g2o";
  ASSERT_TRUE(WriteG2o(out, *g).ok());
  auto back = ReadPoseGraph(out);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_TRUE(back->edges2[0].information.isApprox(info));
  EXPECT_NEAR(back->vertices2[1].pose.theta, 0.1, 1e-12);
}

// A FIX line holds vertex ids only, and only ids of vertices in the file (the optimiser holds each
// one; an unknown or misspelled id used to be dropped without a word).
TEST(G2o, FixIdsMustBeVertices) {
  std::istringstream ok("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nFIX 0 1\n");
  auto g = ParsePoseGraph(ok, "graph.g2o");
  ASSERT_TRUE(g.ok()) << g.error().message;
  EXPECT_EQ(g->fixed, (std::vector<int>{0, 1}));
  std::istringstream junk("VERTEX_SE2 0 0 0 0\nFIX 0 abc\n");
  g = ParsePoseGraph(junk, "graph.g2o");
  ASSERT_FALSE(g.ok());
  EXPECT_NE(g.error().message.find("graph.g2o:2"), std::string::npos) << g.error().message;
  EXPECT_NE(g.error().message.find("'abc'"), std::string::npos) << g.error().message;
  std::istringstream missing("VERTEX_SE2 0 0 0 0\nFIX 7\n");
  g = ParsePoseGraph(missing, "graph.g2o");
  ASSERT_FALSE(g.ok());
  EXPECT_NE(g.error().message.find("graph.g2o:2: FIX: vertex 7 does not exist"), std::string::npos)
      << g.error().message;
}

// TORO's EDGE3 information is over (x, y, z, roll, pitch, yaw); the residual it weights here is
// the translation and the error quaternion's vector part (half the angle): rotation terms x4,
// cross terms x2 — the same weighting as the equivalent EDGE_SE3:QUAT line.
TEST(G2o, Toro3DInformationIsConvertedToTheQuaternionResidual) {
  std::string info;
  for (int r = 0; r < 6; ++r)
    for (int c = r; c < 6; ++c) info += r == c ? " 10" : (r == 0 && c == 3 ? " 1" : " 0");
  std::istringstream in("VERTEX3 0 0 0 0 0 0 0\nVERTEX3 1 1 0 0 0 0 0\nEDGE3 0 1 1 0 0 0 0 0" +
                        info + "\n");
  auto g = ParsePoseGraph(in, "toro3.graph");
  ASSERT_TRUE(g.ok()) << g.error().message;
  const auto& m = g->edges3[0].information;
  EXPECT_DOUBLE_EQ(m(0, 0), 10);
  EXPECT_DOUBLE_EQ(m(2, 2), 10);
  EXPECT_DOUBLE_EQ(m(3, 3), 40);
  EXPECT_DOUBLE_EQ(m(5, 5), 40);
  EXPECT_DOUBLE_EQ(m(0, 3), 2);
  EXPECT_DOUBLE_EQ(m(3, 0), 2);
}

}  // namespace
}  // namespace omni::io
