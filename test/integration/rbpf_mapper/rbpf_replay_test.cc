// The rbpf_mapper process on a replayed log (file:// URL: the bus reads the log), the node on
// memq:// in-process, and omni-slam's offline runner with its CLI errors. Data: a short prefix
// of ../shared/datasets/slam-noisy-odom/intel.noisy.clf.gz.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "../../unit/common/test_paths.h"
#include "../tools/mapper_replay.h"
#include "../tools/run.h"
#include "omni/bus/bus.h"
#include "omni/bus/convert.h"
#include "omni/common/time.h"
#include "omni/eval/eval.h"
#include "omni/heartbeat_t.hpp"
#include "omni/imu_t.hpp"
#include "omni/io/carmen.h"
#include "omni/io/grid.h"
#include "omni/io/lcm_log.h"
#include "omni/io/trajectory_io.h"
#include "omni/laser_scan_t.hpp"
#include "omni/occupancy_grid_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/pose2d_t.hpp"
#include "omni/rbpf_mapper/rbpf_node.h"
#include "omni/trajectory_t.hpp"

namespace omni {
namespace {

constexpr size_t kScans = 150;

void WritePrefixLog(const std::string& clf, const std::string& out) {
  testing::WriteCarmenPrefixLog(clf, out, kScans);
}

double Ate(const std::string& ref_path, const std::string& est_path, size_t* matched) {
  return testing::AteRmse(ref_path, est_path, matched);
}

TEST(RbpfMapperProcess, MapsAReplayedLog) {
  OMNI_REQUIRE_DATASET(clf, "slam-noisy-odom/intel.noisy.clf.gz");
  OMNI_REQUIRE_DATASET(ref, "slam-noisy-odom/intel.reference.txt");
  const std::string dir = testing::TempDir();
  const std::string log = dir + "/prefix.lcmlog";
  WritePrefixLog(clf, log);
  const auto r =
      testing::Run(testing::Bin("rbpf_mapper") +
                   " --config " OMNI_SOURCE_DIR "/config/rbpf_mapper.yaml --url 'file://" + log +
                   "?speed=0' --out " + dir + "/out");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("150 scans"), std::string::npos) << r.output;
  for (const char* f : {"map.pgm", "map.yaml", "map.png", "trajectory.txt"})
    EXPECT_TRUE(std::filesystem::exists(dir + "/out/" + f)) << f;
  size_t matched = 0;
  const double ate = Ate(ref, dir + "/out/trajectory.txt", &matched);
  EXPECT_GE(matched, kScans - 5);
  // The noisy odometry alone drifts; on this prefix the filter stays within a few decimetres.
  EXPECT_LT(ate, 0.3) << "ATE " << ate << " m over " << matched << " scans";
  auto map = io::ReadMapServer(dir + "/out/map.yaml");
  ASSERT_TRUE(map.ok());
  EXPECT_GT(map->width, 100);
}

// Two processes over real UDP multicast in a private network namespace: the prefix replayed flat
// out (a burst far faster than the filter) must reach rbpf_mapper without a lost scan.
TEST(RbpfMapperProcess, MapsABurstReplayedOverUdpInANetns) {
  OMNI_REQUIRE_DATASET(clf, "slam-noisy-odom/intel.noisy.clf.gz");
  OMNI_REQUIRE_DATASET(ref, "slam-noisy-odom/intel.reference.txt");
  if (testing::Run("unshare -n true").exit_code != 0)
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string dir = testing::TempDir();
  const std::string log = dir + "/burst.lcmlog";
  WritePrefixLog(clf, log);
  const auto r = testing::RunReplayInNetns(
      dir,
      {testing::Bin("rbpf_mapper") + " --config " OMNI_SOURCE_DIR "/config/rbpf_mapper.yaml" +
       " --out " + dir + "/out --idle-exit 2"},
      log, "0");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("150 scans"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("0 lost on the bus"), std::string::npos) << r.output;
  size_t matched = 0;
  const double ate = Ate(ref, dir + "/out/trajectory.txt", &matched);
  EXPECT_GE(matched, kScans - 5);
  EXPECT_LT(ate, 0.3) << "ATE " << ate << " m over " << matched << " scans";
}

TEST(RbpfMapperNode, PublishesPosesAndGridsOnMemq) {
  OMNI_REQUIRE_DATASET(clf, "slam-noisy-odom/intel.noisy.clf.gz");
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  rbpf::RbpfOptions opt;
  opt.particles = 10;
  opt.grid_publish_interval_s = 0.5;
  opt.trajectory_publish_interval_s = 0.5;
  opt.grid_publish_resolution_m = 0;  // the map's own cells: the switch shows in the grids
  // Active within the prefix, so its counters in the heartbeat have something to count.
  opt.odometry_calibration.min_pairs = 5;
  ManualClock clock(1000000);
  rbpf::RbpfNode node(&b, opt, &clock);
  int poses = 0, grids = 0, heartbeats = 0;
  int64_t cal_pairs = -1, cell_mm = -1, switched = -1, map_tiles = -1;
  double first_grid_resolution = 0, last_grid_resolution = 0;
  std::vector<omni::pose2d_t> published;
  b.Subscribe<omni::pose2d_t>("POSE_RBPF", [&](const omni::pose2d_t& p, int64_t) {
    EXPECT_EQ(p.source, "rbpf");
    EXPECT_TRUE(std::isfinite(p.x_m));
    // The particles' spread: they agree on the heading to well under 0.1 rad, also for scans
    // between filter updates (whose pose is moved on by odometry from the particles').
    EXPECT_GE(p.covariance[0], 0.0);
    EXPECT_GE(p.covariance[4], 0.0);
    EXPECT_GE(p.covariance[8], 0.0);
    EXPECT_LT(p.covariance[8], 0.01) << "scan " << published.size();
    published.push_back(p);
    ++poses;
  });
  // The reported particle's path: scans accepted so far (thinned, at most one pose per scan), in
  // time order, ending at the pose just published for the newest scan.
  int trajectories = 0, trajectory_ends_checked = 0;
  b.Subscribe<omni::trajectory_t>("TRAJECTORY_RBPF", [&](const omni::trajectory_t& t, int64_t) {
    ++trajectories;
    EXPECT_EQ(t.source, "rbpf");
    ASSERT_EQ(t.num_poses, static_cast<int32_t>(t.pose_utime.size()));
    ASSERT_GT(t.num_poses, 0);
    EXPECT_LE(t.num_poses, static_cast<int32_t>(published.size()));
    for (size_t i = 1; i < t.pose_utime.size(); ++i)
      EXPECT_LT(t.pose_utime[i - 1], t.pose_utime[i]);
    EXPECT_EQ(t.utime, t.pose_utime.back());
    for (const auto& p : published) {
      if (p.utime != t.utime) continue;
      EXPECT_NEAR(p.x_m, t.x_m.back(), 1e-9);
      EXPECT_NEAR(p.y_m, t.y_m.back(), 1e-9);
      EXPECT_NEAR(p.yaw_rad, t.yaw_rad.back(), 1e-9);
      ++trajectory_ends_checked;
    }
  });
  b.Subscribe<omni::occupancy_grid_t>("GRID_RBPF", [&](const omni::occupancy_grid_t& g, int64_t) {
    if (++grids == 1) first_grid_resolution = g.resolution_m;
    last_grid_resolution = g.resolution_m;
  });
  b.Subscribe<omni::heartbeat_t>("HEARTBEAT", [&](const omni::heartbeat_t& h, int64_t) {
    EXPECT_EQ(h.process, "rbpf_mapper");
    ++heartbeats;
    for (int i = 0; i < h.num_counters; ++i)
      if (h.counter_names[static_cast<size_t>(i)] == "odom_cal_pairs_used")
        cal_pairs = h.counter_values[static_cast<size_t>(i)];
      else if (h.counter_names[static_cast<size_t>(i)] == "grid_cell_mm")
        cell_mm = h.counter_values[static_cast<size_t>(i)];
      else if (h.counter_names[static_cast<size_t>(i)] == "resolution_switched")
        switched = h.counter_values[static_cast<size_t>(i)];
      else if (h.counter_names[static_cast<size_t>(i)] == "map_tiles")
        map_tiles = h.counter_values[static_cast<size_t>(i)];
  });
  testing::PublishCarmenPrefix(
      clf, 60, b, clock, node,
      [](int64_t seq, omni::laser_scan_t& scan) {
        if (seq == 20) scan.ranges_m.assign(scan.ranges_m.size(), -1.f);  // garbage: counted
      },
      /*junk=*/true);  // an undecodable LIDAR_SCAN after each scan: counted, never handed over
  node.Flush();
  while (b.HandleTimeout(0) > 0) {
  }
  EXPECT_EQ(poses, 60);
  EXPECT_GE(grids, 5);
  EXPECT_GE(trajectories, 5);
  EXPECT_EQ(trajectory_ends_checked, trajectories);
  EXPECT_EQ(node.trajectories_published(), trajectories);
  EXPECT_GE(heartbeats, 5);
  EXPECT_EQ(b.counters().decode_errors.load(), 60);
  EXPECT_GE(node.slam().counters().invalid_beams, 180);
  EXPECT_GT(node.slam().counters().scans_processed, 20);
  EXPECT_GT(cal_pairs, 10);
  EXPECT_LE(cal_pairs, node.slam().odometry_calibrator().pairs_used());
  // One scan per 0.5-0.7 m: after the first 20 m the node maps on 5 cm cells, and says so.
  EXPECT_EQ(cell_mm, 50);
  EXPECT_EQ(switched, 1);
  // The last heartbeat's count of distinct tiles: at most as many as the particles reference.
  EXPECT_GT(map_tiles, 0);
  EXPECT_LE(map_tiles, static_cast<int64_t>(node.slam().total_tile_refs()));
  EXPECT_FLOAT_EQ(static_cast<float>(first_grid_resolution), 0.025f);  // before the 20 m
  EXPECT_FLOAT_EQ(static_cast<float>(last_grid_resolution), 0.05f);
  EXPECT_EQ(node.slam().counters().scans_in, 60);
}

// On 2.5 cm cells (the first 20 scans, before the cell-size decision) the node publishes its map
// on 5 cm cells, each the largest value of the four it covers; the map itself stays fine.
TEST(RbpfMapperNode, PublishesAFineMapOnCoarserCells) {
  OMNI_REQUIRE_DATASET(clf, "slam-noisy-odom/intel.noisy.clf.gz");
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  rbpf::RbpfOptions opt;
  opt.particles = 5;
  opt.grid_publish_interval_s = 0.5;
  ASSERT_DOUBLE_EQ(opt.grid_publish_resolution_m, 0.05);
  ManualClock clock(1000000);
  rbpf::RbpfNode node(&b, opt, &clock);
  io::GridMap last;
  int grids = 0;
  b.Subscribe<omni::occupancy_grid_t>("GRID_RBPF", [&](const omni::occupancy_grid_t& g, int64_t) {
    auto m = bus::FromGridMessage(g);
    ASSERT_TRUE(m.ok()) << m.error().message;
    EXPECT_NEAR(m->resolution_m, 0.05, 1e-6);  // a float in the message
    last = *m;
    ++grids;
  });
  testing::PublishCarmenPrefix(clf, 20, b, clock, node);
  node.Flush();
  ASSERT_FALSE(node.slam().resolution_choice().decided);
  clock.Advance(1000000);
  node.Tick();  // publishes the map as it is now
  while (b.HandleTimeout(0) > 0) {
  }
  EXPECT_GE(grids, 2);
  const io::GridMap fine = node.slam().ReportedMap();  // the published particle's
  ASSERT_DOUBLE_EQ(fine.resolution_m, 0.025);
  const io::GridMap expected = io::CoarsenGrid(fine, 2);
  EXPECT_EQ(last.width, expected.width);
  EXPECT_EQ(last.height, expected.height);
  EXPECT_NEAR(last.origin_x_m, fine.origin_x_m, 1e-5);
  EXPECT_NEAR(last.origin_y_m, fine.origin_y_m, 1e-5);
  EXPECT_EQ(last.cells, expected.cells);
  EXPECT_LT(last.cells.size() * 3, fine.cells.size());
  size_t occupied = 0;
  for (int8_t c : last.cells) occupied += c > 50;
  EXPECT_GT(occupied, 100u);
}

// A scan of 300 beams, all 2 m, over [-1.5, 1.5] rad, and an odometry pose along x: the
// inputs of the node tests below that need no real data.
omni::laser_scan_t FlatScan(int64_t utime, int64_t seq) {
  omni::laser_scan_t m{};
  m.utime = utime;
  m.seq = seq;
  m.angle_min_rad = -1.5f;
  m.angle_increment_rad = 0.01f;
  m.range_min_m = 0.1f;
  m.range_max_m = 30.f;
  m.ranges_m.assign(300, 2.f);
  m.num_ranges = static_cast<int32_t>(m.ranges_m.size());
  return m;
}

omni::odometry_t OdomAlongX(int64_t utime, double x, int64_t seq) {
  omni::odometry_t m{};
  m.utime = utime;
  m.seq = seq;
  m.x_m = x;
  return m;
}

// The process defers the filter and drains the socket first; a scan must still use the
// odometry that had arrived when it was covered, not a later sample with the same stamp
// (Intel's log repeats stamps).
TEST(RbpfMapperNode, DeferredScansKeepTheOdometryOfTheirArrival) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  rbpf::RbpfOptions opt;
  opt.particles = 4;
  ManualClock clock(1000000);
  rbpf::RbpfNode node(&b, opt, &clock);
  node.set_deferred(true);
  std::vector<omni::pose2d_t> poses;
  b.Subscribe<omni::pose2d_t>("POSE_RBPF",
                              [&](const omni::pose2d_t& p, int64_t) { poses.push_back(p); });
  auto odom = [&](int64_t utime, double x, int64_t seq) {
    b.Publish("WHEEL_ODOM", OdomAlongX(utime, x, seq));
  };
  auto scan = [&](int64_t utime, int64_t seq) { b.Publish("LIDAR_SCAN", FlatScan(utime, seq)); };
  odom(1000000, 0.0, 0);
  scan(1000000, 0);
  odom(2000000, 0.1, 1);
  scan(2000000, 1);
  odom(2000000, 5.0, 2);  // same stamp, arrives after the scan was covered
  while (b.HandleTimeout(0) > 0) {
  }
  EXPECT_EQ(node.pending(), 2u);
  EXPECT_EQ(node.ProcessReady(10), 2);
  while (b.HandleTimeout(0) > 0) {
  }
  ASSERT_EQ(poses.size(), 2u);
  EXPECT_NEAR(poses[1].x_m - poses[0].x_m, 0.1, 1e-6);
  EXPECT_EQ(node.slam().counters().odom_jumps, 0);
}

// Stopping with scans still queued: they are mapped and the map written, and the heartbeat
// sent with the outputs says the process is stopping (each scan the flush mapped used to set
// it back to "mapping"). The map before the queued scans is written first, so that a kill
// during a long flush leaves it.
TEST(RbpfMapperNode, StoppingWithQueuedScansMapsThemAndSaysItIsStopping) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  rbpf::RbpfOptions opt;
  opt.particles = 4;
  ManualClock clock(1000000);
  rbpf::RbpfNode node(&b, opt, &clock);
  node.set_deferred(true);
  std::vector<omni::heartbeat_t> beats;
  b.Subscribe<omni::heartbeat_t>("HEARTBEAT", [&](const omni::heartbeat_t& h, int64_t) {
    if (h.process == "rbpf_mapper") beats.push_back(h);
  });
  auto send = [&](int k) {
    const int64_t t = 1000000 + k * 100000;
    b.Publish("WHEEL_ODOM", OdomAlongX(t, 0.05 * k, k));
    b.Publish("LIDAR_SCAN", FlatScan(t, k));
  };
  auto drain = [&] {
    while (b.HandleTimeout(0) > 0) {
    }
  };
  for (int k = 0; k < 3; ++k) send(k);
  drain();
  node.ProcessReady(100);
  ASSERT_GT(node.slam().counters().scans_processed, 0);
  for (int k = 3; k < 8; ++k) send(k);
  drain();
  ASSERT_GT(node.pending(), 0u);
  const std::string dir = omni::testing::TempDir() + "/rbpf_stop";
  std::filesystem::create_directories(dir);
  node.heartbeat().SetState(omni::heartbeat_t::STATE_STOPPING, "writing map");
  ASSERT_TRUE(node.WriteOutputs(dir).ok());
  omni::testing::ExpectOnlyListedFiles(dir, rbpf::RbpfNode::OutputFiles());
  drain();
  EXPECT_EQ(node.pending(), 0u);
  EXPECT_TRUE(std::filesystem::exists(dir + "/map.pgm"));
  auto traj = io::ReadTrajectory(dir + "/trajectory.txt");
  ASSERT_TRUE(traj.ok()) << traj.error().message;
  EXPECT_EQ(traj->entries.size(), 8u);
  ASSERT_FALSE(beats.empty());
  EXPECT_EQ(beats.back().state, omni::heartbeat_t::STATE_STOPPING) << beats.back().status_text;
}

testing::NodeReplay ReplayToRbpfNode(const std::string& clf, int scans,
                                     const testing::Glitches& g) {
  return testing::ReplayToNode(clf, scans, g, "POSE_RBPF", [](bus::Bus* b, const Clock* clock) {
    rbpf::RbpfOptions opt;
    opt.particles = 8;
    opt.threads = 1;
    return std::make_unique<rbpf::RbpfNode>(b, opt, clock);
  });
}

// One odometry message and one scan stamped an hour ahead, and one pair published twice, in
// the middle of a run: the node drops them, says so in its heartbeat, and maps on as if they
// had not come (before, the future odometry froze the odometry and the future scan held the
// queue for up to 3000 scans).
TEST(RbpfMapperNode, FutureStampsAndDuplicatesDoNotStallMapping) {
  OMNI_REQUIRE_DATASET(clf, "slam-noisy-odom/intel.noisy.clf.gz");
  constexpr int kPairs = 120;
  testing::Glitches g;
  g.future_odom_at = 40;
  g.future_scan_at = 70;
  g.duplicate_at = 90;
  const auto clean = ReplayToRbpfNode(clf, kPairs, {});
  const auto glitched = ReplayToRbpfNode(clf, kPairs, g);
  ASSERT_EQ(clean.poses.size(), static_cast<size_t>(kPairs));
  EXPECT_EQ(testing::HeartbeatCounter(clean.heartbeat, "time_rebases"), 0);
  // The five odometry messages after the future one prove it (stamp_order.h) and are kept; the
  // scans behind the future scan wait in the queue until five of them prove it: none is lost.
  EXPECT_EQ(glitched.poses.size(), static_cast<size_t>(kPairs));
  const auto& hb = glitched.heartbeat;
  EXPECT_EQ(testing::HeartbeatCounter(hb, "time_rebases"), 2);  // the odometry's and the scans'
  EXPECT_EQ(testing::HeartbeatCounter(hb, "scans_future_dropped"), 1);
  EXPECT_EQ(testing::HeartbeatCounter(hb, "scans_duplicate"), 1);
  // No stamp of an hour ahead went out, and the robot kept moving: the last pose is where the
  // clean run's is.
  for (const auto& p : glitched.poses) EXPECT_LT(p.utime, clean.poses.back().utime + 1000000);
  EXPECT_EQ(glitched.poses.back().utime, clean.poses.back().utime);
  EXPECT_LT(std::hypot(glitched.poses.back().x_m - clean.poses.back().x_m,
                       glitched.poses.back().y_m - clean.poses.back().y_m),
            0.05);
}

// The clock set back an hour mid-run (an NTP step, a driver PC's reboot): the node and the
// filter re-base their streams and map on from the new stamps; the scans that prove it are
// held and mapped too.
TEST(RbpfMapperNode, FollowsAClockSetBack) {
  OMNI_REQUIRE_DATASET(clf, "slam-noisy-odom/intel.noisy.clf.gz");
  constexpr int kPairs = 120;
  testing::Glitches g;
  g.clock_back_at = 60;
  const auto clean = ReplayToRbpfNode(clf, kPairs, {});
  const auto stepped = ReplayToRbpfNode(clf, kPairs, g);
  ASSERT_EQ(clean.poses.size(), static_cast<size_t>(kPairs));
  EXPECT_EQ(stepped.poses.size(), static_cast<size_t>(kPairs));
  EXPECT_EQ(testing::HeartbeatCounter(stepped.heartbeat, "scans_late"), 4);
  EXPECT_GE(testing::HeartbeatCounter(stepped.heartbeat, "time_rebases"), 2);
  EXPECT_EQ(testing::HeartbeatCounter(stepped.heartbeat, "scans_future_dropped"), 0);
  EXPECT_EQ(stepped.poses.back().utime, clean.poses.back().utime - 3600LL * 1000000);
  EXPECT_LT(std::hypot(stepped.poses.back().x_m - clean.poses.back().x_m,
                       stepped.poses.back().y_m - clean.poses.back().y_m),
            0.3);
}

// A 300-beam scan of a wavy wall about 2 m away (every return NaN when `covered`).
omni::laser_scan_t WavyScan(int64_t utime, int64_t seq, float range_max_m = 30.f,
                            bool covered = false) {
  omni::laser_scan_t s{};
  s.utime = utime;
  s.seq = seq;
  s.angle_min_rad = -1.5f;
  s.angle_increment_rad = 0.01f;
  s.range_min_m = 0.1f;
  s.range_max_m = range_max_m;
  for (int i = 0; i < 300; ++i)
    s.ranges_m.push_back(covered ? NAN : 2.f + 0.5f * std::sin(0.05f * i));
  s.num_ranges = static_cast<int32_t>(s.ranges_m.size());
  return s;
}

// Scans without odometry (the base bridge stopped): DEGRADED with the reason in the heartbeat,
// not "waiting for scans" while every scan is dropped (review finding 2026-12-06); OK again once
// odometry comes back.
TEST(RbpfMapperNode, ScansWithoutOdometryMakeTheHeartbeatDegraded) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  rbpf::RbpfOptions opt;
  opt.particles = 4;
  ManualClock clock(1000000);
  rbpf::RbpfNode node(&b, opt, &clock);
  int8_t state = -1;
  std::string text;
  int64_t no_odom = 0, processed = 0;
  b.Subscribe<omni::heartbeat_t>("HEARTBEAT", [&](const omni::heartbeat_t& h, int64_t) {
    state = h.state;
    text = h.status_text;
    for (size_t i = 0; i < h.counter_names.size(); ++i) {
      if (h.counter_names[i] == "scans_no_odom") no_odom = h.counter_values[i];
      if (h.counter_names[i] == "scans_processed") processed = h.counter_values[i];
    }
  });
  int64_t seq = 0;
  auto step = [&](bool with_odom, bool covered = false, float range_max_m = 30.f) {
    clock.Advance(100000);
    const int64_t t = clock.NowUtime();
    if (with_odom) {
      omni::odometry_t o{};
      o.utime = t;
      o.seq = seq;
      o.x_m = 0.02 * static_cast<double>(seq);
      b.Publish("WHEEL_ODOM", o);
    }
    b.Publish("LIDAR_SCAN", WavyScan(t, ++seq, range_max_m, covered));
    while (b.HandleTimeout(0) > 0) {
    }
    node.ProcessReady(10);
    node.Tick();
    while (b.HandleTimeout(0) > 0) {
    }
  };
  for (int i = 0; i < 120; ++i) step(false);
  EXPECT_GT(no_odom, 100);
  EXPECT_EQ(state, omni::heartbeat_t::STATE_DEGRADED) << text;
  EXPECT_NE(text.find("no odometry for"), std::string::npos) << text;
  for (int i = 0; i < 120; ++i) step(true);
  EXPECT_EQ(state, omni::heartbeat_t::STATE_OK) << text;
  EXPECT_GT(processed, 0);
  // The lidar covered (every return NaN) while the base drives: nothing can be mapped, and the
  // heartbeat says so (it said OK "mapping" while every scan had too few beams).
  const int64_t processed_before = node.slam().counters().scans_processed;
  for (int i = 0; i < 120; ++i) step(true, /*covered=*/true);
  EXPECT_EQ(node.slam().counters().scans_processed, processed_before);
  EXPECT_EQ(state, omni::heartbeat_t::STATE_DEGRADED) << text;
  EXPECT_NE(text.find("too few valid beams"), std::string::npos) << text;
  // A driver that gives range_max 0 (no limit, as the pose-graph mapper's matching reads it):
  // mapped, not refused as having no valid beam.
  for (int i = 0; i < 120; ++i) step(true, false, /*range_max_m=*/0.f);
  EXPECT_GT(node.slam().counters().scans_processed, processed_before);
  EXPECT_EQ(state, omni::heartbeat_t::STATE_OK) << text;
}

// One odometry sample stamped an hour ahead among good ones at 20 Hz: the scans stamped while it
// is the newest wait for the samples that bracket them (it is dropped once five good ones
// re-base the stream) and are placed as without it. Before, they took the last good sample as
// their odometry (the bracket to the future sample is a gap) and were mapped at once, up to
// 0.25 s of motion off.
TEST(RbpfMapperNode, AnOdometrySampleStampedAheadDoesNotPlaceTheScansBeforeIt) {
  auto run = [](bool glitch) {
    auto bus_or = bus::Bus::Create("memq://");
    EXPECT_TRUE(bus_or.ok());
    auto& b = **bus_or;
    rbpf::RbpfOptions opt;
    opt.particles = 4;
    opt.threads = 1;
    ManualClock clock(1000000);
    rbpf::RbpfNode node(&b, opt, &clock);
    std::vector<omni::pose2d_t> poses;
    b.Subscribe<omni::pose2d_t>("POSE_RBPF",
                                [&](const omni::pose2d_t& m, int64_t) { poses.push_back(m); });
    for (int k = 1; k <= 120; ++k) {
      clock.Advance(50000);
      const int64_t t = clock.NowUtime();
      omni::odometry_t o{};
      o.utime = t;
      o.seq = k;
      o.x_m = 0.04 * k;  // 0.8 m/s
      o.yaw_rad = 0.01 * k;
      b.Publish("WHEEL_ODOM", o);
      if (glitch && k == 60) {
        o.utime = t + 3600LL * 1000000;
        o.x_m += 0.04;
        b.Publish("WHEEL_ODOM", o);
      }
      if (k % 2 == 1) {
        b.Publish("LIDAR_SCAN", WavyScan(t + 20000, k));  // between this sample and the next
      }
      while (b.HandleTimeout(0) > 0) {
      }
      node.ProcessReady(10);
      while (b.HandleTimeout(0) > 0) {
      }
    }
    return poses;
  };
  const auto clean = run(false), glitched = run(true);
  ASSERT_GT(clean.size(), 50u);
  ASSERT_EQ(glitched.size(), clean.size());
  double worst = 0;
  for (size_t i = 0; i < clean.size(); ++i) {
    EXPECT_EQ(glitched[i].utime, clean[i].utime);
    worst =
        std::max(worst, std::hypot(glitched[i].x_m - clean[i].x_m, glitched[i].y_m - clean[i].y_m));
  }
  EXPECT_LT(worst, 1e-3);
}

// Stamps at the ends of int64 (corrupt messages) are refused and counted before any time
// arithmetic: a scan stamped near INT64_MAX overflowed the wait for its last beam's odometry,
// and an odometry sample at INT64_MIN every interpolation bracketing it (UBSan aborts on both).
TEST(RbpfMapperNode, StampsAtTheEndsOfInt64AreRefused) {
  auto bus_or = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus_or.ok()) << bus_or.error().message;
  auto& b = **bus_or;
  rbpf::RbpfOptions opt;
  opt.particles = 4;
  opt.use_imu = true;
  ManualClock clock(1000000);
  rbpf::RbpfNode node(&b, opt, &clock);
  omni::odometry_t o{};
  o.utime = std::numeric_limits<int64_t>::min();
  b.Publish("WHEEL_ODOM", o);
  omni::imu_t imu{};
  imu.utime = std::numeric_limits<int64_t>::max();
  b.Publish(opt.imu_channel, imu);
  for (int i = 1; i <= 30; ++i) {
    o.utime = 1000000 + i * 100000;
    o.seq = i;
    o.x_m = 0.05 * i;
    b.Publish("WHEEL_ODOM", o);
    omni::laser_scan_t s = WavyScan(i == 10 ? std::numeric_limits<int64_t>::max() - 5 : o.utime, i);
    s.scan_time_s = 0.1f;
    b.Publish("LIDAR_SCAN", s);
    while (b.HandleTimeout(0) > 0) {
    }
    node.ProcessReady(10);
  }
  node.Flush();
  const rbpf::RbpfCounters& c = node.slam().counters();
  EXPECT_EQ(c.odom_invalid, 1);
  EXPECT_EQ(c.imu_invalid, 1);
  EXPECT_EQ(c.scans_no_odom, 1);  // the scan at INT64_MAX: no odometry can be stamped there
  EXPECT_GE(c.scans_processed, 2);
}

TEST(OmniSlam, WritesEveryOutputAndRejectsBadArguments) {
  OMNI_REQUIRE_DATASET(clf, "slam-noisy-odom/intel.noisy.clf.gz");
  const std::string dir = testing::TempDir();
  auto r = testing::Run(testing::Bin("omni-slam") + " rbpf " + clf + " --out " + dir +
                        " --seed 3 --particles 10 --max-scans 60 --quiet");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* f : {"map.pgm", "map.yaml", "map.png", "map_trajectory.png", "trajectory.txt",
                        "live_trajectory.txt", "stats.json"})
    EXPECT_TRUE(std::filesystem::exists(dir + "/" + f)) << f;
  std::ifstream stats(dir + "/stats.json");
  std::string json((std::istreambuf_iterator<char>(stats)), std::istreambuf_iterator<char>());
  for (const char* k : {"\"wall_s\"", "\"scans\": 60", "\"particles\": 10", "\"resamplings\"",
                        "\"match_failures\"", "\"seed\": 3", "\"reported_to_final_m\""})
    EXPECT_NE(json.find(k), std::string::npos) << k << " in " << json;
  auto t = io::ReadTrajectory(dir + "/trajectory.txt");
  ASSERT_TRUE(t.ok());
  EXPECT_EQ(t->entries.size(), 60u);
  EXPECT_EQ(t->entries.front().index, 0);
  // The pose returned at each scan (what POSE_RBPF carries), one per scan in input order.
  auto live = io::ReadTrajectory(dir + "/live_trajectory.txt");
  ASSERT_TRUE(live.ok());
  ASSERT_EQ(live->entries.size(), 60u);
  for (size_t i = 0; i < live->entries.size(); ++i)
    EXPECT_EQ(live->entries[i].index, static_cast<int64_t>(i));

  r = testing::Run(testing::Bin("omni-slam") + " gmapping x --out " + dir);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("unknown mapper 'gmapping'"), std::string::npos) << r.output;
  r = testing::Run(testing::Bin("omni-slam") + " rbpf /nonexistent.clf --out " + dir);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("does not exist"), std::string::npos) << r.output;
  const std::string bad = dir + "/bad.yaml";
  std::ofstream(bad) << "particle: 30\n";
  r = testing::Run(testing::Bin("omni-slam") + " rbpf " + clf + " --out " + dir + " --config " +
                   bad);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("particle"), std::string::npos) << r.output;
  r = testing::Run(testing::Bin("omni-slam") + " --help");
  EXPECT_EQ(r.exit_code, 0);
}

}  // namespace
}  // namespace omni
