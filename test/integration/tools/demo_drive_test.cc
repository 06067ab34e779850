// ./omni demo --drive: the whole stack live on the simulator under the supervisor, in a private
// network namespace, driven by the keyboard teleop (here keys through a pipe); when the teleop
// ends the stack stops in order and every map is written and scored.
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "run.h"

namespace omni {
namespace {

TEST(DemoDrive, TheStackMapsWhatTheKeysDrove) {
  if (testing::Run("unshare -n true").exit_code != 0)
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string out = ::testing::TempDir() + "/demo_drive";
  std::filesystem::remove_all(out);
  const auto r = testing::Run(
      "(sleep 3; for i in $(seq 40); do printf w; sleep 0.1; done;"
      " for i in $(seq 15); do printf q; sleep 0.1; done; printf ' '; sleep 1; printf '\\033')"
      " | OMNI_BUILD_DIR=" OMNI_BINARY_DIR " OMNI_OUT_DIR=" +
      out + " timeout 120 " OMNI_SOURCE_DIR "/omni demo --drive --no-setup");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("vx +0.20 m/s"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("omni demo --drive: done"), std::string::npos) << r.output;
  for (const char* f :
       {"drive/sim/truth.txt", "drive/odom_map.yaml", "drive/rbpf/map.yaml",
        "drive/posegraph/map.yaml", "drive/octomap/map.bt", "drive/fusion/fused_map.yaml"})
    EXPECT_TRUE(std::filesystem::exists(out + "/" + f)) << f << "\n" << r.output;
  // Three trajectories scored against the truth, the SLAM ones within centimetres.
  size_t n = 0;
  const std::string key = "matched poses: RMSE ";
  for (size_t at = r.output.find(key); at != std::string::npos; at = r.output.find(key, at + 1)) {
    EXPECT_LT(std::stod(r.output.substr(at + key.size())), 0.05) << r.output;
    ++n;
  }
  EXPECT_EQ(n, 3u) << r.output;
}

}  // namespace
}  // namespace omni
