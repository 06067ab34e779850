// The pipeline end to end: omni-octomap build on a dataset folder and on an LCM log, and the
// node on memq:// (one process, nothing leaves the machine).
#include <zlib.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <memory>

#include <gtest/gtest.h>

#include "omni/bus/convert.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/grid.h"
#include "omni/io/lcm_log.h"
#include "omni/occupancy_grid_t.hpp"
#include "omni/octomap_builder/map_output.h"
#include "omni/octomap_builder/octomap_node.h"
#include "omni/pose2d_t.hpp"

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
    if (i < 6) (*bus)->Publish("DEPTH", WallFrame(t0 + i * 100000 + 50000, 0.1 * i + 0.05, i + 1));
    pump();
  }
  (*bus)->Publish("POSE_RBPF", Pose(t0, 0.0, 99));  // out of order
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
  EXPECT_EQ(counters["frames_posed"], 6);
  EXPECT_EQ(counters["frames_dropped_no_pose"], 1);
  EXPECT_EQ(counters["out_of_order"], 1);
  EXPECT_EQ(counters["decode_errors"], 1);
  EXPECT_EQ(hb.process, "octomap_builder");
  ASSERT_TRUE(node.SaveOutputs().ok());
  EXPECT_TRUE(fs::exists(opt->out_dir + "/map.bt"));
  EXPECT_TRUE(fs::exists(opt->out_dir + "/grid.yaml"));
}

}  // namespace
}  // namespace omni::octo
