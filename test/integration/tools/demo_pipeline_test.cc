// Two processes on the bus: omni-replay publishes an imported log over UDP multicast inside a
// private network namespace; odom_mapper maps it. Nothing leaves the machine.
#include <chrono>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "../../unit/common/test_paths.h"
#include "omni/io/grid.h"
#include "omni/io/lcm_log.h"
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

// A log whose time jumps (two recordings joined, a clock set forward, then back): the forward
// jump is replayed as --max-gap, the step back as no gap, both said; and Ctrl-C stops a replay
// that is waiting out a long gap at once (it used to sleep through the whole gap, deaf to
// SIGINT and SIGTERM).
TEST(DemoPipeline, ReplayKeepsItsPaceAcrossLogTimeJumpsAndStopsOnSignal) {
  const std::string dir = testing::TempDir() + "/replay_jumps";
  std::filesystem::create_directories(dir);
  {
    auto w = io::LcmLogWriter::Open(dir + "/jumps.lcmlog");
    ASSERT_TRUE(w.ok()) << w.error().message;
    const char payload[4] = {1, 2, 3, 4};
    int64_t t = 1'700'000'000'000'000;
    auto run = [&](int n) {
      for (int i = 0; i < n; ++i, t += 10'000) ASSERT_TRUE(w->Write(t, "X", payload, 4).ok());
    };
    run(20);
    t += 3600'000'000LL;  // an hour forward
    run(20);
    t -= 2'000'000;  // two seconds back
    run(20);
    ASSERT_TRUE(w->Close().ok());
  }
  const std::string replay =
      testing::Bin("omni-replay") + " " + dir + "/jumps.lcmlog --url memq://";
  const auto t0 = std::chrono::steady_clock::now();
  auto r = testing::Run(replay + " --max-gap 0.5 2>&1");
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("replayed 60 events"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("1 jumps back, 1 gaps over 0.5 s shortened"), std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("jumps forward by 3600.010 s"), std::string::npos) << r.output;
  EXPECT_GT(took, 0.9);  // 0.57 s of events plus the 0.5 s gap
  EXPECT_LT(took, 5.0);
  const auto t1 = std::chrono::steady_clock::now();
  r = testing::Run("timeout --preserve-status -s INT 1 " + replay + " --max-gap 3600; echo rc=$?");
  const double stop = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  EXPECT_NE(r.output.find("[interrupted]"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("rc=130"), std::string::npos) << r.output;
  EXPECT_LT(stop, 3.0);
}

// A recording cut short (the robot lost power while logging) replays up to its partial last
// event with a warning and exit status 0; a length corrupted past the end with events after it
// is still an error (it used to be the same error as the cut, exit 1 for both).
TEST(DemoPipeline, ACutRecordingReplaysToItsEndAndACorruptOneFails) {
  const std::string dir = testing::TempDir() + "/replay_cut";
  std::filesystem::create_directories(dir);
  const std::string log = dir + "/cut.lcmlog";
  {
    auto w = io::LcmLogWriter::Open(log);
    ASSERT_TRUE(w.ok()) << w.error().message;
    const char payload[8] = {1, 2, 3, 4, 5, 6, 7, 8};
    for (int i = 0; i < 30; ++i) ASSERT_TRUE(w->Write(1000 + i, "X", payload, 8).ok());
    ASSERT_TRUE(w->Close().ok());
  }
  const auto size = std::filesystem::file_size(log);  // 30 events of 28 + 1 + 8 bytes
  ASSERT_EQ(size, 30u * 37u);
  std::filesystem::resize_file(log, size - 5);
  const std::string replay = testing::Bin("omni-replay") + " " + log + " --speed 0 --url memq://";
  auto r = testing::Run(replay + " 2>&1");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("replayed 29 events"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("the log ends inside an event"), std::string::npos) << r.output;
  // Event 10's data length 8 -> 4104: past the end, with 19 intact events after it.
  {
    std::fstream f(log, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(10 * 37 + 26);
    f.put(static_cast<char>(0x10));
  }
  r = testing::Run(replay + " 2>&1");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("events follow"), std::string::npos) << r.output;
  r = testing::Run(replay + " --resync 2>&1");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("replayed 28 events"), std::string::npos) << r.output;
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
