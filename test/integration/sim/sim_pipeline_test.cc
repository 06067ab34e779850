// The stack on the built-in simulator, process by process: omni-sim writes a log and the truth
// (its base is the firmware and base bridge code in the loop); the odometry, RBPF and pose-graph
// mappers read the whole tour's log (file://) and are scored against the truth; then, over UDP in a
// private network namespace, rbpf_mapper publishes the poses that octomap_builder needs to place
// the depth frames, and the 3D map must hold the low box that the lidar's plane passes over.
#include <octomap/octomap.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "../tools/mapper_replay.h"
#include "../tools/run.h"
#include "omni/eval/eval.h"
#include "omni/io/grid.h"
#include "omni/io/trajectory_io.h"

namespace omni {
namespace {

std::string Simulate(const std::string& dir, const std::string& args) {
  std::filesystem::create_directories(dir);
  const auto r = testing::Run(testing::Bin("omni-sim") + " --out " + dir + " " + args);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  return r.output;
}

// A live tour stopped by SIGINT (Ctrl-C, a supervisor's stop) ends at the next step with its log
// closed and its truth written; it used to die without either.
TEST(SimPipeline, ALiveTourStoppedBySignalKeepsItsLogAndTruth) {
  // SIGINT (Ctrl-C) and SIGHUP (the terminal or SSH session went away) alike.
  for (const char* sig : {"INT", "HUP"}) {
    SCOPED_TRACE(sig);
    const std::string dir = ::testing::TempDir() + "/sim_sig" + sig;
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    const auto r = testing::Run("timeout --preserve-status -s " + std::string(sig) + " 2 " +
                                testing::Bin("omni-sim") + " --out " + dir +
                                " --no-depth --live memq:// --speed 1; echo rc=$?");
    EXPECT_NE(r.output.find("stopped by a signal"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("rc=0"), std::string::npos) << r.output;
    EXPECT_TRUE(std::filesystem::exists(dir + "/truth.txt")) << r.output;
    EXPECT_TRUE(std::filesystem::exists(dir + "/truth_map.yaml")) << r.output;
    const auto check = testing::Run(testing::Bin("omni-logcat") + " " + dir + "/sim.lcmlog");
    EXPECT_EQ(check.exit_code, 0) << check.output;
  }
}

// The base options: each base runs, bad values are errors that name the option.
TEST(SimPipeline, OmniSimBaseOptions) {
  const std::string dir = ::testing::TempDir() + "/sim_opts";
  std::filesystem::create_directories(dir);
  const std::string sim = testing::Bin("omni-sim") + " --out " + dir + " --no-depth ";
  auto r = testing::Run(sim + "--duration 2 --base ideal");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.find("firmware in the loop"), std::string::npos) << r.output;
  r = testing::Run(sim + "--duration 2 --slip 0.05,0,0 --slip-noise 0");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("firmware RUNNING, fault bits 0x0"), std::string::npos) << r.output;
  for (const char* bad : {"--base wheels", "--slip 0.1,0.2", "--slip 0.1,0.2,0.6", "--slip 0.1,x,0",
                          "--slip-noise 0.5", "--still -1", "--still 5 --drive bus"}) {
    r = testing::Run(sim + bad);
    EXPECT_EQ(r.exit_code, 2) << bad << ": " << r.output;
    const std::string opt = std::string(bad).substr(0, std::string(bad).find(' '));
    EXPECT_NE(r.output.find(opt), std::string::npos) << bad << ": " << r.output;
  }
}

TEST(SimPipeline, MappersBeatTheDriftingOdometryOnTheSimulatedTour) {
  const std::string dir = ::testing::TempDir() + "/sim_2d";
  // The whole tour, so both SLAM processes close their loops: on the firmware base, 80 s
  // (before the first loop) leave the pose graph bent by up to 8 cm (docs/sim.md).
  const std::string out = Simulate(dir, "--no-depth");
  EXPECT_NE(out.find("tour finished"), std::string::npos) << out;
  EXPECT_NE(out.find("firmware RUNNING, fault bits 0x0, 0 watchdog stops; bridge: ok"),
            std::string::npos)
      << out;
  const std::string url = " --url 'file://" + dir + "/sim.lcmlog?speed=0'";
  const std::string cfg = " --config " OMNI_SOURCE_DIR "/config/";
  auto r = testing::Run(testing::Bin("odom_mapper") + cfg + "odom_mapper.yaml --out " + dir + url);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::Run(testing::Bin("rbpf_mapper") + cfg + "rbpf_mapper.yaml --out " + dir + "/rbpf" +
                   url);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::Run(testing::Bin("pose_graph_mapper") + cfg + "pose_graph_mapper.yaml --out " + dir +
                   "/pg" + url);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  size_t n_odom = 0, n_rbpf = 0, n_pg = 0;
  const std::string truth = dir + "/truth.txt";
  const double odom = testing::AteRmse(truth, dir + "/odom_trajectory.txt", &n_odom);
  const double rbpf = testing::AteRmse(truth, dir + "/rbpf/trajectory.txt", &n_rbpf);
  const double pg = testing::AteRmse(truth, dir + "/pg/trajectory.txt", &n_pg);
  EXPECT_GE(n_rbpf, 2390u);
  EXPECT_GE(n_pg, 2390u);
  // The wheels' slip has bent the odometry by metres; both SLAM processes stay within
  // centimetres of the truth.
  EXPECT_GT(odom, 1.0) << "odometry ATE " << odom;
  // The lidar sweeps (0.1 s per scan): without undoing the motion during the sweep both
  // mappers end near 0.02-0.03 m, with it below 0.01 m (docs/sim.md).
  EXPECT_LT(rbpf, 0.015) << "RBPF ATE " << rbpf;
  EXPECT_LT(pg, 0.015) << "pose-graph ATE " << pg;

  // The world as a map, in the mappers' frame: free where the robot started, walls where the
  // mappers saw them (both SLAM maps need no alignment against it), and map_fusion's vote of
  // the two SLAM maps scores better than either (each fills in cells the other did not see).
  auto truth_map = io::ReadMapServer(dir + "/truth_map.yaml");
  ASSERT_TRUE(truth_map.ok()) << truth_map.error().message;
  const int c0 = static_cast<int>(std::floor(-truth_map->origin_x_m / truth_map->resolution_m));
  const int r0 = static_cast<int>(std::floor(-truth_map->origin_y_m / truth_map->resolution_m));
  EXPECT_EQ(eval::NormalizedCell(truth_map->at(c0, r0)), 0);
  auto rbpf_map = io::ReadMapServer(dir + "/rbpf/map.yaml");
  auto pg_map = io::ReadMapServer(dir + "/pg/map.yaml");
  ASSERT_TRUE(rbpf_map.ok() && pg_map.ok());
  const auto er = eval::CompareMaps(*truth_map, *rbpf_map);
  const auto ep = eval::CompareMaps(*truth_map, *pg_map);
  // Walls only where the world has them: a map rendered from the scans without undoing the
  // lidar's sweep smears them (pose graph 0.96).
  EXPECT_GT(er.precision, 0.99);
  EXPECT_GT(ep.precision, 0.99);
  EXPECT_LT(std::abs(er.dx_m) + std::abs(er.dy_m), 0.1);
  r = testing::Run(testing::Bin("map_fusion") + cfg + "map_fusion.yaml --fuse " + dir +
                   "/pg/map.yaml " + dir + "/rbpf/map.yaml --out " + dir + "/fusion");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto fused = io::ReadMapServer(dir + "/fusion/fused_map.yaml");
  ASSERT_TRUE(fused.ok()) << fused.error().message;
  const auto ef = eval::CompareMaps(*truth_map, *fused);
  EXPECT_LT(ef.error, std::min(er.error, ep.error))
      << "RBPF " << er.error << " pose graph " << ep.error << " fused " << ef.error;
}

// Eight people walking through the floor (omni-sim --walkers): the lidar sees them, the truth
// map does not hold them. Both SLAM processes keep their paths within centimetres and their
// maps free of them: the 360-degree lidar sees where a person stood empty again (docs/sim.md,
// "People").
TEST(SimPipeline, PeopleWalkingBendNeitherSlamPathNorMap) {
  const std::string dir = ::testing::TempDir() + "/sim_walkers";
  const std::string out = Simulate(dir, "--no-depth --walkers 8");
  EXPECT_NE(out.find("tour finished"), std::string::npos) << out;
  EXPECT_NE(out.find("omni-sim: 8 walkers"), std::string::npos) << out;
  EXPECT_NE(out.find(", 0.00 touching it"), std::string::npos) << out;
  EXPECT_TRUE(std::filesystem::exists(dir + "/walkers.txt"));
  const std::string url = " --url 'file://" + dir + "/sim.lcmlog?speed=0'";
  const std::string cfg = " --config " OMNI_SOURCE_DIR "/config/";
  auto r = testing::Run(testing::Bin("rbpf_mapper") + cfg + "rbpf_mapper.yaml --out " + dir +
                        "/rbpf" + url);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::Run(testing::Bin("pose_graph_mapper") + cfg + "pose_graph_mapper.yaml --out " + dir +
                   "/pg" + url);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  size_t n_rbpf = 0, n_pg = 0;
  const double rbpf = testing::AteRmse(dir + "/truth.txt", dir + "/rbpf/trajectory.txt", &n_rbpf);
  const double pg = testing::AteRmse(dir + "/truth.txt", dir + "/pg/trajectory.txt", &n_pg);
  EXPECT_GE(n_rbpf, 2390u);
  EXPECT_GE(n_pg, 2390u);
  // Without people both end below 0.01 m; with eight, within 3 mm of that (docs/sim.md).
  EXPECT_LT(rbpf, 0.015) << "RBPF ATE " << rbpf;
  EXPECT_LT(pg, 0.015) << "pose-graph ATE " << pg;
  auto truth_map = io::ReadMapServer(dir + "/truth_map.yaml");
  auto rbpf_map = io::ReadMapServer(dir + "/rbpf/map.yaml");
  auto pg_map = io::ReadMapServer(dir + "/pg/map.yaml");
  ASSERT_TRUE(truth_map.ok() && rbpf_map.ok() && pg_map.ok());
  // A person left in a map is a wall where the truth has floor: precision falls.
  EXPECT_GT(eval::CompareMaps(*truth_map, *rbpf_map).precision, 0.98);
  EXPECT_GT(eval::CompareMaps(*truth_map, *pg_map).precision, 0.98);
}

TEST(SimPipeline, OctomapPosedByTheLiveRbpfHoldsTheLowBox) {
  if (testing::Run("unshare -n true").exit_code != 0)
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string dir = ::testing::TempDir() + "/sim_3d";
  Simulate(dir, "--duration 20 --depth-hz 2");
  const auto r = testing::RunReplayInNetns(
      dir,
      {testing::Bin("rbpf_mapper") +
           " --config " OMNI_SOURCE_DIR "/config/rbpf_mapper.yaml --out " + dir +
           "/rbpf --idle-exit 2",
       testing::Bin("octomap_builder") +
           " --config " OMNI_SOURCE_DIR "/config/octomap_builder.yaml --out " + dir +
           "/octomap --idle-exit 3"},
      dir + "/sim.lcmlog", "2");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  ASSERT_TRUE(std::filesystem::exists(dir + "/octomap/map.bt")) << r.output;
  octomap::OcTree tree(0.05);
  ASSERT_TRUE(tree.readBinary(dir + "/octomap/map.bt"));
  EXPECT_GT(tree.getNumLeafNodes(), 1000u);
  // The low box of the built-in world at x 7.8..8.4, y 1.7..2.2, 0.12 m tall, in the map frame
  // of the SLAM (its origin is the first pose, (2.5, 3.0) facing +x): x 5.3..5.9, y -1.3..-0.8.
  auto occupied_in = [&](double x0, double y0, double x1, double y1, double z0, double z1) {
    int n = 0;
    for (auto it = tree.begin_leafs_bbx(octomap::point3d(x0, y0, z0), octomap::point3d(x1, y1, z1));
         it != tree.end_leafs_bbx(); ++it)
      n += tree.isNodeOccupied(*it);
    return n;
  };
  EXPECT_GE(occupied_in(5.3, -1.3, 5.9, -0.8, 0.03, 0.15), 4);
  // Above it (0.2..1.0 m) there is nothing but air.
  EXPECT_EQ(occupied_in(5.3, -1.3, 5.9, -0.8, 0.25, 1.0), 0);
}

// --live publishes on the bus at the chosen speed: odom_mapper, listening over UDP in a private
// network namespace, receives every scan (10 s of simulation at 5x: 100 scans in about 2 s; the
// 101st sweep is still turning when the run stops).
TEST(SimPipeline, LiveModePublishesOnTheBus) {
  if (testing::Run("unshare -n true").exit_code != 0)
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string dir = ::testing::TempDir() + "/sim_live";
  std::filesystem::create_directories(dir);
  {
    std::ofstream s(dir + "/run.sh");
    s << "set -u\nip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304'\n"
      << testing::Bin("odom_mapper") << " --config " OMNI_SOURCE_DIR "/config/odom_mapper.yaml"
      << " --out " << dir << " --idle-exit 1 & m=$!\nsleep 0.5\n"
      << "start=$(date +%s%N)\n"
      << testing::Bin("omni-sim") << " --out " << dir
      << " --duration 10 --no-depth --live \"$LCM_DEFAULT_URL\" --speed 5 || exit 1\n"
      << "echo \"sim wall ms: $(( ($(date +%s%N) - start) / 1000000 ))\"\nwait $m\n";
  }
  const auto r = testing::Run("timeout 120 unshare -n bash " + dir + "/run.sh");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("mapped 100 of 100 scans"), std::string::npos) << r.output;
  // Paced: 10 s at 5x takes about 2 s of wall time, not the fraction of a second it computes in.
  const size_t at = r.output.find("sim wall ms: ");
  ASSERT_NE(at, std::string::npos) << r.output;
  const int ms = std::stoi(r.output.substr(at + 13));
  EXPECT_GT(ms, 1800) << r.output;
  EXPECT_LT(ms, 10000) << r.output;
}

// --drive bus: the simulated base is driven by BASE_CMD from another process (omni-drive, as a
// planner would, then its keyboard teleop fed through a pipe), over UDP in a private network
// namespace; it moves as commanded, stops when the commands stop, and counts what it received.
TEST(SimPipeline, DriveBusTakesBaseCmdFromAnotherProcess) {
  {
    const auto r = testing::Run(testing::Bin("omni-sim") + " --out " + ::testing::TempDir() +
                                "/sim_nolive --drive bus");
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_NE(r.output.find("--drive bus needs --live URL"), std::string::npos) << r.output;
  }
  if (testing::Run("unshare -n true").exit_code != 0)
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string dir = ::testing::TempDir() + "/sim_drive";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  {
    std::ofstream s(dir + "/run.sh");
    s << "set -u\nip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0'\n"
      << testing::Bin("omni-sim") << " --out " << dir
      << " --no-depth --duration 7 --drive bus --live \"$LCM_DEFAULT_URL\" & s=$!\n"
      << "sleep 1\n"
      << testing::Bin("omni-drive") << " --vx 0.3 --duration 2 || exit 4\n"
      << "(printf 'xy'; for i in $(seq 15); do printf w; sleep 0.1; done; printf ' '; sleep 0.3)"
      << " | " << testing::Bin("omni-drive") << " --keys || exit 5\n"
      << testing::Bin("omni-drive") << " --estop || exit 6\n"
      << "wait $s\n";
  }
  const auto r = testing::Run("timeout 60 unshare -n bash " + dir + "/run.sh");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("sent 40 twists"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("teleop ended"), std::string::npos) << r.output;
  // Left e-stopped by the operator: said, and not an unhealthy end (exit 0 above).
  EXPECT_NE(r.output.find("the base ends e-stopped, as commanded"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("vx +0.20 m/s"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("reports the base e-stopped"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("on the bus: "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(" commands, 0 refused by the base, 0 undecodable"), std::string::npos)
      << r.output;
  auto truth = io::ReadTrajectory(dir + "/truth.txt");
  ASSERT_TRUE(truth.ok()) << truth.error().message;
  ASSERT_GE(truth->entries.size(), 65u);
  const Pose2 first = truth->entries.front().pose2();
  const Pose2 last = truth->entries.back().pose2();
  // 2 s at 0.3 m/s straight ahead, then about 1.5 s at 0.2 m/s from the held key (the process
  // start-up and the bus add jitter, not distance). The e-stop is confirmed by the bridge's
  // BASE_STATUS (omni-drive exits 1 otherwise).
  EXPECT_NEAR(last.x - first.x, 0.9, 0.2) << r.output;
  EXPECT_NEAR(last.y - first.y, 0.0, 0.05) << r.output;
}

// Map saving on request: while the simulator's log is replayed into the mappers over UDP (in a
// private network namespace), `omni-save-map` asks every mapper for its maps; each answers and
// its files are there while it keeps mapping, and it still writes its own at the end. A request
// for a process that is not there gets no answer (exit 3); a relative --dir is the caller's.
TEST(SimPipeline, MappersSaveTheirMapsOnRequestWhileMapping) {
  if (testing::Run("unshare -n true").exit_code != 0)
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string dir = ::testing::TempDir() + "/sim_save";
  std::filesystem::remove_all(dir);
  Simulate(dir, "--duration 12 --no-depth");
  const std::string cfg = " --config " OMNI_SOURCE_DIR "/config/";
  {
    std::ofstream s(dir + "/run.sh");
    s << "set -u\nip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304'\n"
      << testing::Bin("rbpf_mapper") << cfg << "rbpf_mapper.yaml --out " << dir
      << "/rbpf --idle-exit 2 &\n"
      << testing::Bin("pose_graph_mapper") << cfg << "pose_graph_mapper.yaml --out " << dir
      << "/pg --idle-exit 2 &\n"
      << testing::Bin("odom_mapper") << cfg << "odom_mapper.yaml --out " << dir
      << "/odom --idle-exit 2 &\n"
      << "sleep 0.5\n"
      << testing::Bin("omni-replay") << " " << dir << "/sim.lcmlog --speed 2 >/dev/null & r=$!\n"
      << "sleep 3\n"
      << testing::Bin("omni-save-map") << " --dir " << dir << "/mid --wait 20; echo \"all: $?\"\n"
      << testing::Bin("omni-save-map") << " --process nobody --wait 0.5; echo \"nobody: $?\"\n"
      << "(cd " << dir << " && " << testing::Bin("omni-save-map")
      << " --process odom_mapper --dir rel --wait 20); echo \"relative: $?\"\n"
      << "wait\n";
  }
  const auto r = testing::Run("timeout 120 unshare -n bash " + dir + "/run.sh");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("all: 0"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("nobody: 3"), std::string::npos) << r.output;
  // A relative folder is this shell's, not the mapper's working folder.
  EXPECT_NE(r.output.find("relative: 0"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("odom_mapper: saved: maps written to " +
                          std::filesystem::canonical(dir).string() + "/rel"),
            std::string::npos)
      << r.output;
  for (const char* p : {"rbpf_mapper", "pose_graph_mapper", "odom_mapper"})
    EXPECT_NE(r.output.find(std::string(p) + ": saved: maps written to " + dir + "/mid/" + p),
              std::string::npos)
        << p << ": " << r.output;
  // Mid-run maps: part of the run, so fewer trajectory lines than at the end.
  auto lines = [](const std::string& path) {
    std::ifstream f(path);
    int n = 0;
    for (std::string l; std::getline(f, l);) n += !l.empty() && l[0] != '#';
    return n;
  };
  for (const char* m : {"/mid/rbpf_mapper/map.yaml", "/mid/pose_graph_mapper/map.yaml",
                        "/mid/pose_graph_mapper/graph.g2o", "/mid/odom_mapper/odom_map.yaml",
                        "/rbpf/map.yaml", "/pg/map.yaml", "/odom/odom_map.yaml"})
    EXPECT_TRUE(std::filesystem::exists(dir + m)) << m << "\n" << r.output;
  const int mid = lines(dir + "/mid/pose_graph_mapper/trajectory.txt");
  const int end = lines(dir + "/pg/trajectory.txt");
  EXPECT_GT(mid, 10);
  EXPECT_LT(mid, end);
  EXPECT_EQ(end, 120) << "every scan of the 12 s log, after the mid-run save";
  EXPECT_LT(lines(dir + "/mid/rbpf_mapper/trajectory.txt"), lines(dir + "/rbpf/trajectory.txt"));
}

}  // namespace
}  // namespace omni
