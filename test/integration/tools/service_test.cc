// scripts/install-service.sh: the systemd unit it generates for the robot passes
// `systemd-analyze verify` (no warning either), waits longer than the supervisor's orderly stop,
// and bad options are errors.
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "run.h"

namespace omni {
namespace {

const std::string kScript = std::string(OMNI_SOURCE_DIR) + "/scripts/install-service.sh";

TEST(InstallService, GeneratedUnitVerifies) {
  if (testing::Run("command -v systemd-analyze").exit_code != 0)
    GTEST_SKIP() << "systemd-analyze is not installed (Debian package systemd)";
  const std::string build = " --build " + std::string(OMNI_BINARY_DIR);
  // The unit is stdout; stderr may carry a warning (a build tree other than build/: the children
  // in the config still run build/bin), which must not end up in the unit file.
  const std::string warnings = ::testing::TempDir() + "/install-service.stderr";
  auto r = testing::Run(kScript + " --print --user root --can can0" + build + " 2>" + warnings);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::string unit = r.output;
  EXPECT_NE(
      unit.find("ExecStart=\"" + std::string(OMNI_BINARY_DIR) + "/bin/supervisor\" --config \""),
      std::string::npos)
      << unit;
  // What the bus needs and a reboot forgets: the receive buffer limit and a multicast route.
  EXPECT_NE(unit.find("net.core.rmem_max=8388608"), std::string::npos) << unit;
  EXPECT_NE(unit.find("ip route add 224.0.0.0/4 dev lo"), std::string::npos) << unit;
  EXPECT_NE(unit.find("KillMode=mixed"), std::string::npos) << unit;
  EXPECT_NE(unit.find("bitrate 1000000"), std::string::npos) << unit;
  // The shipped supervisor config's stop graces add up to 170 s: systemd waits longer.
  const size_t at = unit.find("TimeoutStopSec=");
  ASSERT_NE(at, std::string::npos) << unit;
  EXPECT_GT(std::stoi(unit.substr(at + 15)), 170) << unit;
  const std::string path = ::testing::TempDir() + "/omni-test.service";
  std::ofstream(path) << unit;
  r = testing::Run("systemd-analyze verify " + path);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output, "") << "systemd-analyze warned:\n" << r.output;
  // A unit pointing at a binary that does not exist does not verify (the check can fail).
  std::string broken = unit;
  broken.replace(broken.find("ExecStart=\"") + 11, 1, "/nonexistent/");
  std::ofstream(path) << broken;
  EXPECT_NE(testing::Run("systemd-analyze verify " + path).exit_code, 0);
}

// The stop timeout counts the children of a config indented by four spaces, with a hyphen in a
// name and a grace in flow form (the awk assumed two spaces and [A-Za-z0-9_] names, so it gave
// 160 s for a stop of up to 170 s here and systemd killed the last mapper mid-write).
TEST(InstallService, TheStopTimeoutCountsEveryChildOfAnyIndentation) {
  const std::string dir = ::testing::TempDir() + "/service_indent";
  std::filesystem::create_directories(dir);
  const std::string config = dir + "/supervisor.yaml";
  std::ofstream(config) << "# a hand-written config\n"
                           "children:\n"
                           "    can-up:\n"
                           "        command: [/bin/true]\n"
                           "        restart: never\n"
                           "    rbpf_mapper:\n"
                           "        command: [build/bin/rbpf_mapper]\n"
                           "        stop_grace_s: 120\n"
                           "    map_fusion: {command: [build/bin/map_fusion], stop_grace_s: 40}\n"
                           "    odom_mapper:\n"
                           "        command: [build/bin/odom_mapper]\n"
                           "heartbeat_timeout_s: 5\n";
  const auto r = testing::Run(kScript + " --print --user root --config '" + config + "' --build " +
                              std::string(OMNI_BINARY_DIR) + " 2>/dev/null");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const size_t at = r.output.find("TimeoutStopSec=");
  ASSERT_NE(at, std::string::npos) << r.output;
  EXPECT_EQ(std::stoi(r.output.substr(at + 15)), 120 + 40 + 5 + 5 + 30) << r.output;
}

// A checkout whose path has a space (and a script reached through a symlink): the unit still
// verifies (ExecStart used to be split at the space, so the stack never started at boot).
TEST(InstallService, AUnitForACheckoutWithASpaceInItsPathVerifies) {
  if (testing::Run("command -v systemd-analyze").exit_code != 0)
    GTEST_SKIP() << "systemd-analyze is not installed (Debian package systemd)";
  namespace fs = std::filesystem;
  const std::string root = ::testing::TempDir() + "/with space/repo";
  fs::remove_all(root);
  fs::create_directories(root + "/scripts");
  fs::create_directories(root + "/config");
  fs::create_directories(root + "/build/bin");
  fs::copy_file(kScript, root + "/scripts/install-service.sh");
  fs::copy_file(std::string(OMNI_SOURCE_DIR) + "/config/supervisor.yaml",
                root + "/config/supervisor.yaml");
  std::ofstream(root + "/build/bin/supervisor") << "#!/bin/sh\n";
  fs::permissions(root + "/build/bin/supervisor", fs::perms::owner_all, fs::perm_options::add);
  const std::string link = ::testing::TempDir() + "/install-service-link.sh";
  fs::remove(link);
  fs::create_symlink(root + "/scripts/install-service.sh", link);
  auto r = testing::Run("'" + link + "' --print --user root 2>/dev/null");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("WorkingDirectory=" + fs::canonical(root).string() + "\n"),
            std::string::npos)
      << r.output;
  const std::string path = ::testing::TempDir() + "/omni-space.service";
  std::ofstream(path) << r.output;
  r = testing::Run("systemd-analyze verify " + path);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output, "") << "systemd-analyze warned:\n" << r.output;
}

TEST(InstallService, BadOptionsAreErrors) {
  const std::string build = " --build " + std::string(OMNI_BINARY_DIR);
  for (const char* bad : {"--bogus", "--user no_such_user_here", "--bitrate fast",
                          "--config config/missing.yaml", "--name 'a b'"}) {
    const auto r = testing::Run(kScript + " --print " + bad + build);
    EXPECT_EQ(r.exit_code, 2) << bad << ": " << r.output;
    EXPECT_NE(r.output.find("install-service:"), std::string::npos) << bad << ": " << r.output;
  }
}

}  // namespace
}  // namespace omni
