// omni-status: the processes' heartbeats as a table and as JSON (a headless robot's health check).
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/heartbeat_t.hpp"
#include "omni/io/lcm_log.h"
#include "run.h"

namespace omni {
namespace {

TEST(OmniStatus, ShowsEveryProcessOnTheBusAndSaysWhenThereIsNone) {
  auto r = testing::Run(testing::Bin("omni-status") + " --lcm-url memq:// --wait 0.3");
  EXPECT_EQ(r.exit_code, 3) << r.output;
  EXPECT_NE(r.output.find("no process's heartbeat within 0.3 s"), std::string::npos) << r.output;
  if (testing::Run("unshare -n true").exit_code != 0)
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string dir = ::testing::TempDir() + "/omni_status";
  std::filesystem::create_directories(dir);
  {
    std::ofstream s(dir + "/run.sh");
    s << "set -u\nip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0'\n"
      << testing::Bin("odom_mapper") << " --config " OMNI_SOURCE_DIR "/config/odom_mapper.yaml"
      << " --out " << dir << " >/dev/null 2>&1 & m=$!\n"
      << "sleep 1.2\n"
      << testing::Bin("omni-status") << "; echo \"table: $?\"\n"
      << testing::Bin("omni-status")
      << " --json --all-counters --wait 1.2; echo \"json: $?\"\n"
      // A second instance of the same name (a process started twice): both shown, flagged.
      << testing::Bin("odom_mapper") << " --config " OMNI_SOURCE_DIR "/config/odom_mapper.yaml"
      << " --out " << dir << "/second >/dev/null 2>&1 & m2=$!\n"
      << "sleep 1.2\n"
      << testing::Bin("omni-status")
      << "; echo \"dup: $?\"\n"
      // It stops (its last heartbeat says STOPPING) while the first beats on: a restart, hidden.
      << "(sleep 0.3; kill -TERM $m2) &\n"
      << testing::Bin("omni-status") << " --wait 2.5; echo \"after: $?\"\n"
      << "wait $m2\n"
      << "kill -TERM $m; wait $m; exit 0\n";
  }
  r = testing::Run("timeout 30 unshare -n bash " + dir + "/run.sh");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("table: 0"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("json: 0"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("PROCESS"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("mapping at raw odometry"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("{\"process\": \"odom_mapper\""), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("\"state\": \"OK\""), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("\"scans_in\": 0"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("\"duplicate\": false"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("DUPLICATE: 2 instances of odom_mapper"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("dup: 1"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("after: 0"), std::string::npos) << r.output;
  // A bus that cannot be opened is its own exit status, not "a process is unhealthy".
  r = testing::Run(testing::Bin("omni-status") + " --url nosuch://x --wait 0.2");
  EXPECT_EQ(r.exit_code, 4) << r.output;
  r = testing::Run(testing::Bin("omni-save-map") + " --url nosuch://x --wait 0.2");
  EXPECT_EQ(r.exit_code, 4) << r.output;
}

// Heartbeats from a recorded log: a process that crashed (its last heartbeat OK, then silence)
// and was started again under a new pid is shown once, as its new instance; two instances
// beating at once are a duplicate.
TEST(OmniStatus, ARestartAfterACrashIsNotADuplicate) {
  const std::string dir = ::testing::TempDir() + "/omni_status_log";
  std::filesystem::create_directories(dir);
  auto write = [&](const std::string& path, const std::vector<std::pair<int32_t, double>>& beats) {
    auto w = io::LcmLogWriter::Open(path);
    ASSERT_TRUE(w.ok()) << w.error().message;
    for (const auto& [pid, t] : beats) {
      omni::heartbeat_t h{};
      h.utime = 1'700'000'000'000'000 + static_cast<int64_t>(t * 1e6);
      h.process = "base_bridge";
      h.pid = pid;
      h.state = omni::heartbeat_t::STATE_OK;
      h.status_text = pid == 111 ? "old" : "new";
      std::vector<uint8_t> buf(static_cast<size_t>(h.getEncodedSize()));
      ASSERT_EQ(h.encode(buf.data(), 0, static_cast<int>(buf.size())),
                static_cast<int>(buf.size()));
      ASSERT_TRUE(w->Write(h.utime, "HEARTBEAT", buf.data(), static_cast<int>(buf.size())).ok());
    }
    ASSERT_TRUE(w->Close().ok());
  };
  write(dir + "/restart.lcmlog", {{111, 0.0}, {111, 1.0}, {222, 1.6}, {222, 2.6}});
  write(dir + "/dup.lcmlog", {{111, 0.0}, {222, 0.5}, {111, 1.0}, {222, 1.5}, {111, 2.0}});
  auto r = testing::Run(testing::Bin("omni-status") + " --url 'file://" + dir +
                        "/restart.lcmlog?speed=0' --wait 0.5");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.find("DUPLICATE"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("new"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("old"), std::string::npos) << r.output;
  r = testing::Run(testing::Bin("omni-status") + " --url 'file://" + dir +
                   "/dup.lcmlog?speed=0' --wait 0.5");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("DUPLICATE: 2 instances of base_bridge"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace omni
