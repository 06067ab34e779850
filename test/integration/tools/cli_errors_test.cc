// Bad input to the command-line tools: a clear message naming the file and line or offset,
// and a non-zero exit. Nothing half-written is left behind.
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include <gtest/gtest.h>

#include "../../unit/common/test_paths.h"
#include "omni/io/lcm_log.h"
#include "omni/io/previous_outputs.h"
#include "run.h"

namespace omni {
namespace {

using testing::Bin;

void Write(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

// A mapper started on a folder another process is writing (a second copy beside the supervisor's,
// or two mappers left on one folder) refuses to start, naming the holder, and leaves the
// holder's files where they are; the mappers' default folders differ, so two started by hand
// without --out do not meet.
TEST(CliErrors, AMapperRefusesAFolderAnotherProcessWrites) {
  const std::string dir = testing::TempDir();
  Write(dir + "/map.pgm", "the running mapper's");
  auto held = io::OutputFolderLock::Take(dir, "rbpf_mapper");
  ASSERT_TRUE(held.ok()) << held.error().message;
  for (const std::string bin :
       {"rbpf_mapper", "pose_graph_mapper", "odom_mapper", "map_fusion", "octomap_builder"}) {
    SCOPED_TRACE(bin);
    const auto r = testing::Run(Bin(bin) + " --url memq:// --idle-exit 1 --out " + dir);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("is being written by rbpf_mapper (pid "), std::string::npos)
        << r.output;
  }
  std::ifstream in(dir + "/map.pgm");
  EXPECT_EQ(std::string((std::istreambuf_iterator<char>(in)), {}), "the running mapper's");
  EXPECT_FALSE(std::filesystem::exists(dir + "/previous"));
}

// The omni script's lists of tools and benchmarks (what `./omni NAME` accepts) match what the
// build makes, and a typo is refused without starting a build.
TEST(CliErrors, OmniScriptKnowsEveryTool) {
  std::ifstream in(std::string(OMNI_SOURCE_DIR) + "/omni");
  const std::string script((std::istreambuf_iterator<char>(in)), {});
  auto list = [&](const std::string& var) {
    const size_t at = script.find("\n" + var + "=\"");
    EXPECT_NE(at, std::string::npos) << var;
    const size_t from = at + var.size() + 3;
    std::istringstream words(script.substr(from, script.find('"', from) - from));
    std::set<std::string> out;
    for (std::string w; words >> w;) out.insert(w);
    return out;
  };
  // The omni-* targets of this configuration (collected by the top-level CMakeLists.txt).
  std::set<std::string> tools, benches;
  std::istringstream targets(OMNI_TOOL_TARGETS);
  for (std::string n; targets >> n;) {
    if (n.rfind("omni-bench-", 0) == 0)
      benches.insert(n.substr(11));
    else
      tools.insert(n.substr(5));
  }
  EXPECT_EQ(list("TOOLS"), tools);
  // ./omni fuzz knows every target in test/fuzz (NAME_fuzz.cc).
  std::set<std::string> fuzz;
  for (const auto& e :
       std::filesystem::directory_iterator(std::string(OMNI_SOURCE_DIR) + "/test/fuzz")) {
    const std::string f = e.path().filename().string();
    if (f.size() > 8 && f.compare(f.size() - 8, 8, "_fuzz.cc") == 0)
      fuzz.insert(f.substr(0, f.size() - 8));
  }
  EXPECT_EQ(list("FUZZ_TARGETS"), fuzz);
  // A build without Google Benchmark lacks some benchmarks; the script may list more.
  const std::set<std::string> listed = list("BENCHMARKS");
  for (const auto& b : benches) EXPECT_TRUE(listed.count(b)) << b << " missing from BENCHMARKS";
  // A fake ninja first on PATH would leave a mark if the script tried to build.
  const std::string dir = testing::TempDir() + "/omni_typo";
  std::filesystem::create_directories(dir);
  Write(dir + "/ninja", "#!/bin/sh\ntouch " + dir + "/built\n");
  std::filesystem::permissions(dir + "/ninja", std::filesystem::perms::owner_all);
  auto r = testing::Run("PATH=" + dir + ":$PATH OMNI_BUILD_DIR=" + std::string(OMNI_BINARY_DIR) +
                        " " + OMNI_SOURCE_DIR + "/omni stauts");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("unknown command 'stauts'"), std::string::npos) << r.output;
  r = testing::Run("PATH=" + dir + ":$PATH " + std::string(OMNI_SOURCE_DIR) + "/omni bench --help");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("rbpf"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir + "/built")) << "a typo or --help started a build";
}

TEST(CliErrors, ImportRefusesToWriteOverItsInput) {
  const std::string dir = testing::TempDir();
  const std::string clf = "ODOM 0 0 0 0 0 0 1.0 h 1.0\n";
  Write(dir + "/same.clf", clf);
  const auto r =
      testing::Run(Bin("omni-import") + " carmen " + dir + "/same.clf " + dir + "/./same.clf");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("is the input file"), std::string::npos) << r.output;
  std::ifstream in(dir + "/same.clf");
  EXPECT_EQ(std::string((std::istreambuf_iterator<char>(in)), {}), clf) << "input untouched";
}

TEST(CliErrors, EvalRefusesOutOfRangeOptions) {
  for (const char* opt : {"--tolerance-cells -1", "--tolerance-cells 1.5", "--max-shift-m -2",
                          "--max-rotation-deg -5", "--delta 0", "--max-dt -1"}) {
    const auto r = testing::Run(Bin("omni-eval") + " map a.pgm b.pgm " + opt);
    EXPECT_EQ(r.exit_code, 2) << opt << ": " << r.output;
    EXPECT_NE(r.output.find("must be"), std::string::npos) << opt << ": " << r.output;
  }
}

TEST(CliErrors, TruncatedCarmenLine) {
  const std::string dir = testing::TempDir();
  Write(dir + "/bad.clf", "ODOM 0 0 0 0 0 0 1.0 h 1.0\nFLASER 180 1.0 1.0\n");
  const auto r =
      testing::Run(Bin("omni-import") + " carmen " + dir + "/bad.clf " + dir + "/out.lcmlog");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("bad.clf:2"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir + "/out.lcmlog"));
}

// Found by the configuration review of 2026-12-06: values that ran forever, aborted or were
// refused against the docs, and an import that wrote an empty log.
TEST(CliErrors, ValuesTheDocsPromiseOrForbid) {
  const std::string dir = testing::TempDir();
  // A file of no CARMEN lines is not imported.
  Write(dir + "/traj.txt", "0 1.0 0 0 0\n1 2.0 1 0 0\n");
  auto r = testing::Run(Bin("omni-import") + " carmen " + dir + "/traj.txt " + dir + "/e.lcmlog");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("not a CARMEN log"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir + "/e.lcmlog"));
  // Imported, but said: lines stamped 0, laser lines sharing stamps, no laser line at all.
  Write(dir + "/stamps.clf",
        "ODOM 0 0 0 0 0 0 0 host 0\n"
        "ODOM 0.1 0 0 0 0 0 5.0 host 5.0\n"
        "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 5.0 host 5.0\n"
        "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 5.0 host 5.0\n");
  r = testing::Run(Bin("omni-import") + " carmen " + dir + "/stamps.clf " + dir + "/s.lcmlog");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("1 lines are stamped 0"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("1 of 2 laser lines repeat the stamp"), std::string::npos) << r.output;
  Write(dir + "/odom_only.clf", "ODOM 0 0 0 0 0 0 1.0 host 1.0\nRAWLASER1 1 2 3\n");
  r = testing::Run(Bin("omni-import") + " carmen " + dir + "/odom_only.clf " + dir + "/o.lcmlog");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("no laser line was read"), std::string::npos) << r.output;
  // The drivers' --duration-s: NaN, negative, infinite ran forever.
  for (const char* v : {"nan", "-5", "inf", "1e300"}) {
    r = testing::Run("timeout 10 " + Bin("omni-rplidar-driver") +
                     " --config " OMNI_SOURCE_DIR
                     "/config/rplidar_driver.yaml --port /nonexistent --duration-s " +
                     v);
    EXPECT_EQ(r.exit_code, 2) << v << ": " << r.output;
    EXPECT_NE(r.output.find("--duration-s"), std::string::npos) << r.output;
  }
  // omni-slam's --particles / --threads follow the config's ranges (100000 threads aborted).
  for (const char* opt : {"--threads 100000", "--particles 4294967297", "--particles 5000"}) {
    r = testing::Run(Bin("omni-slam") + " rbpf " + dir + "/traj.txt --out " + dir + "/s " + opt);
    EXPECT_EQ(r.exit_code, 2) << opt << ": " << r.output;
    EXPECT_NE(r.output.find("must be in [1, "), std::string::npos) << opt << ": " << r.output;
  }
  // omni-octomap build: --max-range < 0 is "unlimited", as its help and the config say; 0 is not.
  r = testing::Run(Bin("omni-octomap") + " build /nonexistent.lcmlog --out " + dir +
                   "/o --max-range -1");
  EXPECT_EQ(r.output.find("--max-range"), std::string::npos) << r.output;
  r = testing::Run(Bin("omni-octomap") + " build /nonexistent.lcmlog --out " + dir +
                   "/o --max-range 0");
  EXPECT_NE(r.output.find("--max-range must be > 0, or < 0 for unlimited"), std::string::npos)
      << r.output;
}

TEST(CliErrors, G2oUnknownTag) {
  const std::string dir = testing::TempDir();
  Write(dir + "/g.g2o", "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_FOO 0 1\n");
  const auto r = testing::Run(Bin("omni-posegraph-check") + " " + dir + "/g.g2o");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("g.g2o:3"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("EDGE_FOO"), std::string::npos) << r.output;
}

TEST(CliErrors, MisspelledConfigKey) {
  const std::string dir = testing::TempDir();
  Write(dir + "/odom.yaml", "resolution_m: 0.05\nmax_pose_gap: 0.5\n");
  const auto r = testing::Run(Bin("odom_mapper") + " --config " + dir +
                              "/odom.yaml --url memq:// --out " + dir);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("odom.yaml:2"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("'max_pose_gap'"), std::string::npos) << r.output;
}

TEST(CliErrors, ShippedOdomMapperConfigLoads) {
  const std::string dir = testing::TempDir();
  // An empty memq bus ends immediately; the config must load before that.
  const auto r = testing::Run(Bin("odom_mapper") + " --config " + OMNI_SOURCE_DIR +
                              "/config/odom_mapper.yaml --url memq:// --idle-exit 0.1 --out " +
                              dir + " & sleep 0.5; kill -TERM $! ; wait $!");
  EXPECT_EQ(r.output.find("bad config"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("no scan was mapped"), std::string::npos) << r.output;
  // Stopped before anything arrived (systemctl stop on an idle robot): nothing lost, exit 0.
  EXPECT_EQ(r.exit_code, 0) << r.output;
}

// A shell line that starts `cmd` in the background and sends it SIGHUP once it has its handler
// (SigCgt bit 0 = SIGHUP), not after a fixed wait a loaded machine may outlast; its exit status
// is the process's.
std::string HangupOnceHandled(const std::string& cmd) {
  return cmd +
         " & p=$!; for i in $(seq 200); do m=$(awk '/^SigCgt/{print $2}' /proc/$p/status "
         "2>/dev/null); [ -n \"$m\" ] && [ $(( 0x$m & 1 )) = 1 ] && break; sleep 0.05; done; "
         "kill -HUP $p; wait $p";
}

// A hangup (the terminal or SSH session the process was started from went away) stops the
// mappers and drivers in order, as SIGTERM does: exit 0 and, for a mapper, its outputs handled
// (with nothing mapped: said, and no empty map written over a real one). Before, SIGHUP's
// default killed them at once (octomap_builder: exit 129).
TEST(CliErrors, AHangupStopsProcessesInOrder) {
  const std::string dir = testing::TempDir();
  for (const std::string& cmd : {Bin("odom_mapper") + " --url memq:// --out " + dir + "/odom",
                                 Bin("octomap_builder") + " --url memq:// --out " + dir + "/octo",
                                 Bin("omni-base-bridge") + " --config " + OMNI_SOURCE_DIR +
                                     "/config/base_bridge.yaml --url memq://"}) {
    SCOPED_TRACE(cmd);
    const auto r = testing::Run(HangupOnceHandled(cmd));
    EXPECT_EQ(r.exit_code, 0) << r.output;
    if (cmd.find("octomap_builder") != std::string::npos) {
      EXPECT_NE(r.output.find("no frame was inserted: nothing to write"), std::string::npos)
          << r.output;
    }
  }
  EXPECT_FALSE(std::filesystem::exists(dir + "/octo/map.bt"));
  // Its output pipe gone (`... | tee` ended by the same hangup): a log line fails instead of
  // killing the process (SIGPIPE, exit 141 before) before it can stop in order.
  const auto r = testing::Run(
      "bash -c '" + Bin("odom_mapper") + " --url memq:// --out " + dir +
      "/odom2 > >(true) 2>&1 & p=$!; for i in $(seq 200); do m=$(awk \"/^SigCgt/{print "
      "\\$2}\" /proc/$p/status 2>/dev/null); [ -n \"$m\" ] && [ $(( 0x$m & 0x4000 )) != 0 ] "
      "&& break; sleep 0.05; done; sleep 0.3; kill -TERM $p; wait $p; echo rc=$?'");
  EXPECT_NE(r.output.find("rc=0"), std::string::npos) << r.output;
}

// The tools stop in order on a hangup too: the firmware simulator writes its truth file, an
// emulator closes its port, a replay says where it was interrupted. Before, SIGHUP's default
// killed them (exit 129).
TEST(CliErrors, AHangupStopsTheToolsInOrder) {
  const std::string dir = testing::TempDir() + "/hangup_tools";
  std::filesystem::create_directories(dir);
  {
    auto w = io::LcmLogWriter::Open(dir + "/slow.lcmlog");
    ASSERT_TRUE(w.ok()) << w.error().message;
    const char payload[4] = {1, 2, 3, 4};
    for (int i = 0; i < 100; ++i)  // one event a second: the replay is still running
      ASSERT_TRUE(w->Write(1'700'000'000'000'000 + i * 1'000'000LL, "X", payload, 4).ok());
    ASSERT_TRUE(w->Close().ok());
  }
  const std::string shm = "shm:hup" + std::to_string(getpid());
  struct Case {
    std::string cmd;
    int exit_code;
    const char* says;
  };
  for (const Case& c : {
           Case{Bin("omni-firmware-sim") + " --config " + OMNI_SOURCE_DIR +
                    "/config/firmware_sim.yaml --can " + shm + " --truth-out " + dir + "/truth.csv",
                0, ""},
           Case{Bin("omni-rplidar-emulator") + " --link " + dir + "/lidar", 0, ""},
           Case{Bin("omni-replay") + " " + dir + "/slow.lcmlog --url memq://", 130,
                "[interrupted]"},
       }) {
    SCOPED_TRACE(c.cmd);
    const auto r = testing::Run(HangupOnceHandled(c.cmd));
    EXPECT_EQ(r.exit_code, c.exit_code) << r.output;
    EXPECT_NE(r.output.find(c.says), std::string::npos) << r.output;
  }
  std::ifstream truth(dir + "/truth.csv");
  std::string header;
  std::getline(truth, header);
  EXPECT_EQ(header.rfind("t_s,", 0), 0u) << header;
}

// A folder or a device where a file is expected is a clear error: omni-decode threw on a folder
// (abort) and read /dev/zero without end, omni-logcat reported a folder as an empty log, and an
// LED mode of NaN was cast to int before its range check.
TEST(CliErrors, ToolsRefuseFoldersDevicesAndNaN) {
  const std::string dir = testing::TempDir();
  struct Case {
    std::string cmd;
    int exit_code;
    const char* says;
  };
  for (const Case& c : {
           Case{Bin("omni-decode") + " imu " + dir, 1, "is not a file or a pipe"},
           Case{Bin("omni-decode") + " rplidar /dev/zero", 1, "is not a file or a pipe"},
           Case{"bash -c '" + Bin("omni-decode") + " imu <(printf abc)'", 0, ""},  // a pipe
           Case{Bin("omni-logcat") + " " + dir, 1, "read error"},
           Case{Bin("omni-devices") + " kinect-led nan", 2, "LED mode must be an integer 0..6"},
           Case{Bin("omni-devices") + " kinect-led 1e300", 2, "LED mode must be an integer"},
       }) {
    const auto r = testing::Run("timeout 10 " + c.cmd);
    EXPECT_EQ(r.exit_code, c.exit_code) << c.cmd << ": " << r.output;
    EXPECT_NE(r.output.find(c.says), std::string::npos) << c.cmd << ": " << r.output;
  }
}

// A number that does not parse is an error naming the program, the option and the value,
// never read as 0 (which would mean "never idle-exit", seed 0, or the first map).
TEST(CliErrors, BadNumbersOnTheCommandLineAreNamed) {
  struct Case {
    const char* bin;
    const char* args;
    const char* says;
  };
  for (const Case& c : {
           Case{"rbpf_mapper", "--idle-exit 2s", "rbpf_mapper: --idle-exit expects a number"},
           Case{"rbpf_mapper", "--seed one", "rbpf_mapper: --seed expects a whole number"},
           Case{"pose_graph_mapper", "--idle-exit -1", "--idle-exit expects a number"},
           Case{"odom_mapper", "--idle-exit", "odom_mapper: --idle-exit needs a value"},
           Case{"octomap_builder", "--idle-exit nan", "--idle-exit expects a number"},
           Case{"map_fusion", "--fuse a.yaml --base 0", "--base expects a whole number in [1, "},
           Case{"supervisor", "--duration-s 1x", "supervisor: --duration-s expects a number"},
           Case{"omni-base-bridge", "--config x.yaml --duration-s y", "--duration-s expects"},
           Case{"omni-base-bridge", "--can can0", "--config FILE is required"},
           Case{"omni-drive", "--vx fast", "omni-drive: --vx expects a number"},
           Case{"omni-drive", "--keys --vx 1", "take no twist"},
           Case{"omni-drive", "--estop --clear-faults", "are two commands"},
           Case{"omni-drive", "--clear-faults --stop", "are two commands"},
           Case{"omni-drive", "--vx 0.2 --rate 2", "--rate expects a number in [5, 1000]"},
           Case{"omni-sim", "--out /tmp/x --speed 2", "--speed paces a --live run"},
           Case{"omni-sim", "--out /tmp/x --base ideal --slip 0.1,0.1,0.1", "--base firmware"},
           Case{"omni-sim", "--out /tmp/x --cmd-channel X", "add --drive bus"},
           Case{"omni-save-map", "--wait 0", "omni-save-map: --wait expects a number"},
           Case{"omni-sim", "--out /tmp/x --seed 1.5", "omni-sim: --seed expects a whole number"},
           Case{"rbpf_mapper", "--bogus", "rbpf_mapper: unknown option '--bogus'"},
       }) {
    const auto r = testing::Run(Bin(c.bin) + " " + c.args);
    EXPECT_EQ(r.exit_code, 2) << c.bin << " " << c.args << ": " << r.output;
    EXPECT_NE(r.output.find(c.says), std::string::npos)
        << c.bin << " " << c.args << ": " << r.output;
  }
  // An e-stop nobody confirms (no base bridge on this bus) is said loudly and exits 1.
  const auto estop = testing::Run(Bin("omni-drive") + " --url memq:// --estop --wait 0.2");
  EXPECT_EQ(estop.exit_code, 1) << estop.output;
  EXPECT_NE(estop.output.find("NOT CONFIRMED: no BASE_STATUS heard"), std::string::npos)
      << estop.output;
  const auto help = testing::Run(Bin("omni-drive") + " --help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.output.find("usage: omni-drive"), std::string::npos) << help.output;
}

TEST(CliErrors, CorruptLcmLog) {
  OMNI_REQUIRE_DATASET(src, "lcm/example.lcmlog");
  const std::string dir = testing::TempDir();
  std::filesystem::copy_file(src, dir + "/x.lcmlog");
  {
    std::fstream f(dir + "/x.lcmlog", std::ios::in | std::ios::out | std::ios::binary);
    // Each event of this log is 28 header + 10 channel + 366 data bytes: hit the 2nd header.
    f.seekp(404 + 2);
    f.write("\xde\xad", 2);
  }
  const auto r = testing::Run(Bin("omni-logcat") + " " + dir + "/x.lcmlog");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("byte offset"), std::string::npos) << r.output;
  const auto replay =
      testing::Run(Bin("omni-replay") + " " + dir + "/x.lcmlog --url memq:// --speed 0");
  EXPECT_NE(replay.exit_code, 0);
  EXPECT_NE(replay.output.find("byte offset"), std::string::npos) << replay.output;
}

// An estimate covering part of the reference is scored on that part, with a warning naming how
// much is left out.
TEST(CliErrors, EvalWarnsWhenTheEstimateCoversPartOfTheReference) {
  const std::string dir = testing::TempDir();
  Write(dir + "/ref.txt", "0 1.0 0 0 0\n1 2.0 1 0 0\n2 3.0 2 0 0\n3 4.0 3 0 0\n");
  Write(dir + "/half.txt", "0 1.0 0 0 0\n1 2.0 1 0 0\n");
  const auto r = testing::Run(Bin("omni-eval") + " ate " + dir + "/ref.txt " + dir + "/half.txt");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("matches 2 of the reference's 4 poses; the other 2 are not scored"),
            std::string::npos)
      << r.output;
}

TEST(CliErrors, EvalOnMissingAndMalformedFiles) {
  const std::string dir = testing::TempDir();
  Write(dir + "/t.txt", "0 1.0 0 0 0\n1 2.0 1 x 0\n");
  auto r = testing::Run(Bin("omni-eval") + " ate " + dir + "/t.txt " + dir + "/t.txt");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("t.txt:2"), std::string::npos) << r.output;
  r = testing::Run(Bin("omni-eval") + " ate /nonexistent_ref.txt " + dir + "/t.txt");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("/nonexistent_ref.txt"), std::string::npos) << r.output;
  r = testing::Run(Bin("omni-eval") + " nonsense a b");
  EXPECT_EQ(r.exit_code, 2);
}

TEST(CliErrors, EvalAteOfIntelRawOdometry) {
  OMNI_REQUIRE_DATASET(clf, "intel-raw/intel.clf");
  OMNI_REQUIRE_DATASET(ref, "intel-raw/intel.reference.txt");
  const std::string dir = testing::TempDir();
  // Raw odometry as an indexed trajectory of every scan, via the FLASER odometry poses.
  const auto w =
      testing::Run("awk '$1==\"FLASER\" {n=$2; print i++, $(n+9), $(n+6), $(n+7), $(n+8)}' " + clf +
                   " > " + dir + "/odom.txt");
  ASSERT_EQ(w.exit_code, 0) << w.output;
  const auto r = testing::Run(Bin("omni-eval") + " ate " + ref + " " + dir + "/odom.txt --json");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto pos = r.output.find("\"ate_rmse_m\": ");
  ASSERT_NE(pos, std::string::npos) << r.output;
  EXPECT_GT(std::stod(r.output.substr(pos + 14)), 10.0) << r.output;
  EXPECT_NE(r.output.find("\"matched\": 174"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace omni
