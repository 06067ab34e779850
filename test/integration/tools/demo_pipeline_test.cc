// Two processes on the bus: omni-replay publishes an imported log over UDP multicast inside a
// private network namespace; odom_mapper maps it. Nothing leaves the machine.
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "../../unit/common/test_paths.h"
#include "omni/io/grid.h"
#include "run.h"

namespace omni {
namespace {

bool CanMakeNetns() { return testing::Run("unshare -n true").exit_code == 0; }

TEST(DemoPipeline, ReplayThroughBusIntoOdomMapperLosesNothing) {
  OMNI_REQUIRE_DATASET(clf, "intel-raw/intel.clf");
  if (!CanMakeNetns())
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string dir = testing::TempDir();
  auto r =
      testing::Run(testing::Bin("omni-import") + " carmen " + clf + " " + dir + "/intel.lcmlog");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  {
    std::ofstream s(dir + "/run.sh");
    s << "set -u\nip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304'\n"
      << testing::Bin("odom_mapper") << " --out " << dir << " & m=$!\nsleep 0.5\n"
      << "timeout 90 " << testing::Bin("omni-replay") << " " << dir << "/intel.lcmlog --speed 20\n"
      << "rc=$?\nsleep 0.5\nkill -TERM $m\nwait $m\nexit $((rc + $?))\n";
  }
  r = testing::Run("timeout 120 unshare -n bash " + dir + "/run.sh");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("replayed 5453 events"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("mapped 2726 of 2726 scans received (0 lost on the bus"),
            std::string::npos)
      << r.output;
  for (const char* f : {"odom_map.png", "odom_map.pgm", "odom_map.yaml", "odom_trajectory.png",
                        "odom_trajectory.txt"})
    EXPECT_TRUE(std::filesystem::exists(dir + "/" + f)) << f;
  auto map = io::ReadMapServer(dir + "/odom_map.yaml");
  ASSERT_TRUE(map.ok()) << map.error().message;
  size_t occupied = 0, free_cells = 0;
  for (int8_t c : map->cells) {
    occupied += c == 100;
    free_cells += c == 0;
  }
  EXPECT_GT(occupied, 10000u);
  EXPECT_GT(free_cells, 10 * occupied);
}

TEST(DemoPipeline, LogReplayThroughLcmFileProvider) {
  OMNI_REQUIRE_DATASET(clf, "intel-raw/intel.clf");
  const std::string dir = testing::TempDir();
  auto r =
      testing::Run(testing::Bin("omni-import") + " carmen " + clf + " " + dir + "/intel.lcmlog");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::Run(testing::Bin("odom_mapper") + " --out " + dir + " --url 'file://" + dir +
                   "/intel.lcmlog?speed=0'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("mapped 2726 of 2726"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace omni
