// The RPLidar driver against its emulator on a real pseudo-terminal: streaming, garbage,
// device removed and restored, health error, and (as processes) an absent device.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "omni/heartbeat_t.hpp"
#include "omni/io/lcm_log.h"
#include "omni/rplidar/emulator.h"
#include "omni/rplidar/rplidar_node.h"

namespace omni::rplidar {
namespace {

class EmulatorThread {
 public:
  explicit EmulatorThread(std::unique_ptr<RplidarEmulator> e) : emu_(std::move(e)) {
    thread_ = std::thread([this] {
      while (!stop_) {
        {
          std::lock_guard<std::mutex> lock(mu_);
          emu_->Step(MonotonicMicros());
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      }
    });
  }
  ~EmulatorThread() {
    stop_ = true;
    thread_.join();
  }
  template <class F>
  void With(F f) {
    std::lock_guard<std::mutex> lock(mu_);
    f(*emu_);
  }

 private:
  std::unique_ptr<RplidarEmulator> emu_;
  std::mutex mu_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

std::string LinkPath(const std::string& name) {
  return "/tmp/omni_rplidar_e2e_" + std::to_string(getpid()) + "_" + name;
}

struct Harness {
  SystemClock clock;
  std::unique_ptr<bus::Bus> bus;
  std::unique_ptr<RplidarDriver> driver;
  std::unique_ptr<RplidarNode> node;
  std::vector<omni::laser_scan_t> scans;
  std::vector<omni::heartbeat_t> heartbeats;

  Status Start(const std::string& port, const std::string& scan_mode = "standard") {
    auto b = bus::Bus::Create("memq://");
    if (!b.ok()) return b.error();
    bus = std::move(*b);
    bus->Subscribe<omni::laser_scan_t>(
        "LIDAR_SCAN", [this](const omni::laser_scan_t& m, int64_t) { scans.push_back(m); });
    bus->Subscribe<omni::heartbeat_t>(
        "HEARTBEAT", [this](const omni::heartbeat_t& m, int64_t) { heartbeats.push_back(m); });
    DriverOptions d;
    d.port = port;
    d.scan_mode = scan_mode;
    d.data_timeout_s = 0.3;
    d.reconnect_interval_s = 0.1;
    d.reset_wait_s = 0.05;
    NodeOptions n;
    n.mount_x_m = 0.1;
    n.mount_yaw_rad = 0.05;
    driver = std::make_unique<RplidarDriver>(d, &clock);
    Status st = driver->Connect();
    if (!st.ok()) return st;
    node = std::make_unique<RplidarNode>(bus.get(), driver.get(), n, &clock);
    return Status::Ok();
  }
  // Runs the node until `count` more scans arrived or `timeout_s` passed.
  bool RunUntilScans(size_t count, double timeout_s) {
    const size_t target = scans.size() + count;
    const int64_t end = MonotonicMicros() + SecondsToUtime(timeout_s);
    while (scans.size() < target && MonotonicMicros() < end) {
      node->RunOnce(20);
      while (bus->HandleTimeout(0) > 0) {
      }
    }
    return scans.size() >= target;
  }
  void RunFor(double s) {
    const int64_t end = MonotonicMicros() + SecondsToUtime(s);
    while (MonotonicMicros() < end) {
      node->RunOnce(20);
      while (bus->HandleTimeout(0) > 0) {
      }
    }
  }
};

std::unique_ptr<EmulatorThread> StartEmulator(const std::string& link, int model = 0x31) {
  EmulatorOptions o;
  o.link_path = link;
  o.model = model;
  auto e = RplidarEmulator::Create(o);
  if (!e.ok()) {
    ADD_FAILURE() << e.error().message;
    return nullptr;
  }
  return std::make_unique<EmulatorThread>(std::move(*e));
}

// The beam nearest a CCW angle.
float RangeAt(const omni::laser_scan_t& s, double ccw_rad) {
  const long i = std::lround((ccw_rad - s.angle_min_rad) / s.angle_increment_rad);
  return s.ranges_m[static_cast<size_t>((i % s.num_ranges + s.num_ranges) % s.num_ranges)];
}

TEST(RplidarE2E, StreamsRevolutionsInTheStandardConvention) {
  auto emu = StartEmulator(LinkPath("stream"));
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("stream")).ok());
  ASSERT_TRUE(h.RunUntilScans(6, 5.0));
  // The first revolution after the scan starts is complete only from the second start flag on.
  const omni::laser_scan_t& s = h.scans.back();
  EXPECT_EQ(s.num_ranges, 720);
  EXPECT_NEAR(s.angle_increment_rad, -2 * M_PI / 720, 1e-6);  // clockwise, as measured
  EXPECT_GE(s.angle_min_rad, -M_PI - 1e-6);
  EXPECT_LE(s.angle_min_rad, M_PI + 1e-6);
  EXPECT_DOUBLE_EQ(s.sensor_x_m, 0.1);
  EXPECT_DOUBLE_EQ(s.sensor_yaw_rad, 0.05);
  EXPECT_EQ(s.frame, "laser");
  EXPECT_GT(s.scan_time_s, 0.05f);  // 10 Hz: ~0.1 s per revolution
  EXPECT_LT(s.scan_time_s, 0.15f);
  // The emulated room: walls at x = +2.3 m (ahead), y = +1.6 m (left), x = -3.7 m (behind).
  EXPECT_NEAR(RangeAt(s, 0.0), 2.3, 0.02);
  EXPECT_NEAR(RangeAt(s, M_PI / 2), 1.6, 0.02);   // CCW: left
  EXPECT_NEAR(RangeAt(s, -M_PI / 2), 2.4, 0.02);  // right wall at y = -2.4
  EXPECT_NEAR(RangeAt(s, M_PI), 3.7, 0.02);
  for (size_t i = 1; i < h.scans.size(); ++i) {
    EXPECT_EQ(h.scans[i].seq, h.scans[i - 1].seq + 1);
    EXPECT_GT(h.scans[i].utime, h.scans[i - 1].utime);
  }
  EXPECT_EQ(h.driver->parser_counters().checkbit_errors, 0);
  h.RunFor(1.1);
  ASSERT_FALSE(h.heartbeats.empty());
  const auto& hb = h.heartbeats.back();
  EXPECT_EQ(hb.process, "rplidar_driver");
  EXPECT_EQ(hb.state, omni::heartbeat_t::STATE_OK);
  bool has_reconnects = false;
  for (const auto& n : hb.counter_names) has_reconnects |= (n == "reconnects");
  EXPECT_TRUE(has_reconnects);
}

// The process held up between reads (a loaded 2-core machine): each read brings 120 ms of
// samples at once. Stamped with the read's time, a revolution's length came out as 0, 120 or
// 240 ms; put back by the sample period, each scan spans its revolution (100 ms at 10 Hz) and
// scans follow one another by a revolution.
TEST(RplidarE2E, ScansKeepTheirTimingWhenReadsComeLate) {
  auto emu = StartEmulator(LinkPath("late"));
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("late")).ok());
  ASSERT_TRUE(h.RunUntilScans(3, 5.0));
  const size_t first = h.scans.size();
  const int64_t end = MonotonicMicros() + SecondsToUtime(2.0);
  while (MonotonicMicros() < end) {
    std::this_thread::sleep_for(std::chrono::milliseconds(120));
    h.node->RunOnce(0);
    while (h.bus->HandleTimeout(0) > 0) {
    }
  }
  ASSERT_GE(h.scans.size(), first + 10);
  // Medians, and most scans within 25 ms: a loaded machine (a sanitizer build beside other
  // tests) can hold the emulator's thread up too. Stamped at the reads, most came out 0 or
  // 120 ms.
  std::vector<double> lengths, steps;
  for (size_t i = first + 2; i < h.scans.size(); ++i) {
    lengths.push_back(h.scans[i].scan_time_s);
    steps.push_back((h.scans[i].utime - h.scans[i - 1].utime) * 1e-6);
  }
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  auto near = [](const std::vector<double>& v) {
    return std::count_if(v.begin(), v.end(), [](double x) { return std::abs(x - 0.1) < 0.025; });
  };
  EXPECT_NEAR(median(lengths), 0.1, 0.01);
  EXPECT_NEAR(median(steps), 0.1, 0.01);
  EXPECT_GE(near(lengths) * 10, static_cast<long>(lengths.size()) * 8);
  EXPECT_GE(near(steps) * 10, static_cast<long>(steps.size()) * 8);
}

TEST(RplidarE2E, ExpressScanStreams) {
  auto emu = StartEmulator(LinkPath("express"));
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("express"), "express").ok());
  ASSERT_TRUE(h.RunUntilScans(4, 5.0));
  EXPECT_NEAR(RangeAt(h.scans.back(), 0.0), 2.3, 0.03);
  EXPECT_NEAR(RangeAt(h.scans.back(), M_PI / 2), 1.6, 0.03);
  EXPECT_GT(h.driver->parser_counters().capsules, 40);
  EXPECT_EQ(h.driver->parser_counters().checksum_errors, 0);
}

TEST(RplidarE2E, GarbageIsCountedAndCostsNoRevolution) {
  auto emu = StartEmulator(LinkPath("garbage"));
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("garbage")).ok());
  ASSERT_TRUE(h.RunUntilScans(2, 5.0));
  for (int k = 0; k < 5; ++k) {
    emu->With([k](RplidarEmulator& e) { e.InjectGarbage(97, static_cast<uint32_t>(k)); });
    h.RunFor(0.05);
  }
  ASSERT_TRUE(h.RunUntilScans(4, 5.0));
  const auto& c = h.driver->parser_counters();
  EXPECT_GT(c.checkbit_errors + c.angle_jumps + c.bad_angles, 0);
  EXPECT_GE(c.resyncs, 1);
  EXPECT_EQ(h.driver->counters().reconnects, 0) << "garbage must not cost a reconnect";
  EXPECT_NEAR(RangeAt(h.scans.back(), 0.0), 2.3, 0.02);
}

TEST(RplidarE2E, VanishedDeviceIsReconnectedWithoutRestart) {
  auto emu = StartEmulator(LinkPath("vanish"));
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("vanish")).ok());
  ASSERT_TRUE(h.RunUntilScans(2, 5.0));
  emu->With([](RplidarEmulator& e) { e.Vanish(); });
  h.RunFor(0.5);
  EXPECT_EQ(h.driver->state(), DriverState::kDisconnected);
  EXPECT_GT(h.driver->counters().connect_failures, 0) << "retries while the device is away";
  emu->With([](RplidarEmulator& e) { ASSERT_TRUE(e.Restore().ok()); });
  ASSERT_TRUE(h.RunUntilScans(3, 5.0)) << "no scans after the device came back";
  EXPECT_EQ(h.driver->counters().reconnects, 1);
  EXPECT_EQ(h.driver->state(), DriverState::kStreaming);
  // The revolutions missed while it was away (0.5 s and more at 10 Hz) are skipped in the
  // sequence numbers, so the mappers count them lost.
  int64_t largest_step = 0;
  for (size_t i = 1; i < h.scans.size(); ++i)
    largest_step = std::max(largest_step, h.scans[i].seq - h.scans[i - 1].seq);
  EXPECT_GE(largest_step, 5);
  EXPECT_EQ(h.node->revolutions_missed(),
            h.scans.back().seq + 1 - static_cast<int64_t>(h.scans.size()));
}

// A motor that does not turn (an A1 whose adapter has no DTR line, a jammed rotor) under a
// forced scan: samples at one angle, no start flag. No scan can be made; the heartbeat says
// DEGRADED instead of OK, and the samples are counted.
TEST(RplidarE2E, AMotorThatDoesNotTurnMakesTheHeartbeatDegraded) {
  EmulatorOptions o;
  o.link_path = LinkPath("stalled");
  for (int i = 0; i < 64; ++i) {
    const auto node = EncodeStandardSample(42.0, 1500.0, 40, false);
    o.capture.insert(o.capture.end(), node.begin(), node.end());
  }
  auto e = RplidarEmulator::Create(o);
  ASSERT_TRUE(e.ok()) << e.error().message;
  EmulatorThread emu(std::move(*e));
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("stalled")).ok());
  h.RunFor(1.0 + RplidarNode::kNoRevolutionS + 0.3);
  EXPECT_TRUE(h.scans.empty());
  ASSERT_FALSE(h.heartbeats.empty());
  EXPECT_EQ(h.heartbeats.back().state, omni::heartbeat_t::STATE_DEGRADED)
      << h.heartbeats.back().status_text;
  EXPECT_GT(h.driver->parser_counters().samples, 4000);
}

TEST(RplidarE2E, SilentDeviceTimesOutAndIsRestarted) {
  auto emu = StartEmulator(LinkPath("silent"));
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("silent")).ok());
  ASSERT_TRUE(h.RunUntilScans(1, 5.0));
  // The device goes quiet with the port open: only the data timeout can notice.
  emu->With([](RplidarEmulator& e) { e.StopStreaming(); });
  ASSERT_TRUE(h.RunUntilScans(2, 5.0));
  EXPECT_EQ(h.driver->counters().timeouts, 1);
  EXPECT_GE(h.driver->counters().reconnects, 1);
}

TEST(RplidarE2E, HealthErrorTriggersReset) {
  auto emu = StartEmulator(LinkPath("health"));
  ASSERT_TRUE(emu);
  emu->With([](RplidarEmulator& e) { e.SetHealth(kHealthError, 0x8001); });
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("health")).ok());
  EXPECT_EQ(h.driver->counters().health_resets, 1);
  emu->With([](RplidarEmulator& e) { EXPECT_EQ(e.counters().resets, 1); });
  ASSERT_TRUE(h.RunUntilScans(1, 5.0));
}

TEST(RplidarE2E, A1MotorByDtrFailsOnAPtyWithoutHarm) {
  auto emu = StartEmulator(LinkPath("a1"), 0x18);
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(LinkPath("a1")).ok());
  EXPECT_EQ(h.driver->counters().dtr_failures, 1);  // ENOTTY on a pty
  ASSERT_TRUE(h.RunUntilScans(1, 5.0));
}

int RunProcess(const std::string& cmd, std::string* output) {
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return -1;
  char buf[512];
  while (fgets(buf, sizeof(buf), p)) *output += buf;
  const int status = pclose(p);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

const std::string kBin = std::string(OMNI_BINARY_DIR) + "/bin/";
const std::string kConfig = std::string(OMNI_SOURCE_DIR) + "/config/rplidar_driver.yaml";

TEST(RplidarProcess, AbsentDeviceIsAClearErrorAndNonZeroExit) {
  std::string out;
  const int rc = RunProcess(kBin + "omni-rplidar-driver --config " + kConfig +
                                " --port /tmp/omni-no-such-lidar --lcm-url memq://",
                            &out);
  EXPECT_NE(rc, 0);
  EXPECT_NE(out.find("/tmp/omni-no-such-lidar"), std::string::npos) << out;
}

TEST(RplidarProcess, DriverAndEmulatorProcessesWriteScansToALog) {
  const std::string link = LinkPath("proc");
  const std::string log = "/tmp/omni_rplidar_e2e_" + std::to_string(getpid()) + ".lcmlog";
  const pid_t emu = fork();
  ASSERT_GE(emu, 0);
  if (emu == 0) {
    execl((kBin + "omni-rplidar-emulator").c_str(), "omni-rplidar-emulator", "--link", link.c_str(),
          "--duration-s", "4", static_cast<char*>(nullptr));
    _exit(127);
  }
  for (int i = 0; i < 200 && access(link.c_str(), F_OK) != 0; ++i) usleep(10000);
  std::string out;
  const int rc = RunProcess(kBin + "omni-rplidar-driver --config " + kConfig + " --port " + link +
                                " --duration-s 1.5 --lcm-url 'file://" + log + "?mode=w'",
                            &out);
  kill(emu, SIGTERM);
  waitpid(emu, nullptr, 0);
  EXPECT_EQ(rc, 0) << out;
  auto reader = io::LcmLogReader::Open(log);
  ASSERT_TRUE(reader.ok()) << reader.error().message;
  io::LcmLogEvent ev;
  int scans = 0, heartbeats = 0;
  while (true) {
    auto more = reader->Next(&ev);
    ASSERT_TRUE(more.ok()) << more.error().message;
    if (!*more) break;
    if (ev.channel == "LIDAR_SCAN") {
      omni::laser_scan_t m;
      ASSERT_GT(m.decode(ev.data.data(), 0, static_cast<int>(ev.data.size())), 0);
      ++scans;
    }
    heartbeats += ev.channel == "HEARTBEAT";
  }
  unlink(log.c_str());
  EXPECT_GE(scans, 10);  // 10 Hz for 1.5 s
  EXPECT_GE(heartbeats, 1);
}

}  // namespace
}  // namespace omni::rplidar
