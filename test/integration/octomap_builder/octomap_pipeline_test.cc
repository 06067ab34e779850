// The pipeline end to end: omni-octomap build on a dataset folder and on an LCM log, and the
// node on memq:// (one process, nothing leaves the machine).
#include <zlib.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>

#include <gtest/gtest.h>

#include "omni/bus/convert.h"
#include "omni/color_image_t.hpp"
#include "omni/heartbeat_t.hpp"
#include "omni/io/grid.h"
#include "omni/io/lcm_log.h"
#include "omni/occupancy_grid_t.hpp"
#include "omni/octomap_builder/color_image.h"
#include "omni/octomap_builder/depth_io.h"
#include "omni/octomap_builder/map_output.h"
#include "omni/octomap_builder/octomap_node.h"
#include "omni/pose2d_t.hpp"
#include "omni/trajectory_t.hpp"

namespace omni::octo {
namespace {

namespace fs = std::filesystem;

struct RunResult {
  int exit_code;
  std::string output;
};
RunResult RunCommand(const std::string& cmd) {
  RunResult r{-1, ""};
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) r.output.append(buf.data(), n);
  const int st = pclose(p);
  r.exit_code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}
std::string Bin(const std::string& name) { return std::string(OMNI_BINARY_DIR) + "/bin/" + name; }
std::string Config() { return std::string(OMNI_SOURCE_DIR) + "/config/octomap_builder.yaml"; }

constexpr double kWallX = 3.0;  // a wall across the map at x = 3 m

// A ZLIB depth frame of the wall seen by the shipped config's camera (x 0.1 m, height 0.45 m,
// looking along the base's x) from a robot at (robot_x, 0, 0) heading +x.
omni::depth_image_t WallFrame(int64_t utime, double robot_x, int64_t seq) {
  omni::depth_image_t m;
  m.utime = utime;
  m.seq = seq;
  m.frame = "depth_optical";
  m.width = 80;
  m.height = 60;
  m.fx = m.fy = 60.0;
  m.cx = 39.5;
  m.cy = 29.5;
  m.depth_scale = 1000;
  m.registered_to_color = false;
  const auto d = static_cast<uint16_t>(std::lround((kWallX - robot_x - 0.1) * 1000));
  std::vector<uint8_t> raw;
  for (int i = 0; i < m.width * m.height; ++i) {
    raw.push_back(static_cast<uint8_t>(d & 0xff));
    raw.push_back(static_cast<uint8_t>(d >> 8));
  }
  std::vector<uint8_t> z(compressBound(raw.size()));
  uLongf zlen = z.size();
  EXPECT_EQ(compress(z.data(), &zlen, raw.data(), raw.size()), Z_OK);
  z.resize(zlen);
  m.encoding = 1;
  m.uncompressed_size = static_cast<int32_t>(raw.size());
  m.data = z;
  m.size = static_cast<int32_t>(z.size());
  return m;
}

omni::pose2d_t Pose(int64_t utime, double x, int64_t seq) {
  omni::pose2d_t p{};
  p.utime = utime;
  p.seq = seq;
  p.frame = "map";
  p.source = "rbpf";
  p.x_m = x;
  p.y_m = 0;
  p.yaw_rad = 0;
  return p;
}

template <class Msg>
std::vector<uint8_t> Encode(const Msg& m) {
  std::vector<uint8_t> b(static_cast<size_t>(m.getEncodedSize()));
  m.encode(b.data(), 0, static_cast<int>(b.size()));
  return b;
}

// Occupied voxels of the wall are at x in [3.0, 3.05); none elsewhere; free space before it.
void ExpectWall(const octomap::OcTree& t) {
  size_t occ = 0;
  for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it) {
    if (!t.isNodeOccupied(*it)) continue;
    ++occ;
    EXPECT_NEAR(it.getX(), kWallX + 0.025, 0.026) << it.getY() << " " << it.getZ();
  }
  EXPECT_GT(occ, 200u);
  const octomap::OcTreeNode* wall = t.search(kWallX + 0.01, 0.0, 0.45);
  ASSERT_NE(wall, nullptr);
  EXPECT_TRUE(t.isNodeOccupied(wall));
  const octomap::OcTreeNode* before = t.search(2.0, 0.0, 0.45);
  ASSERT_NE(before, nullptr);
  EXPECT_FALSE(t.isNodeOccupied(before));
}

TEST(OctomapCli, BuildsFromAnRgbdFolder) {
  const std::string in = std::string(OMNI_DATASETS_DIR) + "/rgbd/kinect-5frames";
  if (!fs::exists(in + "/pose.txt")) GTEST_SKIP() << "dataset rgbd/kinect-5frames absent";
  const std::string out = testing::TempDir() + "/octo_cli_rgbd";
  auto r = RunCommand(Bin("omni-octomap") + " build " + in + " --out " + out +
                      " --fx 518 --fy 519 --cx 325.5 --cy 253.5 --depth-scale 1000 --up -y"
                      " --grid-min-z -0.3 --grid-max-z 0.5 --resolution 0.05 --pcd");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("5 frames"), std::string::npos) << r.output;
  for (const char* f :
       {"map.bt", "map.ot", "grid.pgm", "grid.yaml", "grid.png", "view.png", "map.pcd"})
    EXPECT_TRUE(fs::exists(out + "/" + f)) << f;
  auto tree = LoadTree(out + "/map.bt");
  ASSERT_TRUE(tree.ok()) << tree.error().message;
  size_t occ = 0;
  for (auto it = (*tree)->begin_leafs(); it != (*tree)->end_leafs(); ++it)
    occ += (*tree)->isNodeOccupied(*it);
  EXPECT_GT(occ, 10000u);
  auto grid = io::ReadMapServer(out + "/grid.yaml");
  ASSERT_TRUE(grid.ok()) << grid.error().message;
  size_t g_occ = 0, g_free = 0;
  for (int8_t c : grid->cells) g_occ += c == 100, g_free += c == 0;
  EXPECT_GT(g_free, 1000u);
  EXPECT_GT(g_occ, 100u);
  // One frame posed 2.1 km away (1500, 1500 m; inside the key range of 0.05 m cells, 1638 m): the
  // map is wider than a grid can carry. The tree, the view and the cloud are still written (they
  // used to stop at the grid), and the exit says what is missing.
  const std::string far = testing::TempDir() + "/octo_cli_rgbd_far";
  fs::remove_all(far);
  fs::create_directories(far);
  fs::create_directory_symlink(in + "/depth", far + "/depth");
  fs::create_directory_symlink(in + "/color", far + "/color");
  {
    std::ifstream poses(in + "/pose.txt");
    std::ofstream moved(far + "/pose.txt");
    std::string line;
    for (int i = 0; std::getline(poses, line); ++i) {
      if (i == 4)
        line = "1500 0 1500" + line.substr(line.find(' ', line.find(' ', line.find(' ') + 1) + 1));
      moved << line << "\n";
    }
  }
  const std::string far_out = testing::TempDir() + "/octo_cli_rgbd_far_out";
  fs::remove_all(far_out);
  r = RunCommand(Bin("omni-octomap") + " build " + far + " --out " + far_out +
                 " --fx 518 --fy 519 --cx 325.5 --cy 253.5 --depth-scale 1000 --up -y"
                 " --grid-min-z -0.3 --grid-max-z 0.5 --resolution 0.05 --pcd");
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("no grid written"), std::string::npos) << r.output;
  for (const char* f : {"map.bt", "map.ot", "view.png", "map.pcd"})
    EXPECT_TRUE(fs::exists(far_out + "/" + f)) << f;
  EXPECT_FALSE(fs::exists(far_out + "/grid.yaml"));
  // Beyond the key range (2000 m at 0.05 m cells, past +-1638 m): said, not silently empty.
  {
    std::ifstream poses(in + "/pose.txt");
    std::ofstream moved(far + "/pose.txt");
    std::string line;
    for (int i = 0; std::getline(poses, line); ++i) {
      if (i == 4)
        line = "2000 0 2000" + line.substr(line.find(' ', line.find(' ', line.find(' ') + 1) + 1));
      moved << line << "\n";
    }
  }
  r = RunCommand(Bin("omni-octomap") + " build " + far + " --out " + far_out +
                 " --fx 518 --fy 519 --cx 325.5 --cy 253.5 --depth-scale 1000 --up -y"
                 " --grid-min-z -0.3 --grid-max-z 0.5 --resolution 0.05");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("frame 5: no point inside the octree's key range"), std::string::npos)
      << r.output;
  // Missing intrinsics are an error that says what to give.
  r = RunCommand(Bin("omni-octomap") + " build " + in + " --out " + out);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--fx"), std::string::npos) << r.output;
}

TEST(OctomapCli, BuildsFromAnLcmLogPosedBy2dSlam) {
  const std::string dir = testing::TempDir() + "/octo_cli_log";
  fs::create_directories(dir);
  const std::string log = dir + "/in.lcmlog";
  {
    auto w = io::LcmLogWriter::Open(log);
    ASSERT_TRUE(w.ok()) << w.error().message;
    const int64_t t0 = 1700000000000000;
    // A frame before any pose: can never be posed (dropped, counted).
    auto f = Encode(WallFrame(t0 - 50000, 0.0, 0));
    ASSERT_TRUE(w->Write(t0 - 50000, "DEPTH", f.data(), f.size()).ok());
    // Poses at 10 Hz while the robot drives from x = 0 to x = 1 m; frames at 5 Hz between them,
    // written before the pose after them arrives (the latency rule makes them wait).
    for (int i = 0; i <= 10; ++i) {
      const int64_t t = t0 + i * 100000;
      auto p = Encode(Pose(t, 0.1 * i, i));
      ASSERT_TRUE(w->Write(t, "POSE_RBPF", p.data(), p.size()).ok());
      if (i % 2 == 0 && i < 10) {
        const int64_t tf = t + 50000;  // halfway to the next pose: x = 0.1 i + 0.05
        auto d = Encode(WallFrame(tf, 0.1 * i + 0.05, i + 1));
        ASSERT_TRUE(w->Write(tf, "DEPTH", d.data(), d.size()).ok());
      }
    }
    // A truncated depth message: a decode error, not a crash.
    auto bad = Encode(WallFrame(t0 + 1100000, 1.0, 99));
    bad.resize(bad.size() / 2);
    ASSERT_TRUE(w->Write(t0 + 1100000, "DEPTH", bad.data(), bad.size()).ok());
    ASSERT_TRUE(w->Close().ok());
  }
  const std::string out = dir + "/out";
  auto r =
      RunCommand(Bin("omni-octomap") + " build " + log + " --out " + out + " --config " + Config());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find(
                "6 frames in, 5 inserted, 1 dropped without pose, 0 out of order, 1 decode errors"),
            std::string::npos)
      << r.output;
  auto tree = LoadTree(out + "/map.ot");
  ASSERT_TRUE(tree.ok()) << tree.error().message;
  ExpectWall(**tree);
  // The grid's band (0.05..1.8 m) holds the wall: an occupied line at x = 3 m.
  auto grid = io::ReadMapServer(out + "/grid.yaml");
  ASSERT_TRUE(grid.ok()) << grid.error().message;
  const int col = static_cast<int>((kWallX + 0.025 - grid->origin_x_m) / grid->resolution_m);
  const int row = static_cast<int>((0.0 - grid->origin_y_m) / grid->resolution_m);
  ASSERT_TRUE(grid->Contains(col, row));
  EXPECT_EQ(grid->at(col, row), 100);
  EXPECT_EQ(grid->at(col - 10, row), 0);

  // The log cut inside its last event (a logger killed, power lost): what came before is
  // mapped and written, with a warning — it used to be an error and no map at all.
  const std::string cut = dir + "/cut.lcmlog";
  fs::copy_file(log, cut, fs::copy_options::overwrite_existing);
  fs::resize_file(cut, fs::file_size(cut) - 10);
  r = RunCommand(Bin("omni-octomap") + " build " + cut + " --out " + dir + "/out_cut --config " +
                 Config());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("event truncated"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("reading stops there"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("6 frames in, 5 inserted, 1 dropped without pose, 0 out of order, 0 "
                          "decode errors"),
            std::string::npos)
      << r.output;  // the truncated depth message was the event cut
  EXPECT_TRUE(fs::exists(dir + "/out_cut/map.ot"));

  // --poses: the same frames posed by a trajectory file (e.g. a mapper's final estimate) in
  // place of the log's POSE_RBPF. This one says the robot was 0.5 m further along x at every
  // time, so the wall is mapped at x = 3.5 m; the log's poses are not read.
  const std::string traj = dir + "/final.txt";
  {
    std::ofstream t(traj);
    t << "# scan_index timestamp x y theta\n";
    t.setf(std::ios::fixed);
    t.precision(6);
    for (int i = 0; i <= 10; ++i)
      t << i << ' ' << 1700000000.0 + 0.1 * i << ' ' << 0.1 * i + 0.5 << " 0 0\n";
  }
  const std::string out2 = dir + "/out_poses";
  r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + out2 + " --config " +
                 Config() + " --poses " + traj);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("11 poses from " + traj), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("6 frames in, 5 inserted, 1 dropped without pose"), std::string::npos)
      << r.output;
  auto shifted = io::ReadMapServer(out2 + "/grid.yaml");
  ASSERT_TRUE(shifted.ok()) << shifted.error().message;
  const int col2 = static_cast<int>((kWallX + 0.5 + 0.025 - shifted->origin_x_m) / 0.05);
  const int row2 = static_cast<int>((0.0 - shifted->origin_y_m) / 0.05);
  ASSERT_TRUE(shifted->Contains(col2, row2));
  EXPECT_EQ(shifted->at(col2, row2), 100);
  EXPECT_EQ(shifted->at(col2 - 10, row2), 0);  // x = 3.0 m: free now
  // A file that is not a trajectory, --poses with --source, or with a folder INPUT: errors that
  // say so.
  std::ofstream(dir + "/bad.txt") << "not a trajectory\n";
  r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + out2 + " --config " +
                 Config() + " --poses " + dir + "/bad.txt");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("bad.txt:1: 'not' is not a finite number"), std::string::npos)
      << r.output;
  r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + out2 + " --config " +
                 Config() + " --poses " + traj + " --source pg");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--source and --poses exclude each other"), std::string::npos)
      << r.output;
  r = RunCommand(Bin("omni-octomap") + " build " + dir + " --out " + out2 + " --poses " + traj);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--poses is for a log INPUT"), std::string::npos) << r.output;
  // --subvoxel overrides the config (0: a ray to every point, the same wall).
  r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + dir + "/out_all --config " +
                 Config() + " --subvoxel 0");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto all_rays = LoadTree(dir + "/out_all/map.ot");
  ASSERT_TRUE(all_rays.ok()) << all_rays.error().message;
  ExpectWall(**all_rays);
  r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + out2 + " --subvoxel 99");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--subvoxel must be in [0, 16]"), std::string::npos) << r.output;
}

// The robot's poses, each `dx` further along x than the log's POSE_RBPF: what the SLAM says once
// it has corrected its path.
omni::trajectory_t ShiftedTrajectory(int64_t t0, int n, double dx, const std::string& frame) {
  omni::trajectory_t m;
  m.frame = frame;
  m.source = "rbpf";
  m.num_poses = n;
  for (int i = 0; i < n; ++i) {
    m.pose_utime.push_back(t0 + i * 100000);
    m.x_m.push_back(0.1 * i + dx);
    m.y_m.push_back(0);
    m.yaw_rad.push_back(0);
  }
  m.utime = m.pose_utime.back();
  return m;
}

bool GridOccupiedAt(const io::GridMap& g, double x) {
  const int col = static_cast<int>((x - g.origin_x_m) / g.resolution_m);
  const int row = static_cast<int>((0.0 - g.origin_y_m) / g.resolution_m);
  return g.Contains(col, row) && g.at(col, row) == 100;
}

// A log whose POSE_RBPF put the wall at x = 3 m and whose last TRAJECTORY_RBPF says every pose
// was 0.5 m further: with repose (the shipped config) the map is rebuilt there.
TEST(OctomapCli, RebuildsAtTheLogsNewestTrajectory) {
  const std::string dir = testing::TempDir() + "/octo_cli_repose";
  fs::create_directories(dir);
  const std::string log = dir + "/in.lcmlog";
  const int64_t t0 = 1700000000000000;
  {
    auto w = io::LcmLogWriter::Open(log);
    ASSERT_TRUE(w.ok()) << w.error().message;
    for (int i = 0; i <= 10; ++i) {
      const int64_t t = t0 + i * 100000;
      auto p = Encode(Pose(t, 0.1 * i, i));
      ASSERT_TRUE(w->Write(t, "POSE_RBPF", p.data(), p.size()).ok());
      if (i % 2 == 0 && i < 10) {
        auto d = Encode(WallFrame(t + 50000, 0.1 * i + 0.05, i + 1));
        ASSERT_TRUE(w->Write(t + 50000, "DEPTH", d.data(), d.size()).ok());
      }
    }
    auto other = Encode(ShiftedTrajectory(t0, 11, 2.0, "odom"));  // another frame: ignored
    ASSERT_TRUE(w->Write(t0 + 1000000, "TRAJECTORY_RBPF", other.data(), other.size()).ok());
    auto tr = Encode(ShiftedTrajectory(t0, 11, 0.5, "map"));
    ASSERT_TRUE(w->Write(t0 + 1000000, "TRAJECTORY_RBPF", tr.data(), tr.size()).ok());
    ASSERT_TRUE(w->Close().ok());
  }
  auto r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + dir + "/out --config " +
                      Config());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("repose: 2 trajectories on TRAJECTORY_RBPF (1 rejected)"),
            std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("retired as revisited), 1 rebuilds"), std::string::npos) << r.output;
  auto grid = io::ReadMapServer(dir + "/out/grid.yaml");
  ASSERT_TRUE(grid.ok()) << grid.error().message;
  EXPECT_TRUE(GridOccupiedAt(*grid, kWallX + 0.5 + 0.025));
  EXPECT_FALSE(GridOccupiedAt(*grid, kWallX + 0.025));
  // --no-repose: the published poses as they were.
  r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + dir + "/out_live --config " +
                 Config() + " --no-repose");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.find("repose:"), std::string::npos) << r.output;
  grid = io::ReadMapServer(dir + "/out_live/grid.yaml");
  ASSERT_TRUE(grid.ok()) << grid.error().message;
  EXPECT_TRUE(GridOccupiedAt(*grid, kWallX + 0.025));
  EXPECT_FALSE(GridOccupiedAt(*grid, kWallX + 0.5 + 0.025));
  // --poses stands in for the live poses: without --repose the file's poses are the map's (the
  // log's trajectory is not applied), with it the log's newest trajectory moves the keyframes.
  const std::string traj = dir + "/live.txt";
  {
    std::ofstream t(traj);
    t << "# scan_index timestamp x y theta\n";
    t.setf(std::ios::fixed);
    t.precision(6);
    for (int i = 0; i <= 10; ++i)
      t << i << ' ' << 1700000000.0 + 0.1 * i << ' ' << 0.1 * i - 1.0 << " 0 0\n";
  }
  r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + dir + "/out_file --config " +
                 Config() + " --poses " + traj);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.find("repose:"), std::string::npos) << r.output;
  grid = io::ReadMapServer(dir + "/out_file/grid.yaml");
  ASSERT_TRUE(grid.ok()) << grid.error().message;
  EXPECT_TRUE(GridOccupiedAt(*grid, kWallX - 1.0 + 0.025));
  r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + dir +
                 "/out_file_repose --config " + Config() + " --poses " + traj + " --repose");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("1 rebuilds (the last"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("for a shift of 1.500 m"), std::string::npos) << r.output;
  grid = io::ReadMapServer(dir + "/out_file_repose/grid.yaml");
  ASSERT_TRUE(grid.ok()) << grid.error().message;
  EXPECT_TRUE(GridOccupiedAt(*grid, kWallX + 0.5 + 0.025));
  EXPECT_FALSE(GridOccupiedAt(*grid, kWallX - 1.0 + 0.025));
}

// The node: TRAJECTORY_RBPF on the bus moves the published map; a trajectory in another frame is
// rejected and an undecodable one a decode error, both counted in the heartbeat.
TEST(OctomapNode, RebuildsWhenTheTrajectoryMovesOnMemq) {
  auto bus = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus.ok()) << bus.error().message;
  auto opt = OctomapBuilderOptions::LoadFile(Config());
  ASSERT_TRUE(opt.ok()) << opt.error().message;
  ASSERT_TRUE(opt->repose.enabled);
  opt->out_dir = testing::TempDir() + "/octo_node_repose";
  opt->octomap_interval_s = 0.5;
  ManualClock clock(1700000000000000);
  OctomapNode node(bus->get(), *opt, &clock);
  std::vector<omni::octomap_t> maps;
  std::vector<omni::heartbeat_t> beats;
  (*bus)->Subscribe<omni::octomap_t>("OCTOMAP",
                                     [&](const omni::octomap_t& m, int64_t) { maps.push_back(m); });
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { beats.push_back(m); });
  const int64_t t0 = 1700000000000000;
  int64_t mono = 0;
  auto pump = [&] {
    while ((*bus)->HandleTimeout(0) > 0) {
    }
    mono += 600000;
    clock.Advance(600000);
    node.Tick(mono);
    while ((*bus)->HandleTimeout(0) > 0) {
    }
  };
  for (int i = 0; i <= 10; ++i) {
    (*bus)->Publish("POSE_RBPF", Pose(t0 + i * 100000, 0.1 * i, i));
    if (i % 2 == 0 && i < 10)
      (*bus)->Publish("DEPTH", WallFrame(t0 + i * 100000 + 50000, 0.1 * i + 0.05, i + 1));
    pump();
  }
  auto wall_at = [](const omni::octomap_t& m, double x) {
    std::istringstream bt(std::string(m.data.begin(), m.data.end()));
    octomap::OcTree t(0.05);
    if (!t.readBinary(bt)) return false;
    const octomap::OcTreeNode* n = t.search(x, 0.0, 0.45);
    return n && t.isNodeOccupied(n);
  };
  ASSERT_FALSE(maps.empty());
  EXPECT_TRUE(wall_at(maps.back(), kWallX + 0.01));
  const size_t before = maps.size();
  (*bus)->Publish("TRAJECTORY_RBPF", ShiftedTrajectory(t0, 11, 2.0, "odom"));
  std::vector<uint8_t> undecodable(12, 0x5a);
  (*bus)->PublishRaw("TRAJECTORY_RBPF", undecodable.data(), static_cast<int>(undecodable.size()));
  (*bus)->Publish("TRAJECTORY_RBPF", ShiftedTrajectory(t0, 11, 0.5, "map"));
  // The rebuild runs in 20 ms slices per tick (repose.rebuild_budget_ms): as many ticks as the
  // machine needs (a sanitizer build is several times slower), then a few more to publish.
  for (int i = 0; i < 4 || (node.pipeline().rebuilding() && i < 400); ++i) pump();
  for (int i = 0; i < 2; ++i) pump();
  node.heartbeat().Tick(true);
  while ((*bus)->HandleTimeout(0) > 0) {
  }
  EXPECT_EQ(node.pipeline().counters().rebuilds_done, 1);
  ASSERT_GT(maps.size(), before);  // the rebuilt tree went out without a new frame
  EXPECT_TRUE(wall_at(maps.back(), kWallX + 0.5 + 0.01));
  EXPECT_FALSE(wall_at(maps.back(), kWallX + 0.01));
  ASSERT_FALSE(beats.empty());
  std::map<std::string, int64_t> counters;
  for (int i = 0; i < beats.back().num_counters; ++i)
    counters[beats.back().counter_names[i]] = beats.back().counter_values[i];
  EXPECT_EQ(counters["trajectories_in"], 2);
  EXPECT_EQ(counters["trajectories_rejected"], 1);
  EXPECT_EQ(counters["rebuilds_done"], 1);
  EXPECT_EQ(counters["last_rebuild_shift_mm"], 500);
  EXPECT_GE(counters["keyframes"], 3);
  EXPECT_EQ(counters["decode_errors"], 1);
}

// A SLAM process restarted by the supervisor numbers its poses from 0 again, in a new map
// frame: the builder cannot lay the new frames onto the old tree, so it says so (a warning,
// pose_restarts, DEGRADED) instead of mapping on as if nothing happened (review finding).
TEST(OctomapNode, ARestartedPoseSourceIsSaidAndDegrades) {
  auto bus = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus.ok()) << bus.error().message;
  auto opt = OctomapBuilderOptions::LoadFile(Config());
  ASSERT_TRUE(opt.ok()) << opt.error().message;
  opt->out_dir = testing::TempDir() + "/octo_pose_restart";
  ManualClock clock(1700000000000000);
  OctomapNode node(bus->get(), *opt, &clock);
  std::vector<omni::heartbeat_t> beats;
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { beats.push_back(m); });
  const int64_t t0 = 1700000000000000;
  int64_t mono = 0;
  const auto pump = [&] {
    while ((*bus)->HandleTimeout(0) > 0) {
    }
    mono += 300000;
    clock.Advance(300000);
    node.Tick(mono);
    node.heartbeat().Tick(true);
    while ((*bus)->HandleTimeout(0) > 0) {
    }
  };
  int64_t t = t0;
  // 5 s of poses: a process that crashes this early is caught too.
  for (int i = 0; i <= 50; ++i, t += 100000) (*bus)->Publish("POSE_RBPF", Pose(t, 0.01 * i, i));
  (*bus)->Publish("DEPTH", WallFrame(t0 + 50000, 0.005, 1));
  pump();
  ASSERT_FALSE(beats.empty());
  EXPECT_NE(beats.back().state, omni::heartbeat_t::STATE_DEGRADED);
  EXPECT_EQ(node.pose_restarts(), 0);
  for (int i = 0; i <= 5; ++i, t += 100000) (*bus)->Publish("POSE_RBPF", Pose(t, 0.01 * i, i));
  pump();
  EXPECT_EQ(node.pose_restarts(), 1);
  EXPECT_EQ(beats.back().state, omni::heartbeat_t::STATE_DEGRADED);
  EXPECT_NE(beats.back().status_text.find("pose source restarted"), std::string::npos)
      << beats.back().status_text;
}

TEST(OctomapNode, MapsOnMemqAndPublishesCounters) {
  auto bus = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus.ok()) << bus.error().message;
  auto opt = OctomapBuilderOptions::LoadFile(Config());
  ASSERT_TRUE(opt.ok()) << opt.error().message;
  opt->out_dir = testing::TempDir() + "/octo_node";
  opt->octomap_interval_s = 0.5;
  opt->grid_interval_s = 0.5;
  ManualClock clock(1700000000000000);
  OctomapNode node(bus->get(), *opt, &clock);
  std::vector<omni::octomap_t> maps;
  std::vector<omni::occupancy_grid_t> grids;
  std::vector<omni::heartbeat_t> beats;
  (*bus)->Subscribe<omni::octomap_t>("OCTOMAP",
                                     [&](const omni::octomap_t& m, int64_t) { maps.push_back(m); });
  int color_maps = 0;  // colour is off: nothing on its channel
  (*bus)->Subscribe<omni::octomap_t>("OCTOMAP_COLOR",
                                     [&](const omni::octomap_t&, int64_t) { ++color_maps; });
  (*bus)->Subscribe<omni::occupancy_grid_t>(
      "GRID_OCTO", [&](const omni::occupancy_grid_t& m, int64_t) { grids.push_back(m); });
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { beats.push_back(m); });
  const int64_t t0 = 1700000000000000;
  int64_t mono = 0;
  auto pump = [&] {
    while ((*bus)->HandleTimeout(0) > 0) {
    }
    mono += 300000;
    clock.Advance(300000);
    node.Tick(mono);
    while ((*bus)->HandleTimeout(0) > 0) {
    }
  };
  (*bus)->Publish("DEPTH", WallFrame(t0 - 10, 0.0, 0));  // before any pose: dropped
  for (int i = 0; i <= 6; ++i) {
    (*bus)->Publish("POSE_RBPF", Pose(t0 + i * 100000, 0.1 * i, i));
    // Sequence numbers 1, 2, 3, 6, 7, 8: frames 4 and 5 were lost on the way.
    if (i < 6)
      (*bus)->Publish("DEPTH",
                      WallFrame(t0 + i * 100000 + 50000, 0.1 * i + 0.05, i + 1 + (i >= 3 ? 2 : 0)));
    pump();
  }
  (*bus)->Publish("POSE_RBPF", Pose(t0, 0.0, 99));  // out of order
  // Corrupt stamps (at the ends of int64, or 0): dropped and counted before any arithmetic.
  (*bus)->Publish("DEPTH", WallFrame(std::numeric_limits<int64_t>::min() + 1, 0.0, 20));
  (*bus)->Publish("POSE_RBPF", Pose(std::numeric_limits<int64_t>::max(), 0.0, 100));
  (*bus)->Publish("DEPTH", WallFrame(0, 0.0, 21));
  // Frame 8 again (a repeating bridge): dropped, not inserted a second time.
  (*bus)->Publish("DEPTH", WallFrame(t0 + 5 * 100000 + 50000, 0.55, 8));
  std::vector<uint8_t> junk(10, 0xff);
  (*bus)->PublishRaw("DEPTH", junk.data(), static_cast<int>(junk.size()));  // undecodable
  for (int i = 0; i < 6; ++i) pump();
  node.heartbeat().Tick(true);
  while ((*bus)->HandleTimeout(0) > 0) {
  }
  const auto& pc = node.pipeline().poser_counters();
  EXPECT_EQ(pc.frames_in, 7);
  EXPECT_EQ(pc.frames_posed, 6);
  EXPECT_EQ(pc.frames_dropped_no_pose, 1);
  EXPECT_EQ(pc.poses_out_of_order, 1);
  EXPECT_EQ(node.pipeline().counters().frames_inserted, 6);
  ExpectWall(node.pipeline().builder().tree());
  ASSERT_FALSE(maps.empty());
  EXPECT_EQ(maps.back().tree_type, "OcTree");
  EXPECT_TRUE(maps.back().binary);
  EXPECT_DOUBLE_EQ(maps.back().resolution_m, 0.05);
  std::istringstream bt(std::string(maps.back().data.begin(), maps.back().data.end()));
  octomap::OcTree received(0.05);
  ASSERT_TRUE(received.readBinary(bt));
  ExpectWall(received);
  ASSERT_FALSE(grids.empty());
  EXPECT_EQ(grids.back().source, "octomap");
  auto grid = bus::FromGridMessage(grids.back());
  ASSERT_TRUE(grid.ok());
  const int col = static_cast<int>((kWallX + 0.025 - grid->origin_x_m) / grid->resolution_m);
  const int row = static_cast<int>((0.0 - grid->origin_y_m) / grid->resolution_m);
  ASSERT_TRUE(grid->Contains(col, row));
  EXPECT_EQ(grid->at(col, row), 100);
  ASSERT_FALSE(beats.empty());
  const auto& hb = beats.back();
  std::map<std::string, int64_t> counters;
  for (int i = 0; i < hb.num_counters; ++i) counters[hb.counter_names[i]] = hb.counter_values[i];
  EXPECT_EQ(counters["frames_in"], 7);
  EXPECT_EQ(counters["frames_lost"], 2);
  EXPECT_EQ(counters["frames_duplicate"], 1);
  EXPECT_EQ(counters["stamps_invalid"], 3);
  EXPECT_EQ(counters["pose_restarts"], 0);
  EXPECT_EQ(node.depth_frames_lost(), 2);
  EXPECT_EQ(counters["frames_posed"], 6);
  EXPECT_EQ(counters["frames_dropped_no_pose"], 1);
  EXPECT_EQ(counters["out_of_order"], 1);
  EXPECT_EQ(counters["decode_errors"], 1);
  EXPECT_EQ(hb.process, "octomap_builder");
  ASSERT_TRUE(node.SaveOutputs().ok());
  for (const auto& e : fs::directory_iterator(opt->out_dir)) {  // all of them moved on a restart
    const std::vector<std::string>& names = OctomapNode::OutputFiles();
    EXPECT_NE(std::find(names.begin(), names.end(), e.path().filename().string()), names.end())
        << e.path() << " is not in the node's list of outputs";
  }
  EXPECT_TRUE(fs::exists(opt->out_dir + "/map.bt"));
  EXPECT_TRUE(fs::exists(opt->out_dir + "/grid.yaml"));
  EXPECT_FALSE(maps.empty());
  EXPECT_EQ(color_maps, 0);
}

// `omni-octomap extract`: the newest readable tree of each type out of a recorded log, with two
// undecodable messages, a truncated tree and an unrelated channel in it.
TEST(OctomapCli, ExtractsTheNewestReadableMapsFromALog) {
  const std::string dir = testing::TempDir() + "/octo_cli_extract";
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string log = dir + "/robot.lcmlog";
  octomap::OcTree older(0.05), newer(0.05);
  older.updateNode(1.025, 0.025, 0.5, true);
  for (double y = -0.5; y < 0.5; y += 0.05) newer.updateNode(3.025, y + 0.025, 0.5, true);
  octomap::ColorOcTree colored(0.05);
  colored.updateNode(2.025, 0.025, 0.5, true);
  colored.setNodeColor(2.025, 0.025, 0.5, 40, 180, 90);
  {
    auto w = io::LcmLogWriter::Open(log);
    ASSERT_TRUE(w.ok()) << w.error().message;
    const int64_t t0 = 1700000000000000;
    auto put = [&](int64_t t, const std::string& ch, const std::vector<uint8_t>& b) {
      ASSERT_TRUE(w->Write(t, ch, b.data(), b.size()).ok());
    };
    put(t0, "OCTOMAP", Encode(ToOctomapMessage(older, t0, "map", "rbpf", true)));
    put(t0 + 1, "OCTOMAP_COLOR", Encode(ToOctomapMessage(colored, t0 + 1, "map", "rbpf")));
    put(t0 + 2, "OCTOMAP", Encode(ToOctomapMessage(newer, t0 + 2, "map", "rbpf", true)));
    put(t0 + 3, "POSE_RBPF", Encode(Pose(t0 + 3, 0.0, 1)));
    auto garbage = Encode(ToOctomapMessage(newer, t0 + 4, "map", "rbpf", true));
    garbage.resize(garbage.size() / 2);  // cut inside the message: undecodable
    put(t0 + 4, "OCTOMAP", garbage);
    // A string whose length field says 0 (LCM counts the NUL, so never 0): lcm-gen's decoder
    // throws on it; an undecodable message too, not the end of the command.
    auto zero_len = Encode(ToOctomapMessage(newer, t0 + 4, "map", "rbpf", true));
    std::fill(zero_len.begin() + 16, zero_len.begin() + 20, 0);  // after the hash and utime
    put(t0 + 4, "OCTOMAP", zero_len);
    // Decodes, but its tree is cut short: checked before octomap reads it, and skipped.
    omni::octomap_t cut = ToOctomapMessage(newer, t0 + 5, "map", "rbpf", true);
    cut.data.resize(cut.data.size() - 10);
    cut.size = static_cast<int32_t>(cut.data.size());
    put(t0 + 5, "OCTOMAP", Encode(cut));
    ASSERT_TRUE(w->Close().ok());
  }
  const std::string out = dir + "/out";
  auto r = RunCommand(Bin("omni-octomap") + " extract " + log + " --out " + out);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("6 messages on 2 channels, 2 undecodable, 1 unreadable trees"),
            std::string::npos)
      << r.output;
  auto tree = LoadTree(out + "/map.bt");  // sent in binary form: written as it was sent
  ASSERT_TRUE(tree.ok()) << tree.error().message;
  EXPECT_EQ((*tree)->getNumLeafNodes(), newer.getNumLeafNodes());
  const octomap::OcTreeNode* wall = (*tree)->search(3.025, 0.025, 0.5);
  ASSERT_NE(wall, nullptr);
  EXPECT_TRUE((*tree)->isNodeOccupied(wall));
  EXPECT_EQ((*tree)->search(1.025, 0.025, 0.5), nullptr) << "the older map was extracted";
  EXPECT_FALSE(fs::exists(out + "/map.ot"));
  EXPECT_TRUE(fs::exists(out + "/view.png"));
  auto col = LoadColorTree(out + "/map_color.ot");
  ASSERT_TRUE(col.ok()) << col.error().message;
  const octomap::ColorOcTreeNode* c = (*col)->search(2.025, 0.025, 0.5);
  ASSERT_NE(c, nullptr);
  EXPECT_EQ(c->getColor().g, 180);
  EXPECT_TRUE(fs::exists(out + "/view_color.png"));

  // Only the colour channel asked for; a log without any map; a missing --out.
  const std::string out2 = dir + "/out2";
  r = RunCommand(Bin("omni-octomap") + " extract " + log + " --out " + out2 +
                 " --channel OCTOMAP_COLOR");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_FALSE(fs::exists(out2 + "/map.bt"));
  EXPECT_TRUE(fs::exists(out2 + "/map_color.ot"));
  r = RunCommand(Bin("omni-octomap") + " extract " + log + " --out " + out2 +
                 " --channel POSE_RBPF");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("1 undecodable"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("no readable octomap_t"), std::string::npos) << r.output;
  r = RunCommand(Bin("omni-octomap") + " extract " + log);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("--out DIR is required"), std::string::npos) << r.output;
}

// ---- Colour (ColorOcTree) ----

using Rgb3 = std::array<double, 3>;

TEST(OctomapCli, ColorBuildOfIclNuimHasTheInputsColours) {
  const std::string in = std::string(OMNI_DATASETS_DIR) + "/rgbd/iclnuim-5frames";
  if (!fs::exists(in + "/pose.txt"))
    GTEST_SKIP() << "dataset rgbd/iclnuim-5frames absent (OMNI_DATASETS_DIR=" << OMNI_DATASETS_DIR
                 << ")";
  const std::string out = testing::TempDir() + "/octo_cli_color";
  const double fx = 481.2, fy = -480.0, cx = 319.5, cy = 239.5, scale = 5000;
  auto r =
      RunCommand(Bin("omni-octomap") + " build " + in + " --out " + out + " --config " + Config() +
                 " --fx 481.2 --fy -480 --cx 319.5 --cy 239.5 --depth-scale 5000 --up -y"
                 " --grid-min-z -0.3 --grid-max-z 0.5 --resolution 0.05 --color");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("map_color.ot"), std::string::npos) << r.output;
  for (const char* f : {"map.bt", "map.ot", "map_color.ot", "view.png", "view_color.png"})
    EXPECT_TRUE(fs::exists(out + "/" + f)) << f;
  // OctoMap's generic reader gives a ColorOcTree.
  std::ifstream file(out + "/map_color.ot", std::ios::binary);
  std::unique_ptr<octomap::AbstractOcTree> any(octomap::AbstractOcTree::read(file));
  ASSERT_NE(any, nullptr);
  const auto* color = dynamic_cast<const octomap::ColorOcTree*>(any.get());
  ASSERT_NE(color, nullptr) << any->getTreeType();
  // Its occupancy is the plain map's.
  auto plain = LoadTree(out + "/map.ot");
  ASSERT_TRUE(plain.ok()) << plain.error().message;
  ASSERT_EQ(color->getNumLeafNodes(), (*plain)->getNumLeafNodes());
  for (auto it = (*plain)->begin_leafs(); it != (*plain)->end_leafs(); ++it) {
    const auto* n = color->search(it.getKey(), it.getDepth());
    ASSERT_NE(n, nullptr);
    ASSERT_EQ(n->getLogOdds(), it->getLogOdds());
  }
  // Coloured occupied leaves and their mean colour.
  size_t occupied = 0, colored = 0;
  Rgb3 voxel_mean{0, 0, 0};
  for (auto it = color->begin_leafs(); it != color->end_leafs(); ++it) {
    if (!color->isNodeOccupied(*it)) continue;
    ++occupied;
    if (!it->isColorSet()) continue;
    ++colored;
    const auto c = it->getColor();
    voxel_mean[0] += c.r;
    voxel_mean[1] += c.g;
    voxel_mean[2] += c.b;
  }
  EXPECT_GT(occupied, 5000u);
  EXPECT_GT(colored, occupied * 98 / 100);
  for (double& v : voxel_mean) v /= static_cast<double>(colored);
  // Mean colour of the input pixels with a valid depth (all of ICL-NUIM's, 1.6..3.4 m).
  auto poses = ReadPoseFile(in + "/pose.txt");
  ASSERT_TRUE(poses.ok());
  Rgb3 pixel_mean{0, 0, 0};
  size_t pixels = 0;
  std::vector<ColorImage> colors(5);
  std::vector<DepthImage> depths(5);
  for (int i = 0; i < 5; ++i) {
    ASSERT_TRUE(ReadColorPng(in + "/color/" + std::to_string(i + 1) + ".png", &colors[i]).ok());
    ASSERT_TRUE(ReadDepthPng(in + "/depth/" + std::to_string(i + 1) + ".png", &depths[i]).ok());
    for (size_t p = 0; p < depths[i].data.size(); ++p) {
      const double z = depths[i].data[p] / scale;
      if (z < 0.4 || z > 5.0) continue;  // the config's min depth, the 5 m max range
      ++pixels;
      for (int ch = 0; ch < 3; ++ch) pixel_mean[ch] += colors[i].rgb[3 * p + ch];
    }
  }
  ASSERT_GT(pixels, 1000000u);
  for (double& v : pixel_mean) v /= static_cast<double>(pixels);
  // Voxels weigh every surface patch once, pixels weigh near surfaces more: close, not equal
  // (measured: voxels 10 levels darker per channel, 2026-12-01).
  for (int ch = 0; ch < 3; ++ch)
    EXPECT_NEAR(voxel_mean[ch], pixel_mean[ch], 15.0)
        << "channel " << ch << ": voxels " << voxel_mean[ch] << ", pixels " << pixel_mean[ch];
  // At the right place: voxels on the surface frame 1 sees have the colour of the pixel their
  // centre projects to (and not that of the mirrored pixel).
  const Eigen::Isometry3d world_to_cam = (*poses)[0].inverse();
  std::vector<double> diff, diff_mirrored;
  for (auto it = color->begin_leafs(); it != color->end_leafs(); ++it) {
    if (!color->isNodeOccupied(*it) || !it->isColorSet() || it.getDepth() != 16) continue;
    const Eigen::Vector3d p = world_to_cam * Eigen::Vector3d(it.getX(), it.getY(), it.getZ());
    if (p.z() <= 0.1) continue;
    const int u = static_cast<int>(std::lround(fx * p.x() / p.z() + cx));
    const int v = static_cast<int>(std::lround(fy * p.y() / p.z() + cy));
    if (u < 0 || v < 0 || u >= 640 || v >= 480) continue;
    const size_t px = static_cast<size_t>(v) * 640 + u;
    if (std::abs(depths[0].data[px] / scale - p.z()) > 0.03) continue;  // hidden or off-surface
    const size_t mirrored = static_cast<size_t>(v) * 640 + (639 - u);
    const auto c = it->getColor();
    const int vc[3] = {c.r, c.g, c.b};
    double d = 0, dm = 0;
    for (int ch = 0; ch < 3; ++ch) {
      d += std::abs(vc[ch] - colors[0].rgb[3 * px + ch]);
      dm += std::abs(vc[ch] - colors[0].rgb[3 * mirrored + ch]);
    }
    diff.push_back(d);
    diff_mirrored.push_back(dm);
  }
  ASSERT_GT(diff.size(), 1000u);
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  const double m = median(diff), mm = median(diff_mirrored);
  EXPECT_LT(m, 30.0) << "median |voxel - pixel| (sum over R, G, B)";
  EXPECT_GT(mm, 2 * m) << "mirrored pixels should disagree";
  std::printf(
      "iclnuim colour: %zu coloured of %zu occupied voxels; mean voxel (%.1f %.1f %.1f), "
      "mean pixel (%.1f %.1f %.1f); median |voxel - pixel| %.1f (mirrored %.1f) over %zu\n",
      colored, occupied, voxel_mean[0], voxel_mean[1], voxel_mean[2], pixel_mean[0], pixel_mean[1],
      pixel_mean[2], m, mm, diff.size());
}

// A colour frame for WallFrame: the same camera, one colour everywhere, RGB8 or JPEG.
omni::color_image_t WallColor(int64_t utime, int64_t seq, bool jpeg) {
  omni::color_image_t m;
  m.utime = utime;
  m.seq = seq;
  m.frame = "rgb_optical";
  m.width = 80;
  m.height = 60;
  m.fx = m.fy = 60.0;
  m.cx = 39.5;
  m.cy = 29.5;
  std::vector<uint8_t> rgb;
  for (int i = 0; i < m.width * m.height; ++i) rgb.insert(rgb.end(), {40, 180, 90});
  if (jpeg) {
    auto j = EncodeJpeg(rgb, m.width, m.height, 90);
    EXPECT_TRUE(j.ok());
    m.encoding = omni::color_image_t::ENCODING_JPEG;
    m.data = *j;
  } else {
    m.encoding = omni::color_image_t::ENCODING_RGB8;
    m.data = rgb;
  }
  m.size = static_cast<int32_t>(m.data.size());
  return m;
}

TEST(OctomapNode, ColoursTheMapFromRgbFramesOnMemq) {
  if (!JpegAvailable()) GTEST_SKIP() << "built without libjpeg (libjpeg-dev not installed)";
  auto bus = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus.ok()) << bus.error().message;
  auto opt = OctomapBuilderOptions::LoadFile(Config());
  ASSERT_TRUE(opt.ok()) << opt.error().message;
  opt->out_dir = testing::TempDir() + "/octo_node_color";
  opt->color = true;
  opt->color_max_dt_us = 10000;
  ManualClock clock(1700000000000000);
  OctomapNode node(bus->get(), *opt, &clock);
  std::vector<omni::heartbeat_t> beats;
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { beats.push_back(m); });
  std::vector<omni::octomap_t> plain, colored;
  (*bus)->Subscribe<omni::octomap_t>(
      "OCTOMAP", [&](const omni::octomap_t& m, int64_t) { plain.push_back(m); });
  (*bus)->Subscribe<omni::octomap_t>(
      "OCTOMAP_COLOR", [&](const omni::octomap_t& m, int64_t) { colored.push_back(m); });
  const int64_t t0 = 1700000000000000;
  int64_t mono = 0;
  auto pump = [&] {
    while ((*bus)->HandleTimeout(0) > 0) {
    }
    mono += 300000;
    clock.Advance(300000);
    node.Tick(mono);
    while ((*bus)->HandleTimeout(0) > 0) {
    }
  };
  for (int i = 0; i <= 6; ++i) {
    (*bus)->Publish("POSE_RBPF", Pose(t0 + i * 100000, 0.1 * i, i));
    if (i < 6) {
      const int64_t tf = t0 + i * 100000 + 50000;
      (*bus)->Publish("DEPTH", WallFrame(tf, 0.1 * i + 0.05, i + 1));
      // Colour 2 ms after each depth frame, alternately RGB8 and JPEG; none for frame 3.
      if (i != 3) (*bus)->Publish("RGB", WallColor(tf + 2000, i + 1, i % 2 == 1));
    }
    if (i == 2) {
      // Bad colour input: a JPEG that is not one, an RGB8 frame one byte short.
      omni::color_image_t bad = WallColor(t0 + 260000, 90, true);
      bad.data.assign(300, 0x11);
      bad.size = 300;
      (*bus)->Publish("RGB", bad);
      bad = WallColor(t0 + 261000, 91, false);
      bad.data.pop_back();
      bad.size = static_cast<int32_t>(bad.data.size());
      (*bus)->Publish("RGB", bad);
    }
    pump();
  }
  // The last frame waits for a colour frame after it; on exit the node flushes it.
  EXPECT_EQ(node.pipeline().counters().frames_inserted, 5);
  EXPECT_EQ(node.pipeline().FlushAwaitingColor(), 1);
  node.heartbeat().Tick(true);
  while ((*bus)->HandleTimeout(0) > 0) {
  }
  const auto& c = node.pipeline().counters();
  EXPECT_EQ(c.frames_inserted, 6);
  EXPECT_EQ(c.frames_colored, 5);
  EXPECT_EQ(c.frames_uncolored, 1);
  EXPECT_EQ(c.color_frames_in, 5);
  EXPECT_EQ(node.color_decode_errors(), 2);
  ASSERT_FALSE(beats.empty());
  std::map<std::string, int64_t> counters;
  for (int i = 0; i < beats.back().num_counters; ++i)
    counters[beats.back().counter_names[i]] = beats.back().counter_values[i];
  EXPECT_EQ(counters["frames_colored"], 5);
  EXPECT_EQ(counters["frames_uncolored"], 1);
  EXPECT_EQ(counters["color_errors"], 2);
  EXPECT_EQ(counters["color_frames_in"], 5);
  // The plain map is the one without colour; the colour map has the wall in its colour.
  ExpectWall(node.pipeline().builder().tree());
  ASSERT_TRUE(node.SaveOutputs().ok());
  auto loaded = LoadColorTree(opt->out_dir + "/map_color.ot");
  ASSERT_TRUE(loaded.ok()) << loaded.error().message;
  size_t wall = 0;
  for (auto it = (*loaded)->begin_leafs(); it != (*loaded)->end_leafs(); ++it) {
    if (!(*loaded)->isNodeOccupied(*it)) continue;
    ++wall;
    EXPECT_NEAR(it.getX(), kWallX + 0.025, 0.026);
    ASSERT_TRUE(it->isColorSet());
    const auto col = it->getColor();
    EXPECT_NEAR(col.r, 40, 4);
    EXPECT_NEAR(col.g, 180, 4);
    EXPECT_NEAR(col.b, 90, 4);
  }
  EXPECT_GT(wall, 200u);
  EXPECT_TRUE(fs::exists(opt->out_dir + "/view_color.png"));
  // The colour map also goes out on the bus, beside the plain one, whenever the plain one does.
  EXPECT_TRUE(node.PublishOctomap());
  while ((*bus)->HandleTimeout(0) > 0) {
  }
  ASSERT_FALSE(colored.empty());
  EXPECT_EQ(colored.size(), plain.size());
  const omni::octomap_t& last = colored.back();
  EXPECT_EQ(last.tree_type, "ColorOcTree");
  EXPECT_FALSE(last.binary);
  EXPECT_EQ(last.frame, "map");
  EXPECT_EQ(last.size, static_cast<int32_t>(last.data.size()));
  EXPECT_EQ(plain.back().tree_type, "OcTree");
  auto sent = ParseColorTree(std::string(last.data.begin(), last.data.end()), "OCTOMAP_COLOR");
  ASSERT_TRUE(sent.ok()) << sent.error().message;
  size_t sent_wall = 0;
  for (auto it = (*sent)->begin_leafs(); it != (*sent)->end_leafs(); ++it) {
    if (!(*sent)->isNodeOccupied(*it)) continue;
    ++sent_wall;
    EXPECT_NEAR(it->getColor().g, 180, 4);
  }
  EXPECT_GT(sent_wall, 200u);
  // Cut short, the message is an error naming the channel, not a crash.
  auto cut = ParseColorTree(std::string(last.data.begin(), last.data.begin() + last.size / 2),
                            "OCTOMAP_COLOR");
  ASSERT_FALSE(cut.ok());
  EXPECT_NE(cut.error().message.find("OCTOMAP_COLOR"), std::string::npos);
}

TEST(OctomapCli, ColorBuildFromAnLcmLogPairsRgbFrames) {
  if (!JpegAvailable()) GTEST_SKIP() << "built without libjpeg (libjpeg-dev not installed)";
  const std::string dir = testing::TempDir() + "/octo_cli_log_color";
  fs::create_directories(dir);
  const std::string log = dir + "/in.lcmlog";
  {
    auto w = io::LcmLogWriter::Open(log);
    ASSERT_TRUE(w.ok()) << w.error().message;
    const int64_t t0 = 1700000000000000;
    for (int i = 0; i <= 10; ++i) {
      const int64_t t = t0 + i * 100000;
      auto p = Encode(Pose(t, 0.1 * i, i));
      ASSERT_TRUE(w->Write(t, "POSE_RBPF", p.data(), p.size()).ok());
      if (i % 2 == 0 && i < 10) {
        const int64_t tf = t + 50000;
        auto d = Encode(WallFrame(tf, 0.1 * i + 0.05, i + 1));
        ASSERT_TRUE(w->Write(tf, "DEPTH", d.data(), d.size()).ok());
        // Colour 3 ms later (JPEG), except for the frame at i = 4; a truncated one at i = 6.
        if (i != 4) {
          auto c = Encode(WallColor(tf + 3000, i + 1, true));
          if (i == 6) c.resize(c.size() - 40);
          ASSERT_TRUE(w->Write(tf + 3000, "RGB", c.data(), c.size()).ok());
        }
      }
    }
    ASSERT_TRUE(w->Close().ok());
  }
  const std::string out = dir + "/out";
  auto r = RunCommand(Bin("omni-octomap") + " build " + log + " --out " + out + " --config " +
                      Config() + " --color");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // Five depth frames: three coloured; one without colour; one whose colour was truncated.
  EXPECT_NE(r.output.find("colour: 3 frames in, 3 depth frames coloured, 2 uncoloured, 1 colour "
                          "errors"),
            std::string::npos)
      << r.output;
  auto color = LoadColorTree(out + "/map_color.ot");
  ASSERT_TRUE(color.ok()) << color.error().message;
  size_t wall = 0;
  for (auto it = (*color)->begin_leafs(); it != (*color)->end_leafs(); ++it) {
    if (!(*color)->isNodeOccupied(*it)) continue;
    ++wall;
    ASSERT_TRUE(it->isColorSet());
    EXPECT_NEAR(it->getColor().g, 180, 4);
  }
  EXPECT_GT(wall, 200u);
}

}  // namespace
}  // namespace omni::octo
