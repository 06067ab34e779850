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

}  // namespace
}  // namespace omni::io
