#include "omni/bus/bus.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/io/lcm_log.h"

#include "../common/failing_log.h"
#include "../common/test_paths.h"
#include "omni/bus/convert.h"
#include "omni/bus/heartbeat.h"
#include "omni/bus/map_save.h"
#include "omni/bus/slam_log.h"
#include "omni/color_image_t.hpp"
#include "omni/common/geometry.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/carmen.h"
#include "omni/io/grid.h"
#include "omni/laser_scan_t.hpp"
#include "omni/map_save_reply_t.hpp"
#include "omni/map_save_request_t.hpp"
#include "omni/occupancy_grid_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/pose2d_t.hpp"

namespace omni::bus {
namespace {

void Pump(Bus& bus) {
  while (bus.HandleTimeout(0) > 0) {
  }
}

TEST(Bus, TypedRoundTripOnMemq) {
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  std::vector<omni::pose2d_t> got;
  (*bus)->Subscribe<omni::pose2d_t>("POSE",
                                    [&](const omni::pose2d_t& m, int64_t) { got.push_back(m); });
  omni::pose2d_t p{};
  p.utime = 42;
  p.frame = "map";
  p.source = "test";
  p.x_m = 1.5;
  ASSERT_TRUE((*bus)->Publish("POSE", p));
  Pump(**bus);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].utime, 42);
  EXPECT_EQ(got[0].x_m, 1.5);
  EXPECT_EQ((*bus)->counters().msgs_in, 1);
  EXPECT_EQ((*bus)->counters().msgs_out, 1);
}

TEST(Bus, UndecodableMessagesAreCountedNotDelivered) {
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  int delivered = 0;
  (*bus)->Subscribe<omni::pose2d_t>("POSE", [&](const omni::pose2d_t&, int64_t) { ++delivered; });
  const char garbage[] = "this is not a pose2d_t";
  ASSERT_TRUE((*bus)->PublishRaw("POSE", garbage, sizeof(garbage)));
  // A valid message of another type on the same channel: wrong fingerprint.
  omni::heartbeat_t hb{};
  hb.process = "x";
  ASSERT_TRUE((*bus)->Publish("POSE", hb));
  // A truncated valid message.
  omni::pose2d_t p{};
  p.frame = "map";
  std::vector<uint8_t> buf(static_cast<size_t>(p.getEncodedSize()));
  p.encode(buf.data(), 0, static_cast<int>(buf.size()));
  ASSERT_TRUE((*bus)->PublishRaw("POSE", buf.data(), static_cast<int>(buf.size() - 5)));
  Pump(**bus);
  EXPECT_EQ(delivered, 0);
  EXPECT_EQ((*bus)->counters().decode_errors, 3);
  EXPECT_EQ((*bus)->last_decode_error(), "POSE");
}

// A process that reads a log whose framing is broken (file://) loses events where LCM's reader
// stops: counted (log_framing_errors), not only warned about once at the start.
TEST(Bus, ACorruptLogReadThroughFileIsCounted) {
  const std::string dir = ::testing::TempDir() + "/bus_corrupt_log";
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/c.lcmlog";
  {
    auto w = io::LcmLogWriter::Open(path);
    ASSERT_TRUE(w.ok());
    const std::string data(40, 'x');
    for (int i = 0; i < 20; ++i) ASSERT_TRUE(w->Write(1000 + i, "X", data.data(), 40).ok());
    ASSERT_TRUE(w->Close().ok());
  }
  auto clean = Bus::Create("file://" + path + "?speed=0");
  ASSERT_TRUE(clean.ok()) << clean.error().message;
  EXPECT_EQ((*clean)->counters().log_framing_errors, 0);
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(69 * 10);  // the eleventh event's sync word (LCM refuses a log whose second is bad)
    f.put('\x00');
  }
  auto bus = Bus::Create("file://" + path + "?speed=0");
  ASSERT_TRUE(bus.ok()) << bus.error().message;
  EXPECT_EQ((*bus)->counters().log_framing_errors, 1);
}

TEST(Bus, HeartbeatCarriesCounters) {
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  std::vector<omni::heartbeat_t> got;
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { got.push_back(m); });
  ManualClock clock(1'000'000);
  Heartbeat hb(bus->get(), "tester", &clock);
  int64_t resyncs = 7;
  hb.AddCounter("resyncs", [&] { return resyncs; });
  hb.SetState(omni::heartbeat_t::STATE_DEGRADED, "device flaky");
  ASSERT_TRUE(hb.Tick());
  EXPECT_FALSE(hb.Tick()) << "second tick within the period publishes nothing";
  clock.Advance(1'000'000);
  resyncs = 9;
  ASSERT_TRUE(hb.Tick());
  Pump(**bus);
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[1].process, "tester");
  EXPECT_EQ(got[1].state, omni::heartbeat_t::STATE_DEGRADED);
  EXPECT_EQ(got[1].uptime_us, 1'000'000);
  ASSERT_GE(got[1].num_counters, 1);
  EXPECT_EQ(got[1].counter_names[0], "resyncs");
  EXPECT_EQ(got[1].counter_values[0], 9);
  EXPECT_GT(got[1].rss_mb, 0.f);
}

// The receivers' view of a thinned path: interpolated at `utime` between the poses around it,
// as the OctoMap builder's lookup does.
Pose2 InterpolatedAt(const omni::trajectory_t& m, int64_t utime) {
  const auto it = std::lower_bound(m.pose_utime.begin(), m.pose_utime.end(), utime);
  const size_t b = static_cast<size_t>(it - m.pose_utime.begin());
  EXPECT_LT(b, m.pose_utime.size());
  const Pose2 pb(m.x_m[b], m.y_m[b], m.yaw_rad[b]);
  if (m.pose_utime[b] == utime) return pb;
  EXPECT_GT(b, 0u);
  const Pose2 pa(m.x_m[b - 1], m.y_m[b - 1], m.yaw_rad[b - 1]);
  const double f = static_cast<double>(utime - m.pose_utime[b - 1]) /
                   static_cast<double>(m.pose_utime[b] - m.pose_utime[b - 1]);
  return Interpolate(pa, pb, f);
}

struct Stamped {
  int64_t utime;
  Pose2 pose;
};

// 10 Hz along a straight 5 m, a quarter turn on the spot, then an arc of 1 m radius whose
// heading, stored wrapped, crosses +-pi.
std::vector<Stamped> DrivenPath() {
  std::vector<Stamped> path;
  int64_t t = 1000;
  for (int i = 0; i <= 100; ++i, t += 100000) path.push_back({t, Pose2(0.05 * i, 0, 0)});
  for (int i = 1; i <= 30; ++i, t += 100000) path.push_back({t, Pose2(5, 0, M_PI / 60 * i)});
  for (int i = 1; i <= 200; ++i, t += 100000) {
    const double a = 0.02 * i;
    path.push_back({t, Pose2(5 - 1 + std::cos(a), std::sin(a), WrapAngle(M_PI / 2 + a))});
  }
  return path;
}

// A mapper's path goes out thinned: every pose left out is where the receivers' interpolation
// puts it, within the tolerances, and no gap between the poses sent is wider than max_gap_us.
TEST(Bus, TrajectoryMessagesAreThinnedWithinTheirTolerances) {
  const std::vector<Stamped> path = DrivenPath();
  const TrajectoryThinning th;  // 5 mm, 0.005 rad, 1 s
  const auto m = ToTrajectoryMessage(path, "map", "posegraph");
  EXPECT_EQ(m.num_poses, static_cast<int32_t>(m.pose_utime.size()));
  EXPECT_EQ(m.x_m.size(), m.pose_utime.size());
  EXPECT_EQ(m.yaw_rad.size(), m.pose_utime.size());
  // The straight line and the turn on the spot need a pose a second; the arc (5 cm steps
  // curving by 0.02 rad) needs more but far from all of its 200.
  EXPECT_LT(m.num_poses, static_cast<int32_t>(path.size()) / 3);
  EXPECT_GT(m.num_poses, 30);
  EXPECT_EQ(m.pose_utime.front(), path.front().utime);
  EXPECT_EQ(m.pose_utime.back(), path.back().utime);
  EXPECT_EQ(m.utime, path.back().utime);
  EXPECT_DOUBLE_EQ(m.yaw_rad.back(), path.back().pose.theta);
  for (size_t i = 1; i < m.pose_utime.size(); ++i) {
    EXPECT_GT(m.pose_utime[i], m.pose_utime[i - 1]);
    EXPECT_LE(m.pose_utime[i] - m.pose_utime[i - 1], th.max_gap_us);
  }
  double worst_m = 0, worst_rad = 0;
  for (const Stamped& s : path) {
    const Pose2 q = InterpolatedAt(m, s.utime);
    worst_m = std::max(worst_m, std::hypot(q.x - s.pose.x, q.y - s.pose.y));
    worst_rad = std::max(worst_rad, std::abs(WrapAngle(q.theta - s.pose.theta)));
  }
  EXPECT_LE(worst_m, th.tolerance_m);
  EXPECT_LE(worst_rad, th.tolerance_rad);
  EXPECT_GT(worst_m + worst_rad, 0.0);  // something was left out

  // Zero tolerances send the path whole.
  TrajectoryThinning exact;
  exact.tolerance_m = 0;
  const auto whole = ToTrajectoryMessage(path, "map", "posegraph", exact);
  EXPECT_EQ(whole.num_poses, static_cast<int32_t>(path.size()));
  // A step back in time and a NaN are kept, never interpolated across.
  std::vector<Stamped> odd;
  for (int i = 0; i < 10; ++i) odd.push_back({1000 + 100000 * i, Pose2(0.01 * i, 0, 0)});
  odd[4].utime = odd[2].utime - 1;
  odd[7].pose.x = std::nan("");
  omni::trajectory_t o = ToTrajectoryMessage(odd, "map", "rbpf");
  EXPECT_NE(std::find(o.pose_utime.begin(), o.pose_utime.end(), odd[4].utime), o.pose_utime.end());
  EXPECT_EQ(std::count_if(o.x_m.begin(), o.x_m.end(), [](double x) { return std::isnan(x); }), 1);
}

// Past the cap the tolerances are doubled until the path fits, and a path that cannot fit even so
// goes out as every k-th thinned pose with the newest in it (10 Hz scans used to grow TRAJECTORY_*
// by 1.15 MB an hour, beyond a 4 MB receive buffer after about 3.5 h); poses on one stamp go out
// once (the later one).
TEST(Bus, TrajectoryMessagesStayUnderTheirCapAndStampsAreUnique) {
  const std::vector<Stamped> path = DrivenPath();
  const TrajectoryThinning th;
  omni::trajectory_t free_run = ToTrajectoryMessage(path, "map", "rbpf");
  const size_t thinned = free_run.pose_utime.size();
  const auto m = ToTrajectoryMessage(path, "map", "rbpf", th, thinned);  // fits as it is
  EXPECT_EQ(m.pose_utime.size(), thinned);
  // With room in the gap (10 s), a cap of five fewer poses than the first pass sends doubles the
  // tolerances (d times), and the path is still followed within them.
  omni::trajectory_t again = ToTrajectoryMessage(path, "map", "rbpf", TrajectoryThinning{0, 0, 0});
  ASSERT_EQ(again.pose_utime.size(), path.size());
  TrajectoryThinning wide = th;
  wide.max_gap_us = 10000000;
  const size_t thinned_wide = ToTrajectoryMessage(path, "map", "rbpf", wide).pose_utime.size();
  const int d = ThinTrajectoryMessage(&again, wide, thinned_wide - 5);
  ASSERT_GE(d, 1);
  ASSERT_LE(d, 7);
  EXPECT_LE(again.pose_utime.size(), thinned_wide - 5);
  EXPECT_EQ(again.pose_utime.back(), path.back().utime);
  for (const Stamped& s : path) {
    const Pose2 q = InterpolatedAt(again, s.utime);
    EXPECT_LE(std::hypot(q.x - s.pose.x, q.y - s.pose.y), th.tolerance_m * (1 << d));
  }
  // Nothing fits in 10 poses within a 1 s gap over 33 s: every k-th pose, the newest included.
  omni::trajectory_t capped = ToTrajectoryMessage(path, "map", "rbpf");
  EXPECT_EQ(ThinTrajectoryMessage(&capped, th, 10), -1);
  EXPECT_LE(capped.num_poses, 10);
  EXPECT_GE(capped.num_poses, 5);
  EXPECT_EQ(capped.num_poses, static_cast<int32_t>(capped.pose_utime.size()));
  EXPECT_EQ(capped.pose_utime.back(), path.back().utime);
  EXPECT_DOUBLE_EQ(capped.x_m.back(), path.back().pose.x);
  EXPECT_EQ(capped.pose_utime.front(), path.front().utime);
  for (size_t cap : {1, 2, 3}) {
    omni::trajectory_t tiny = ToTrajectoryMessage(path, "map", "rbpf");
    EXPECT_EQ(ThinTrajectoryMessage(&tiny, th, cap), -1);
    ASSERT_EQ(tiny.pose_utime.size(), cap);
    EXPECT_EQ(tiny.pose_utime.back(), path.back().utime);
    if (cap > 1) {
      EXPECT_EQ(tiny.pose_utime.front(), path.front().utime);
    }
  }
  // No cap: the first pass as it is. Nothing to thin in none, one or two poses.
  omni::trajectory_t uncapped = ToTrajectoryMessage(path, "map", "rbpf");
  EXPECT_EQ(ThinTrajectoryMessage(&uncapped, th, 0), 0);
  EXPECT_EQ(uncapped.pose_utime.size(), thinned);
  for (size_t n : {0, 1, 2}) {
    const std::vector<Stamped> few(path.begin(), path.begin() + static_cast<std::ptrdiff_t>(n));
    const omni::trajectory_t f = ToTrajectoryMessage(few, "map", "rbpf", th, 1);
    EXPECT_EQ(f.pose_utime.size(), std::min<size_t>(n, 1));
  }

  std::vector<Stamped> repeated = {
      {10, Pose2(0, 0, 0)}, {20, Pose2(1, 0, 0)}, {20, Pose2(2, 0, 0)}, {30, Pose2(3, 0, 0)}};
  auto once = ToTrajectoryMessage(repeated, "map", "rbpf");
  ASSERT_EQ(once.num_poses, 3);  // 0, 2, 3 m at 10, 20, 30 µs: 2 m is not on the line
  EXPECT_EQ(once.pose_utime, (std::vector<int64_t>{10, 20, 30}));
  EXPECT_DOUBLE_EQ(once.x_m[1], 2.0);
}

// The wall clock set back a minute (NTP stepping it at boot): heartbeats go on at their period
// from the step instead of stopping for the minute (the supervisor would have restarted every
// process), and the uptime neither goes negative nor stalls.
TEST(Bus, HeartbeatGoesOnWhenTheClockIsSetBack) {
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  std::vector<omni::heartbeat_t> got;
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { got.push_back(m); });
  ManualClock clock(100'000'000);
  Heartbeat hb(bus->get(), "tester", &clock);
  ASSERT_TRUE(hb.Tick());
  clock.Advance(1'000'000);
  ASSERT_TRUE(hb.Tick());
  clock.Set(41'000'000);  // 60 s back
  EXPECT_TRUE(hb.Tick()) << "the step back is not a wait of 60 s";
  clock.Advance(500'000);
  EXPECT_FALSE(hb.Tick());
  clock.Advance(500'000);
  EXPECT_TRUE(hb.Tick()) << "one period after the step";
  Pump(**bus);
  ASSERT_EQ(got.size(), 4u);
  EXPECT_EQ(got[1].uptime_us, 1'000'000);
  EXPECT_EQ(got[2].uptime_us, 1'000'000);
  EXPECT_EQ(got[3].uptime_us, 2'000'000);
}

// A map save request reaches the processes it names (or all), each writes where it was asked
// (its --out by default; DIR/<process> when every mapper is asked) and answers with the request's
// number; a folder that cannot be made and a failed write are answered as failures and counted.
TEST(MapSave, RequestsAreServedAnsweredAndCounted) {
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  ManualClock clock(5'000'000);
  Heartbeat hb(bus->get(), "rbpf_mapper", &clock);
  const std::string tmp = ::testing::TempDir() + "/map_save_test";
  std::filesystem::remove_all(tmp);
  MapSaveService rbpf(bus->get(), "rbpf_mapper", tmp + "/out/rbpf", &clock, &hb);
  MapSaveService pg(bus->get(), "pose_graph_mapper", tmp + "/out/pg", &clock);
  std::vector<omni::map_save_reply_t> replies;
  (*bus)->Subscribe<omni::map_save_reply_t>(
      kMapSaveReplyChannel,
      [&](const omni::map_save_reply_t& m, int64_t) { replies.push_back(m); });
  std::vector<std::string> rbpf_dirs, pg_dirs;
  Status pg_result = Status::Ok();
  auto serve = [&] {
    Pump(**bus);
    rbpf.Serve([&](const std::string& d) {
      rbpf_dirs.push_back(d);
      return Status::Ok();
    });
    pg.Serve([&](const std::string& d) {
      pg_dirs.push_back(d);
      return pg_result;
    });
    Pump(**bus);
  };
  auto request = [&](int64_t seq, const std::string& process, const std::string& dir) {
    omni::map_save_request_t r{};
    r.seq = seq;
    r.process = process;
    r.directory = dir;
    ASSERT_TRUE((*bus)->Publish(kMapSaveChannel, r));
  };
  // One process, its own folder.
  request(1, "rbpf_mapper", tmp + "/a");
  serve();
  ASSERT_EQ(replies.size(), 1u);
  EXPECT_EQ(replies[0].seq, 1);
  EXPECT_EQ(replies[0].process, "rbpf_mapper");
  EXPECT_TRUE(replies[0].ok);
  EXPECT_EQ(replies[0].directory, tmp + "/a");
  EXPECT_EQ(replies[0].utime, 5'000'000);
  EXPECT_TRUE(std::filesystem::is_directory(tmp + "/a")) << "the folder is made first";
  EXPECT_TRUE(pg_dirs.empty());
  // Every mapper: each in its own subfolder; the pose graph's write fails.
  pg_result = MakeError(ErrorCode::kIo, "disk full");
  request(2, "", tmp + "/all");
  serve();
  ASSERT_EQ(replies.size(), 3u);
  ASSERT_EQ(rbpf_dirs.size(), 2u);
  EXPECT_EQ(rbpf_dirs[1], tmp + "/all/rbpf_mapper");
  ASSERT_EQ(pg_dirs.size(), 1u);
  EXPECT_EQ(pg_dirs[0], tmp + "/all/pose_graph_mapper");
  for (size_t i = 1; i < 3; ++i) {
    EXPECT_EQ(replies[i].seq, 2);
    EXPECT_EQ(replies[i].ok, replies[i].process == "rbpf_mapper") << replies[i].process;
    if (!replies[i].ok) {
      EXPECT_EQ(replies[i].message, "disk full");
    }
  }
  // No folder: the process's default (its --out); a folder that cannot be made is an error
  // before anything is written.
  pg_result = Status::Ok();
  request(3, "pose_graph_mapper", "");
  request(4, "rbpf_mapper", "/proc/omni-cannot-be-made");
  serve();
  ASSERT_EQ(replies.size(), 5u);
  ASSERT_EQ(pg_dirs.size(), 2u);
  EXPECT_EQ(pg_dirs[1], tmp + "/out/pg");
  EXPECT_EQ(rbpf_dirs.size(), 2u) << "nothing written where the folder could not be made";
  for (size_t i = 3; i < 5; ++i) {
    EXPECT_EQ(replies[i].ok, replies[i].seq == 3) << replies[i].seq;
    if (replies[i].seq == 4) {
      EXPECT_NE(replies[i].message.find("cannot create folder"), std::string::npos)
          << replies[i].message;
    }
  }
  EXPECT_EQ(rbpf.saved(), 2);
  EXPECT_EQ(rbpf.failed(), 1);
  EXPECT_EQ(pg.saved(), 1);
  EXPECT_EQ(pg.failed(), 1);
  // The counters ride on the heartbeat.
  std::vector<omni::heartbeat_t> beats;
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { beats.push_back(m); });
  ASSERT_TRUE(hb.Tick(true));
  Pump(**bus);
  ASSERT_EQ(beats.size(), 1u);
  std::map<std::string, int64_t> counters;
  for (int i = 0; i < beats[0].num_counters; ++i)
    counters[beats[0].counter_names[i]] = beats[0].counter_values[i];
  EXPECT_EQ(counters["maps_saved"], 2);
  EXPECT_EQ(counters["map_save_errors"], 1);
}

TEST(Bus, JavaJarHoldsEveryType) {
  const std::string jar = std::string(OMNI_BINARY_DIR) + "/omni_lcmtypes.jar";
  ASSERT_TRUE(std::filesystem::exists(jar)) << jar;
  std::set<std::string> types;
  for (const auto& e :
       std::filesystem::directory_iterator(std::string(OMNI_SOURCE_DIR) + "/common/lcmtypes"))
    if (e.path().extension() == ".lcm") types.insert(e.path().stem().string());
  ASSERT_GE(types.size(), 15u);
  FILE* p = popen(("jar tf '" + jar + "'").c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::set<std::string> classes;
  char line[512];
  while (fgets(line, sizeof(line), p)) {
    std::string s(line);
    while (!s.empty() && (s.back() == '\n' || s.back() == '\r')) s.pop_back();
    classes.insert(s);
  }
  ASSERT_EQ(pclose(p), 0);
  for (const auto& t : types)
    EXPECT_TRUE(classes.count("omni/" + t + ".class")) << t << " missing from the jar";
}

// lcm-gen's decoders size an array from its count before checking it against the bytes: a
// negative count throws. On the bus and in a log it is an undecodable message, never a crash.
TEST(Bus, AMessageWithANegativeArrayCountIsADecodeErrorNotACrash) {
  omni::laser_scan_t m{};
  m.num_ranges = 3;
  m.ranges_m = {1.f, 2.f, 3.f};
  std::vector<uint8_t> buf(static_cast<size_t>(m.getEncodedSize()));
  m.encode(buf.data(), 0, static_cast<int>(buf.size()));
  // num_ranges is the int32 right after the fixed fields: find it by value and make it -1.
  bool patched = false;
  for (size_t i = 8; i + 4 <= buf.size() && !patched; ++i)
    if (buf[i] == 0 && buf[i + 1] == 0 && buf[i + 2] == 0 && buf[i + 3] == 3) {
      buf[i] = buf[i + 1] = buf[i + 2] = buf[i + 3] = 0xFF;
      patched = true;
    }
  ASSERT_TRUE(patched);
  omni::laser_scan_t out;
  EXPECT_LT(DecodeMessage(&out, buf.data(), static_cast<int>(buf.size())), 0);
  auto bus = Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  int handled = 0;
  (*bus)->Subscribe<omni::laser_scan_t>("LIDAR_SCAN",
                                        [&](const omni::laser_scan_t&, int64_t) { ++handled; });
  ASSERT_TRUE((*bus)->PublishRaw("LIDAR_SCAN", buf.data(), static_cast<int>(buf.size())));
  Pump(**bus);
  EXPECT_EQ(handled, 0);
  EXPECT_EQ((*bus)->counters().decode_errors, 1);
}

// The same decoders would allocate (and zero) whatever an array count claims before looking for
// the bytes, and throw on a string whose length field is 0. The generated headers are patched
// at build time (common/lcmtypes/harden_decoders.cmake; found by fuzzing): a count beyond the
// bytes left and a non-positive string length fail the decode before any allocation.
TEST(Bus, ACountBeyondTheMessageIsRefusedBeforeAnythingIsAllocated) {
  omni::color_image_t m{};
  m.frame = "camera";
  m.width = 2;
  m.height = 1;
  m.data = {1, 2, 3, 4, 5, 6};
  m.size = 6;
  std::vector<uint8_t> buf(static_cast<size_t>(m.getEncodedSize()));
  ASSERT_GT(m.encode(buf.data(), 0, static_cast<int>(buf.size())), 0);
  // `size` is the int32 just before the 6 data bytes at the end: claim 2^31 - 1 bytes.
  const size_t at = buf.size() - 6 - 4;
  ASSERT_EQ(buf[at + 3], 6);
  buf[at] = 0x7F;
  buf[at + 1] = buf[at + 2] = buf[at + 3] = 0xFF;
  omni::color_image_t out;
  EXPECT_EQ(out.decode(buf.data(), 0, static_cast<int>(buf.size())), -1);
  EXPECT_EQ(out.data.capacity(), 0u) << "the claimed 2 GB were allocated before the check";

  // A string length of 0 (LCM counts the terminating NUL, so a real one is >= 1).
  ASSERT_GT(m.encode(buf.data(), 0, static_cast<int>(buf.size())), 0);
  const size_t frame_len = 8 + 8 + 8;  // after the hash, utime and seq
  ASSERT_EQ(buf[frame_len + 3], m.frame.size() + 1);
  buf[frame_len + 3] = 0;
  int rc = 0;
  EXPECT_NO_THROW(rc = out.decode(buf.data(), 0, static_cast<int>(buf.size())));
  EXPECT_EQ(rc, -1);
}

// An LCM log of `n` WHEEL_ODOM events (at 1 s, 2 s, ..., x = 0, 1, ...); returns the size of
// one event (they are all the same size), 0 on failure.
size_t WriteOdometryLog(const std::string& path, int n) {
  auto w = io::LcmLogWriter::Open(path);
  if (!w.ok()) {
    ADD_FAILURE() << w.error().message;
    return 0;
  }
  size_t event_bytes = 0;
  for (int i = 0; i < n; ++i) {
    omni::odometry_t m{};
    m.utime = 1000000 * (i + 1);
    m.x_m = i;
    std::vector<uint8_t> buf(static_cast<size_t>(m.getEncodedSize()));
    m.encode(buf.data(), 0, static_cast<int>(buf.size()));
    if (!w->Write(m.utime, "WHEEL_ODOM", buf.data(), buf.size()).ok()) {
      ADD_FAILURE() << "cannot write " << path;
      return 0;
    }
    event_bytes = 28 + std::string("WHEEL_ODOM").size() + buf.size();
  }
  if (!w->Close().ok()) {
    ADD_FAILURE() << "cannot close " << path;
    return 0;
  }
  return event_bytes;
}

// The offline mappers' reader (ReadSlamLog on an LCM log) on a stream whose reads fail: an I/O
// error, never the end of the log or a truncated tail, also when it happens while skipping a
// corrupt region; a log that really is cut short still ends with `stopped_early`.
TEST(SlamLog, AFailedReadOfAnLcmLogIsAnErrorNotItsEnd) {
  const std::string path = ::testing::TempDir() + "/slam_failing.lcmlog";
  const size_t event_bytes = WriteOdometryLog(path, 5);
  ASSERT_GT(event_bytes, 0u);
  std::string bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  ASSERT_EQ(bytes.size(), 5 * event_bytes);
  const long ev = static_cast<long>(event_bytes);
  auto read = [&](::omni::testing::FailingLog& log, std::vector<double>* xs) {
    SlamLogHandlers h;
    h.scan = [](const SlamScan&) { return true; };
    h.odom = [xs](int64_t, const Pose2& p) { xs->push_back(p.x); };
    return ReadSlamLcmLog(log.Reader(), SlamLogChannels{}, h);
  };
  {  // a read inside the third event fails and the device does not come back
    ::omni::testing::FailingLog log;
    log.bytes = bytes;
    log.fail_from = 2 * ev + 30;
    log.fail_to = 5 * ev;
    std::vector<double> xs;
    auto r = read(log, &xs);
    ASSERT_FALSE(r.ok()) << "a failed read was taken for the end of the log";
    EXPECT_EQ(r.error().code, ErrorCode::kIo) << r.error().message;
    EXPECT_EQ(xs, (std::vector<double>{0.0, 1.0}));
  }
  {  // the second event's sync word is corrupt, and the read fails while skipping to the next
     // (after the whole header was read, so in the scan for the next sync word)
    ::omni::testing::FailingLog log;
    log.bytes = bytes;
    log.bytes[static_cast<size_t>(ev)] = '\x00';
    ASSERT_GT(ev, 40 + 4);
    log.fail_from = ev + 40;
    log.fail_to = 5 * ev;
    std::vector<double> xs;
    auto r = read(log, &xs);
    ASSERT_FALSE(r.ok()) << "a failed read while resynchronising was taken for the end";
    EXPECT_EQ(r.error().code, ErrorCode::kIo) << r.error().message;
    EXPECT_NE(r.error().message.find("byte offset " + std::to_string(ev) + ": read error"),
              std::string::npos)
        << r.error().message;
    EXPECT_EQ(xs, (std::vector<double>{0.0}));
  }
  {  // cut inside the last event: the reading ends there, said so, nothing before it lost
    ::omni::testing::FailingLog log;
    log.bytes = bytes.substr(0, bytes.size() - 5);
    log.failing = false;
    std::vector<double> xs;
    auto r = read(log, &xs);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_FALSE(r->stopped_early.empty());
    EXPECT_EQ(xs, (std::vector<double>{0.0, 1.0, 2.0, 3.0}));
  }
}

TEST(SlamLog, ACorruptRegionOfAnLcmLogIsSkippedAndCounted) {
  const std::string path = ::testing::TempDir() + "/slam_corrupt.lcmlog";
  const size_t event_bytes = WriteOdometryLog(path, 3);
  ASSERT_GT(event_bytes, 0u);
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(static_cast<std::streamoff>(event_bytes));  // the second event's sync word
    f.put('\x00');
  }
  std::vector<double> xs;
  SlamLogHandlers h;
  h.scan = [](const SlamScan&) { return true; };
  h.odom = [&](int64_t, const Pose2& p) { xs.push_back(p.x); };
  auto r = ReadSlamLog(path, SlamLogChannels{}, h);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(xs, (std::vector<double>{0.0, 2.0})) << "the corrupt event is lost, the next is read";
  EXPECT_EQ(r->skipped_bytes, event_bytes);
  EXPECT_TRUE(r->stopped_early.empty());
}

// The offline runners read scans as the live mappers take them: a repeated scan (same seq and
// stamp) once, gaps in seq counted, undecodable messages counted per channel.
TEST(SlamLog, RepeatedAndMissingScansAndBadMessagesAreCounted) {
  const std::string path = ::testing::TempDir() + "/slam_seq.lcmlog";
  {
    auto w = io::LcmLogWriter::Open(path);
    ASSERT_TRUE(w.ok());
    auto scan = [&](int64_t seq, int64_t utime) {
      omni::laser_scan_t m{};
      m.utime = utime;
      m.seq = seq;
      m.num_ranges = 3;
      m.ranges_m = {1.f, 2.f, 3.f};
      std::vector<uint8_t> buf(static_cast<size_t>(m.getEncodedSize()));
      m.encode(buf.data(), 0, static_cast<int>(buf.size()));
      ASSERT_TRUE(w->Write(utime, "LIDAR_SCAN", buf.data(), buf.size()).ok());
    };
    scan(0, 1000000);
    scan(1, 1100000);
    scan(1, 1100000);  // the same scan again
    scan(4, 1400000);  // 2 and 3 missing
    const char junk[5] = {1, 2, 3, 4, 5};
    ASSERT_TRUE(w->Write(1500000, "LIDAR_SCAN", junk, 5).ok());
    ASSERT_TRUE(w->Close().ok());
  }
  std::vector<int64_t> stamps;
  SlamLogHandlers h;
  h.scan = [&](const SlamScan& s) {
    stamps.push_back(s.utime);
    return true;
  };
  h.odom = [](int64_t, const Pose2&) {};
  auto r = ReadSlamLog(path, SlamLogChannels{}, h);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(stamps, (std::vector<int64_t>{1000000, 1100000, 1400000}));
  EXPECT_EQ(r->scans_repeated, 1);
  EXPECT_EQ(r->scans_lost, 2);
  EXPECT_EQ(r->decode_errors, 1);
  EXPECT_EQ(r->decode_errors_by_channel.at("LIDAR_SCAN"), 1);
}

// A scan's sweep ends 5 ms after the odometry written before it (a lidar whose phase drifted
// against the 100 Hz odometry, as the simulator's does after 85 minutes): it is handed over after
// the odometry sample that covers its end, as the live mappers' queues do, so the mapper can undo
// the sweep. A scan stamped far ahead of the odometry, and the scans of a stream whose odometry
// stopped, are not held back for long, a clock set back hands over every scan held first, and
// the scan waiting at the log's end is not lost.
TEST(SlamLog, AScanWaitsForTheOdometryCoveringItsSweep) {
  const std::string path = ::testing::TempDir() + "/slam_hold.lcmlog";
  {
    auto w = io::LcmLogWriter::Open(path);
    ASSERT_TRUE(w.ok());
    auto odom = [&](int64_t utime) {
      omni::odometry_t m{};
      m.utime = utime;
      std::vector<uint8_t> buf(static_cast<size_t>(m.getEncodedSize()));
      m.encode(buf.data(), 0, static_cast<int>(buf.size()));
      ASSERT_TRUE(w->Write(utime, "WHEEL_ODOM", buf.data(), buf.size()).ok());
    };
    auto scan = [&](int64_t seq, int64_t utime) {
      omni::laser_scan_t m{};
      m.utime = utime;
      m.seq = seq;
      m.scan_time_s = 0.1f;
      m.num_ranges = 3;
      m.ranges_m = {1.f, 2.f, 3.f};
      std::vector<uint8_t> buf(static_cast<size_t>(m.getEncodedSize()));
      m.encode(buf.data(), 0, static_cast<int>(buf.size()));
      ASSERT_TRUE(w->Write(utime + 100000, "LIDAR_SCAN", buf.data(), buf.size()).ok());
    };
    for (int64_t t = 1000000; t <= 1200000; t += 10000) {
      odom(t);
      if (t == 1100000) scan(0, 1000000);  // ends at 1.1 s: covered, handed at once
      if (t == 1200000) scan(1, 1105000);  // ends at 1.205 s: waits for 1.21 s
    }
    odom(1210000);
    scan(2, 9000000000);  // hours ahead of the odometry: not held
    odom(1220000);
    scan(3, 1215000);  // the odometry stops here: handed over once a scan 0.5 s newer came
    for (int64_t i = 4; i <= 10; ++i) scan(i, 1315000 + 100000 * (i - 4));  // to 1.915 s
    odom(1230000);  // scan 4 (to 1.415 s) still waits
    odom(1000000);  // the clock set back: every scan held is handed over first
    scan(11, 905000);
    odom(1010000);      // covers scan 11
    scan(12, 1015000);  // waits for odometry that never comes: handed over at the log's end
    ASSERT_TRUE(w->Close().ok());
  }
  std::vector<std::pair<char, int64_t>> order;
  SlamLogHandlers h;
  h.scan = [&](const SlamScan& s) {
    order.emplace_back('s', s.utime);
    return true;
  };
  h.odom = [&](int64_t utime, const Pose2&) { order.emplace_back('o', utime); };
  auto r = ReadSlamLog(path, SlamLogChannels{}, h);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const std::vector<std::pair<char, int64_t>> want = {
      {'o', 1190000}, {'o', 1200000}, {'o', 1210000}, {'s', 1105000}, {'s', 9000000000},
      {'o', 1220000}, {'s', 1215000}, {'o', 1230000}, {'s', 1315000}, {'s', 1415000},
      {'s', 1515000}, {'s', 1615000}, {'s', 1715000}, {'s', 1815000}, {'s', 1915000},
      {'o', 1000000}, {'o', 1010000}, {'s', 905000},  {'s', 1015000}};
  // The first scan, covered when it came, is before all of these.
  ASSERT_GE(order.size(), want.size());
  const std::vector<std::pair<char, int64_t>> tail(order.end() - static_cast<long>(want.size()),
                                                   order.end());
  EXPECT_EQ(tail, want);
  EXPECT_EQ(std::count(order.begin(), order.end(), std::make_pair('s', int64_t{1000000})), 1);
}

// A real map: the ACES building from its corrected log, 5 cm cells.
io::GridMap AcesMap() {
  const std::string path = ::omni::testing::Dataset("carmen-corrected/aces-corrected.log.gz");
  if (path.empty()) return {};
  auto log = io::ReadCarmenLog(path);
  EXPECT_TRUE(log.ok()) << log.error().message;
  if (!log.ok()) return {};
  io::LogOddsGrid grid;
  for (const auto& r : log->records) {
    if (r.kind != io::CarmenRecord::Kind::kLaser) continue;
    grid.IntegrateScan(r.laser.laser_pose, r.laser.ranges_m, r.laser.angle_min_rad,
                       r.laser.angle_increment_rad, r.laser.max_range_m);
  }
  return grid.ToGridMap();
}

TEST(GridMessage, ARealMapGoesCompressedOverTheBusAndComesBackCellForCell) {
  OMNI_REQUIRE_DATASET(path, "carmen-corrected/aces-corrected.log.gz");
  const io::GridMap map = AcesMap();
  ASSERT_GT(map.cells.size(), 500000u);
  auto made = bus::ToGridMessage(map, 42, "rbpf");
  ASSERT_TRUE(made.ok()) << made.error().message;
  const omni::occupancy_grid_t& z = *made;
  EXPECT_EQ(z.encoding, omni::occupancy_grid_t::ENCODING_ZLIB);
  EXPECT_EQ(z.num_cells, static_cast<int32_t>(map.cells.size()));
  EXPECT_EQ(z.num_bytes, static_cast<int32_t>(z.data.size()));
  std::printf("ACES map %d x %d: %zu cells -> %zu bytes of zlib\n", map.width, map.height,
              map.cells.size(), z.data.size());
  EXPECT_LT(z.data.size() * 10, map.cells.size()) << z.data.size();
  auto b = bus::Bus::Create("memq://");
  ASSERT_TRUE(b.ok());
  std::vector<omni::occupancy_grid_t> got;
  (*b)->Subscribe<omni::occupancy_grid_t>(
      "GRID_RBPF", [&](const omni::occupancy_grid_t& g, int64_t) { got.push_back(g); });
  ASSERT_TRUE((*b)->Publish("GRID_RBPF", z));
  while ((*b)->HandleTimeout(0) > 0) {
  }
  ASSERT_EQ(got.size(), 1u);
  auto back = bus::FromGridMessage(got[0]);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->cells, map.cells);
  EXPECT_EQ(back->width, map.width);
  EXPECT_DOUBLE_EQ(back->origin_x_m, map.origin_x_m);
  const omni::occupancy_grid_t raw = *bus::ToGridMessage(map, 42, "rbpf", /*raw=*/true);
  EXPECT_EQ(raw.encoding, omni::occupancy_grid_t::ENCODING_RAW);
  ASSERT_EQ(raw.data.size(), map.cells.size());
  auto back_raw = bus::FromGridMessage(raw);
  ASSERT_TRUE(back_raw.ok()) << back_raw.error().message;
  EXPECT_EQ(back_raw->cells, map.cells);
}

TEST(GridMessage, CorruptOrInconsistentCellsAreErrorsNotMaps) {
  io::GridMap map;
  map.width = 300;
  map.height = 200;
  map.cells.assign(60000, -1);
  for (int c = 40; c < 260; ++c) map.at(c, 100) = 100;  // a wall
  for (int r = 50; r < 150; ++r) map.at(150, r) = 0;
  const omni::occupancy_grid_t good = *bus::ToGridMessage(map, 1, "posegraph");
  ASSERT_EQ(good.encoding, omni::occupancy_grid_t::ENCODING_ZLIB);
  ASSERT_TRUE(bus::FromGridMessage(good).ok());
  auto expect_error = [](const omni::occupancy_grid_t& g, const std::string& says) {
    auto r = bus::FromGridMessage(g);
    ASSERT_FALSE(r.ok()) << says;
    EXPECT_NE(r.error().message.find(says), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find("posegraph"), std::string::npos) << r.error().message;
  };
  auto flipped = good;
  flipped.data[flipped.data.size() / 2] ^= 0x5A;
  expect_error(flipped, "zlib");
  auto cut = good;
  cut.data.resize(cut.data.size() - 4);  // the Adler-32 lost
  cut.num_bytes = static_cast<int32_t>(cut.data.size());
  expect_error(cut, "zlib");
  auto fewer = good;  // inflates to one byte more than the header says
  fewer.width = 299;
  fewer.num_cells = 299 * 200;
  expect_error(fewer, "zlib");
  auto more = good;  // inflates to fewer bytes than the header says
  more.width = 301;
  more.num_cells = 301 * 200;
  expect_error(more, "inflates to 60000 bytes, not 60200");
  auto bomb = good;  // a few bytes claiming 2^28 cells: refused before 256 MB is allocated
  bomb.width = 1 << 14;
  bomb.height = 1 << 14;
  bomb.num_cells = 1 << 28;
  expect_error(bomb, "cannot inflate to 268435456 cells");
  auto unknown = good;
  unknown.encoding = 7;
  expect_error(unknown, "unknown encoding 7");
  auto short_raw = *bus::ToGridMessage(map, 1, "posegraph", true);
  short_raw.data.pop_back();
  short_raw.num_bytes -= 1;
  expect_error(short_raw, "59999 raw bytes for 60000 cells");
  auto count = good;
  count.num_bytes += 1;  // disagrees with the array
  expect_error(count, "inconsistent size");
  auto huge = good;  // refused before anything is allocated
  huge.width = 1 << 15;
  huge.height = 1 << 15;
  huge.num_cells = 1 << 30;
  expect_error(huge, "2^28");
  auto negative = good;  // sizes that multiply out right but are negative
  negative.width = -300;
  negative.height = -200;
  expect_error(negative, "inconsistent size");
  auto one_negative = good;
  one_negative.width = -300;
  one_negative.num_cells = -60000;
  expect_error(one_negative, "inconsistent size");
  auto zero_wide = good;  // no cells, but 60000 bytes of data claimed to be them
  zero_wide.width = 0;
  zero_wide.num_cells = 0;
  expect_error(zero_wide, "zlib");
  // A grid turned in its frame is refused when its axis-aligned copy would outgrow the cap,
  // though the message itself is within it (2^28 cells turned 45 degrees need twice as many).
  EXPECT_FALSE(io::AxisAligned(map, M_PI / 4, 100000).ok());
  EXPECT_TRUE(io::AxisAligned(map, M_PI / 4, 200000).ok());
}

TEST(GridMessage, AnEmptyGridIsAnEmptyMapNotAnError) {
  io::GridMap empty;
  auto g = bus::ToGridMessage(empty, 1, "octomap");
  ASSERT_TRUE(g.ok()) << g.error().message;
  EXPECT_EQ(g->num_cells, 0);
  auto back = bus::FromGridMessage(*g);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->width, 0);
  EXPECT_TRUE(back->cells.empty());
}

// The sender refuses what every receiver would: a grid over the cap, or one whose cells do not
// match its size. PublishGrid sends nothing then and counts it as a publish error.
TEST(GridMessage, TheSenderRefusesAGridNoReceiverWouldTake) {
  io::GridMap over;
  over.width = 1 << 15;  // 2^30 cells claimed; the cap is checked before the cells are
  over.height = 1 << 15;
  auto r = bus::ToGridMessage(over, 1, "fused");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("more than a grid message carries"), std::string::npos)
      << r.error().message;
  io::GridMap mismatched;
  mismatched.width = 10;
  mismatched.height = 10;
  mismatched.cells.assign(99, -1);
  r = bus::ToGridMessage(mismatched, 1, "fused");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("99 cells for 10 x 10"), std::string::npos) << r.error().message;
  mismatched.width = -10;
  mismatched.height = -10;
  mismatched.cells.assign(100, -1);
  EXPECT_FALSE(bus::ToGridMessage(mismatched, 1, "fused").ok());

  auto b = bus::Bus::Create("memq://");
  ASSERT_TRUE(b.ok());
  std::vector<omni::occupancy_grid_t> got;
  (*b)->Subscribe<omni::occupancy_grid_t>(
      "GRID_FUSED", [&](const omni::occupancy_grid_t& g, int64_t) { got.push_back(g); });
  EXPECT_FALSE(bus::PublishGrid(**b, "GRID_FUSED", over, 1, "fused"));
  EXPECT_EQ((*b)->counters().publish_errors.load(), 1);
  io::GridMap fine;
  fine.width = 4;
  fine.height = 3;
  fine.cells.assign(12, 100);
  EXPECT_TRUE(bus::PublishGrid(**b, "GRID_FUSED", fine, 7, "fused", "odom"));
  while ((*b)->HandleTimeout(0) > 0) {
  }
  ASSERT_EQ(got.size(), 1u);  // only the good grid went out
  EXPECT_EQ(got[0].frame, "odom");
  EXPECT_EQ(got[0].num_cells, 12);
  EXPECT_EQ((*b)->counters().publish_errors.load(), 1);
}

}  // namespace
}  // namespace omni::bus
