// Test helpers of the mapper processes' replay tests: the first scans of a CARMEN log written as
// an LCM log laid out as `omni import carmen` does (odometry on WHEEL_ODOM, scans on LIDAR_SCAN,
// each laser line's own odometry pose published just before its scan), and the ATE of a
// trajectory file against a reference.
#pragma once

#include <cstdint>
#include <fstream>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/bus/bus.h"
#include "omni/bus/convert.h"
#include "omni/common/geometry.h"
#include "omni/common/time.h"
#include "omni/eval/eval.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/carmen.h"
#include "omni/io/lcm_log.h"
#include "omni/io/trajectory_io.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/pose2d_t.hpp"
#include "run.h"

namespace omni::testing {

inline void WriteCarmenPrefixLog(const std::string& clf, const std::string& out, size_t scans) {
  auto log = io::ReadCarmenLog(clf);
  ASSERT_TRUE(log.ok()) << log.error().message;
  auto w = io::LcmLogWriter::Open(out);
  ASSERT_TRUE(w.ok());
  int64_t seq = 0, oseq = 0;
  auto put = [&](const auto& msg, const std::string& channel, int64_t utime) {
    std::vector<uint8_t> buf(static_cast<size_t>(msg.getEncodedSize()));
    msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
    ASSERT_TRUE(w->Write(utime, channel, buf.data(), buf.size()).ok());
  };
  for (const auto& r : log->records) {
    if (r.kind == io::CarmenRecord::Kind::kOdom) {
      const auto m = bus::ToOdometry(r.odom, oseq++);
      put(m, "WHEEL_ODOM", m.utime);
      continue;
    }
    io::CarmenOdom o;
    o.timestamp_s = r.laser.timestamp_s;
    o.pose = r.laser.robot_pose;
    const auto om = bus::ToOdometry(o, oseq++);
    put(om, "WHEEL_ODOM", om.utime);
    const auto m = bus::ToLaserScan(r.laser, seq);
    put(m, "LIDAR_SCAN", m.utime);
    if (static_cast<size_t>(++seq) >= scans) break;
  }
  ASSERT_TRUE(w->Close().ok());
}

// The first `scans` laser records of a CARMEN log published on `b` in process (memq://): each
// record's odometry on WHEEL_ODOM, then its scan on LIDAR_SCAN (after `edit(seq, scan)` when
// given), with `junk`, an undecodable LIDAR_SCAN message after each scan; the bus is handled,
// then `clock` advances 0.25 s and the node ticks.
template <typename Node>
void PublishCarmenPrefix(const std::string& clf, int64_t scans, bus::Bus& b, ManualClock& clock,
                         Node& node,
                         const std::function<void(int64_t, omni::laser_scan_t&)>& edit = {},
                         bool junk = false) {
  auto log = io::ReadCarmenLog(clf);
  ASSERT_TRUE(log.ok()) << log.error().message;
  int64_t seq = 0;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    io::CarmenOdom o;
    o.timestamp_s = r.laser.timestamp_s;
    o.pose = r.laser.robot_pose;
    b.Publish("WHEEL_ODOM", bus::ToOdometry(o, seq));
    auto scan = bus::ToLaserScan(r.laser, seq);
    if (edit) edit(seq, scan);
    b.Publish("LIDAR_SCAN", scan);
    if (junk) b.PublishRaw("LIDAR_SCAN", "junk", 4);
    while (b.HandleTimeout(0) > 0) {
    }
    clock.Advance(250000);
    node.Tick();
    if (++seq >= scans) break;
  }
}

// ATE RMSE in metres of `est_path` against `ref_path` (1e9 when either is unreadable or they
// share no stamps); `matched` gets the number of matched poses.
inline double AteRmse(const std::string& ref_path, const std::string& est_path, size_t* matched) {
  auto ref = io::ReadTrajectory(ref_path);
  auto est = io::ReadTrajectory(est_path);
  if (!ref.ok() || !est.ok()) return 1e9;
  auto ate = eval::ComputeAte(*ref, *est);
  if (!ate.ok()) return 1e9;
  *matched = ate->matched;
  return ate->rmse_m;
}

// Runs `processes` (command lines, each started in the background) and then `omni-replay LOG
// --speed SPEED` in a private network namespace with loopback multicast (nothing leaves the
// machine), waits for every process and returns the combined output; the exit code is non-zero
// when any of them failed. The script goes to DIR/run.sh.
inline RunResult RunReplayInNetns(const std::string& dir, const std::vector<std::string>& processes,
                                  const std::string& log, const std::string& speed) {
  {
    std::ofstream s(dir + "/run.sh");
    s << "set -u\nip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304'\n"
      << "pids=\"\"\n";
    for (const auto& p : processes) s << p << " & pids=\"$pids $!\"\n";
    s << "sleep 0.5\ntimeout 120 " << Bin("omni-replay") << " " << log << " --speed " << speed
      << "\nrc=$?\nfor p in $pids; do wait $p || rc=$((rc + 1)); done\nexit $rc\n";
  }
  return Run("timeout 250 unshare -n bash " + dir + "/run.sh");
}

// The value of a heartbeat's counter `name` (a test failure when it has none).
inline int64_t HeartbeatCounter(const omni::heartbeat_t& h, const std::string& name) {
  for (size_t i = 0; i < h.counter_names.size(); ++i)
    if (h.counter_names[i] == name) return h.counter_values[i];
  ADD_FAILURE() << "no heartbeat counter " << name;
  return -1;
}

// The bad stamps a glitching clock or a corrupt field produce, by scan index (-1: none): after
// scan `future_odom_at` one extra odometry message stamped an hour ahead, after scan
// `future_scan_at` one extra scan stamped so, scan `duplicate_at` published twice, and from
// scan `clock_back_at` on every stamp an hour earlier (a clock set back).
struct Glitches {
  int future_odom_at = -1, future_scan_at = -1, duplicate_at = -1, clock_back_at = -1;
};

// Publishes the first `scans` laser scans of a CARMEN log on `bus`, each after five WHEEL_ODOM
// messages interpolated from the previous scan's robot pose to its own (odometry at about five
// times the scan rate, as on the robot), handling the bus after each scan and calling
// `step(i)`, with the glitches `g` asks for.
template <typename Step>
void PublishCarmenWithGlitches(bus::Bus& bus, const std::string& clf, int scans, const Glitches& g,
                               Step step) {
  auto log = io::ReadCarmenLog(clf);
  ASSERT_TRUE(log.ok()) << log.error().message;
  constexpr int64_t kHourUs = 3600LL * 1000000;
  constexpr int kOdomPerScan = 5;
  int64_t seq = 0, odom_seq = 0;
  std::optional<io::CarmenOdom> prev;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    io::CarmenOdom o;
    o.timestamp_s = r.laser.timestamp_s;
    if (g.clock_back_at >= 0 && seq >= g.clock_back_at) o.timestamp_s -= 3600.0;
    o.pose = r.laser.robot_pose;
    omni::odometry_t odom{};
    for (int k = prev ? 1 : kOdomPerScan; k <= kOdomPerScan; ++k) {
      io::CarmenOdom at = o;
      if (prev) {
        const double f = static_cast<double>(k) / kOdomPerScan;
        at.timestamp_s = prev->timestamp_s + f * (o.timestamp_s - prev->timestamp_s);
        at.pose = Interpolate(prev->pose, o.pose, f);
      }
      odom = bus::ToOdometry(at, odom_seq++);
      bus.Publish("WHEEL_ODOM", odom);
    }
    prev = o;
    auto laser = r.laser;
    laser.timestamp_s = o.timestamp_s;
    const auto scan = bus::ToLaserScan(laser, seq);
    for (int k = 0; k < (seq == g.duplicate_at ? 2 : 1); ++k) bus.Publish("LIDAR_SCAN", scan);
    if (seq == g.future_odom_at) {
      auto late = odom;
      late.utime += kHourUs;
      bus.Publish("WHEEL_ODOM", late);
    }
    if (seq == g.future_scan_at) {
      auto late = scan;
      late.utime += kHourUs;
      bus.Publish("LIDAR_SCAN", late);
    }
    while (bus.HandleTimeout(0) > 0) {
    }
    step(static_cast<int>(seq));
    if (++seq >= scans) break;
  }
}

// What a mapper node published over such a replay: its poses and its last heartbeat.
struct NodeReplay {
  std::vector<omni::pose2d_t> poses;
  omni::heartbeat_t heartbeat{};
};

// Replays the first `scans` scans of `clf` with `g` to the node `make_node(bus, clock)` builds
// on memq:// (a manual clock advancing 0.1 s per scan), flushes it and collects what it
// published on `pose_channel` and HEARTBEAT.
template <typename MakeNode>
NodeReplay ReplayToNode(const std::string& clf, int scans, const Glitches& g,
                        const std::string& pose_channel, MakeNode make_node) {
  NodeReplay out;
  auto bus_or = bus::Bus::Create("memq://");
  EXPECT_TRUE(bus_or.ok()) << bus_or.error().message;
  if (!bus_or.ok()) return out;
  auto& b = **bus_or;
  ManualClock clock(1000000);
  auto node = make_node(&b, &clock);
  b.Subscribe<omni::pose2d_t>(pose_channel,
                              [&](const omni::pose2d_t& p, int64_t) { out.poses.push_back(p); });
  b.Subscribe<omni::heartbeat_t>("HEARTBEAT",
                                 [&](const omni::heartbeat_t& h, int64_t) { out.heartbeat = h; });
  PublishCarmenWithGlitches(b, clf, scans, g, [&](int) { clock.Advance(100000); });
  node->Flush();
  node->heartbeat().Tick(true);
  while (b.HandleTimeout(0) > 0) {
  }
  return out;
}

}  // namespace omni::testing
