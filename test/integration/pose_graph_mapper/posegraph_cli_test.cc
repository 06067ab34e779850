// omni-posegraph and omni-bench-posegraph as a user runs them: bad graphs are errors naming the
// line, a real graph is optimised and its output file scores the optimum, the benchmark runs
// without the peer and says so.
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "../../integration/tools/run.h"
#include "../../unit/common/test_paths.h"

namespace omni {
namespace {

using testing::Bin;

void Write(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

TEST(PoseGraphCli, HelpAndUnknownSubcommand) {
  auto r = testing::Run(Bin("omni-posegraph") + " --help");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.output.find("optimize"), std::string::npos);
  r = testing::Run(Bin("omni-posegraph") + " optimise x.g2o");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("optimise"), std::string::npos) << r.output;
  r = testing::Run(Bin("omni-bench-posegraph") + " --help");
  EXPECT_EQ(r.exit_code, 0);
}

TEST(PoseGraphCli, EdgeToAMissingVertexNamesTheLine) {
  const std::string dir = testing::TempDir();
  Write(dir + "/g.g2o",
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
        "EDGE_SE2 1 7 1 0 0 1 0 0 1 0 1\n");
  const auto r =
      testing::Run(Bin("omni-posegraph") + " optimize " + dir + "/g.g2o -o " + dir + "/out.g2o");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("g.g2o:4"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir + "/out.g2o"));
}

// `-o` into a folder that does not exist yet (`out/` on a fresh checkout): it is made.
TEST(PoseGraphCli, OutputFolderIsMade) {
  const std::string dir = testing::TempDir() + "/pg_out_folder";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  Write(dir + "/g.g2o",
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0.1\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n");
  const auto r = testing::Run(Bin("omni-posegraph") + " optimize " + dir + "/g.g2o -o " + dir +
                              "/new/sub/out.g2o");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir + "/new/sub/out.g2o")) << r.output;
}

TEST(PoseGraphCli, NonPositiveDefiniteInformationNamesTheLine) {
  const std::string dir = testing::TempDir();
  Write(dir + "/g.g2o",
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n");
  const auto r = testing::Run(Bin("omni-posegraph") + " optimize " + dir + "/g.g2o");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("g.g2o:3"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("positive definite"), std::string::npos) << r.output;
}

TEST(PoseGraphCli, BadOptionsAreErrors) {
  const std::string dir = testing::TempDir();
  Write(dir + "/g.g2o", "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n");
  auto r = testing::Run(Bin("omni-posegraph") + " optimize " + dir + "/g.g2o --init magic");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("magic"), std::string::npos) << r.output;
  Write(dir + "/c.yaml", "batch:\n  max_iteratons: 3\n");
  r = testing::Run(Bin("omni-posegraph") + " optimize " + dir + "/g.g2o --config " + dir +
                   "/c.yaml");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("max_iteratons"), std::string::npos) << r.output;
}

TEST(PoseGraphCli, OptimizesIntelAndTheOutputScoresTheOptimum) {
  OMNI_REQUIRE_DATASET(intel, "pose-graphs/intel.g2o");
  const std::string dir = testing::TempDir();
  auto r = testing::Run("cd " + std::string(OMNI_SOURCE_DIR) + " && " + Bin("omni-posegraph") +
                        " optimize " + intel + " -o " + dir + "/intel.opt.g2o");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("chi2 before      551.7"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("chi2 after       45.00"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("iterations"), std::string::npos) << r.output;
  r = testing::Run(Bin("omni-posegraph") + " chi2 " + intel + " --poses " + dir + "/intel.opt.g2o");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("chi2 45.00"), std::string::npos) << r.output;
}

TEST(PoseGraphCli, BenchmarkWithoutThePeerSaysSoAndWritesJsonl) {
  OMNI_REQUIRE_DATASET(intel, "pose-graphs/intel.g2o");
  const std::string dir = testing::TempDir();
  const auto r = testing::Run(Bin("omni-bench-posegraph") + " --peer none --only intel --out " +
                              dir + " --datasets " + OMNI_DATASETS_DIR);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("graph-slam is not installed"), std::string::npos) << r.output;
  std::ifstream f(dir + "/posegraph.jsonl");
  std::string ours, peer;
  std::getline(f, ours);
  std::getline(f, peer);
  EXPECT_NE(ours.find("\"system\": \"omni-ceres\", \"dataset\": \"intel\""), std::string::npos)
      << ours;
  EXPECT_NE(ours.find("\"chi2\": 45.00"), std::string::npos) << ours;
  EXPECT_NE(ours.find("\"iterations\": "), std::string::npos);
  EXPECT_NE(peer.find("\"status\": \"absent\""), std::string::npos) << peer;
}

}  // namespace
}  // namespace omni
