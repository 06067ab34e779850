// The IMU driver against its WT901 emulator on a real pseudo-terminal: streaming values that
// match the simulated motion, garbage spliced into frames, device removed and restored, a
// silent device, and (as processes) an absent device, a driver + emulator run with faults, and
// a driver writing its settings into a factory-set device.
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "../../unit/common/test_paths.h"
#include "../tools/run.h"
#include "omni/heartbeat_t.hpp"
#include "omni/imu/emulator.h"
#include "omni/imu/imu_node.h"
#include "omni/io/lcm_log.h"

namespace omni::imu {
namespace {

class EmulatorThread {
 public:
  explicit EmulatorThread(std::unique_ptr<ImuEmulator> e) : emu_(std::move(e)) {
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
  std::unique_ptr<ImuEmulator> emu_;
  std::mutex mu_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

std::string LinkPath(const std::string& name) {
  return "/tmp/omni_imu_e2e_" + std::to_string(getpid()) + "_" + name;
}

EmulatorOptions Motion(const std::string& link) {
  EmulatorOptions o;
  o.link_path = link;
  o.rate_hz = 100;
  o.yaw_rate_rad_s = 0.2;
  o.roll_rad = 0.1;
  o.pitch_rad = -0.05;
  return o;
}

std::unique_ptr<EmulatorThread> StartEmulator(const EmulatorOptions& o) {
  auto e = ImuEmulator::Create(o);
  if (!e.ok()) {
    ADD_FAILURE() << e.error().message;
    return nullptr;
  }
  return std::make_unique<EmulatorThread>(std::move(*e));
}

int64_t Counter(const omni::heartbeat_t& hb, const std::string& name) {
  for (int i = 0; i < hb.num_counters; ++i) {
    if (hb.counter_names[static_cast<size_t>(i)] == name) {
      return hb.counter_values[static_cast<size_t>(i)];
    }
  }
  ADD_FAILURE() << "heartbeat has no counter " << name;
  return -1;
}

struct Harness {
  SystemClock clock;
  std::unique_ptr<bus::Bus> bus;
  std::unique_ptr<ImuDriver> driver;
  std::unique_ptr<ImuNode> node;
  std::vector<omni::imu_t> msgs;
  std::vector<omni::heartbeat_t> heartbeats;

  Status Start(const std::string& port) {
    auto b = bus::Bus::Create("memq://");
    if (!b.ok()) return b.error();
    bus = std::move(*b);
    bus->Subscribe<omni::imu_t>("IMU",
                                [this](const omni::imu_t& m, int64_t) { msgs.push_back(m); });
    bus->Subscribe<omni::heartbeat_t>(
        "HEARTBEAT", [this](const omni::heartbeat_t& m, int64_t) { heartbeats.push_back(m); });
    DriverOptions d;
    d.port = port;
    d.data_timeout_s = 0.4;
    d.reconnect_interval_s = 0.1;
    NodeOptions n;
    driver = std::make_unique<ImuDriver>(d, &clock);
    Status st = driver->Connect();
    if (!st.ok()) return st;
    node = std::make_unique<ImuNode>(bus.get(), driver.get(), n, &clock);
    return Status::Ok();
  }
  void Once() {
    node->RunOnce(20);
    while (bus->HandleTimeout(0) > 0) {
    }
  }
  bool RunUntilMessages(size_t count, double timeout_s) {
    const size_t target = msgs.size() + count;
    const int64_t end = MonotonicMicros() + SecondsToUtime(timeout_s);
    while (msgs.size() < target && MonotonicMicros() < end) Once();
    return msgs.size() >= target;
  }
  void RunFor(double s) {
    const int64_t end = MonotonicMicros() + SecondsToUtime(s);
    while (MonotonicMicros() < end) Once();
  }
};

// Roll, pitch, yaw of a unit quaternion (R = Rz Ry Rx).
std::array<double, 3> Euler(const double q[4]) {
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  return {std::atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
          std::asin(std::clamp(2 * (w * y - z * x), -1.0, 1.0)),
          std::atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))};
}

TEST(ImuE2E, StreamsTheEmulatedMotion) {
  const EmulatorOptions o = Motion(LinkPath("stream"));
  auto emu = StartEmulator(o);
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(o.link_path).ok()) << h.driver->status_text();
  ASSERT_TRUE(h.RunUntilMessages(120, 5.0));
  EXPECT_EQ(h.driver->cycle().types(),
            (std::vector<uint8_t>{kTypeAccel, kTypeGyro, kTypeAngle, kTypeMag, kTypeQuaternion}));
  // Constant parts of the motion: the tilted gravity and the body rates of the yaw rotation.
  const MotionState truth = SimulatedMotion(o, 0);
  for (const omni::imu_t& m : h.msgs) {
    for (size_t i = 0; i < 3; ++i) {
      ASSERT_NEAR(m.linear_acceleration_m_s2[i], truth.accel_m_s2[i], 0.006) << i;
      ASSERT_NEAR(m.angular_velocity_rad_s[i], truth.gyro_rad_s[i], 0.0015) << i;
    }
    const auto e = Euler(m.orientation_wxyz);
    ASSERT_NEAR(e[0], 0.1, 1e-3);
    ASSERT_NEAR(e[1], -0.05, 1e-3);
    ASSERT_EQ(m.frame, "imu");
    ASSERT_TRUE(std::isnan(m.magnetic_field_t[0]));
    ASSERT_NEAR(m.temperature_c, 25.0, 0.01);
    ASSERT_GT(m.orientation_covariance[0], 0);
  }
  // The yaw turns at 0.2 rad/s: compare over the run, by the message stamps.
  const omni::imu_t& a = h.msgs[10];
  const omni::imu_t& b = h.msgs.back();
  const double dt = UtimeToSeconds(b.utime - a.utime);
  const double dyaw =
      std::remainder(Euler(b.orientation_wxyz)[2] - Euler(a.orientation_wxyz)[2], 2 * M_PI);
  ASSERT_GT(dt, 0.8);
  EXPECT_NEAR(dyaw / dt, 0.2, 0.02);
  for (size_t i = 1; i < h.msgs.size(); ++i) {
    ASSERT_EQ(h.msgs[i].seq, h.msgs[i - 1].seq + 1);
    ASSERT_GT(h.msgs[i].utime, h.msgs[i - 1].utime);
  }
  EXPECT_EQ(h.driver->frame_counters().checksum_errors, 0);
  EXPECT_EQ(h.driver->counters().dropped_frames, 0);
  h.RunFor(1.1);
  ASSERT_FALSE(h.heartbeats.empty());
  const auto& hb = h.heartbeats.back();
  EXPECT_EQ(hb.process, "imu_driver");
  EXPECT_EQ(hb.state, omni::heartbeat_t::STATE_OK);
  EXPECT_GT(Counter(hb, "messages"), 120);
  for (const char* c : {"checksum_errors", "resyncs", "reconnects", "timeouts", "dropped_frames"}) {
    EXPECT_EQ(Counter(hb, c), 0) << c;
  }
}

TEST(ImuE2E, GarbageCostsOnlyTheCorruptedFrames) {
  const EmulatorOptions o = Motion(LinkPath("garbage"));
  auto emu = StartEmulator(o);
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(o.link_path).ok()) << h.driver->status_text();
  ASSERT_TRUE(h.RunUntilMessages(20, 5.0));
  // Quiesce (no byte in flight), count, stream with garbage, quiesce and count again.
  auto quiet = [&](int64_t* frames_sent, int64_t* periods_sent) {
    emu->With([](ImuEmulator& e) { e.SetStreaming(false); });
    h.RunFor(0.15);  // < data_timeout_s: not a silence
    emu->With([&](ImuEmulator& e) {
      *frames_sent = e.counters().frames;
      *periods_sent = e.counters().periods;
    });
  };
  int64_t f0 = 0, p0 = 0, f1 = 0, p1 = 0;
  quiet(&f0, &p0);
  const int64_t got0 = h.driver->frame_counters().frames;
  const size_t msgs0 = h.msgs.size();
  emu->With([](ImuEmulator& e) { e.SetStreaming(true); });
  constexpr int kInjections = 6;
  for (int k = 0; k < kInjections; ++k) {
    h.RunFor(0.05);
    emu->With([k](ImuEmulator& e) { e.InjectGarbage(20 + 13 * k, static_cast<uint32_t>(k)); });
  }
  h.RunFor(0.1);
  quiet(&f1, &p1);
  // Injections that reach the emulator before its next period share one cut frame.
  int64_t cut = 0;
  emu->With([&](ImuEmulator& e) { cut = e.counters().frames_corrupted; });
  EXPECT_GE(cut, kInjections / 2);
  EXPECT_LE(cut, kInjections);
  const auto& c = h.driver->frame_counters();
  EXPECT_EQ(c.frames - got0, (f1 - f0) - cut) << "only the corrupted frames are lost";
  EXPECT_EQ(h.driver->counters().dropped_frames, cut);
  EXPECT_EQ(c.resyncs, cut);
  EXPECT_GT(c.bytes_skipped, 0);
  EXPECT_GE(c.checksum_errors, 1);
  const int64_t msgs = static_cast<int64_t>(h.msgs.size() - msgs0);
  EXPECT_LE(msgs, p1 - p0);
  EXPECT_GE(msgs, p1 - p0 - cut) << "a lost frame costs at most its own sample";
  EXPECT_EQ(h.driver->counters().reconnects, 0) << "garbage must not cost a reconnect";
  EXPECT_EQ(h.driver->counters().timeouts, 0);
  // Values after the noise are still right.
  emu->With([](ImuEmulator& e) { e.SetStreaming(true); });
  ASSERT_TRUE(h.RunUntilMessages(5, 2.0));
  EXPECT_NEAR(h.msgs.back().linear_acceleration_m_s2[2], SimulatedMotion(o, 0).accel_m_s2[2],
              0.006);
  h.RunFor(1.05);
  ASSERT_FALSE(h.heartbeats.empty());
  EXPECT_EQ(Counter(h.heartbeats.back(), "dropped_frames"), cut);
  EXPECT_EQ(Counter(h.heartbeats.back(), "resyncs"), cut);
}

TEST(ImuE2E, VanishedDeviceIsReconnectedWithoutRestart) {
  const EmulatorOptions o = Motion(LinkPath("vanish"));
  auto emu = StartEmulator(o);
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(o.link_path).ok()) << h.driver->status_text();
  ASSERT_TRUE(h.RunUntilMessages(20, 5.0));
  emu->With([](ImuEmulator& e) { e.Vanish(); });
  h.RunFor(0.5);
  EXPECT_EQ(h.driver->state(), DriverState::kDisconnected);
  EXPECT_GT(h.driver->counters().connect_failures, 0) << "retries while the device is away";
  EXPECT_EQ(h.driver->counters().timeouts, 0) << "a hang-up is seen at once, not by timeout";
  h.RunFor(1.05);
  ASSERT_FALSE(h.heartbeats.empty());
  EXPECT_EQ(h.heartbeats.back().state, omni::heartbeat_t::STATE_ERROR);
  EXPECT_NE(h.heartbeats.back().status_text.find(o.link_path), std::string::npos)
      << h.heartbeats.back().status_text;
  emu->With([](ImuEmulator& e) { ASSERT_TRUE(e.Restore().ok()); });
  ASSERT_TRUE(h.RunUntilMessages(20, 5.0)) << "no samples after the device came back";
  EXPECT_EQ(h.driver->counters().reconnects, 1);
  EXPECT_EQ(h.driver->state(), DriverState::kStreaming);
  const size_t n = h.heartbeats.size();
  h.RunFor(1.05);
  ASSERT_GT(h.heartbeats.size(), n);
  EXPECT_EQ(h.heartbeats.back().state, omni::heartbeat_t::STATE_OK);
  EXPECT_EQ(Counter(h.heartbeats.back(), "reconnects"), 1);
}

TEST(ImuE2E, SilentDeviceTimesOutAndIsReopened) {
  const EmulatorOptions o = Motion(LinkPath("silent"));
  auto emu = StartEmulator(o);
  ASSERT_TRUE(emu);
  Harness h;
  ASSERT_TRUE(h.Start(o.link_path).ok()) << h.driver->status_text();
  ASSERT_TRUE(h.RunUntilMessages(10, 5.0));
  // Quiet with the port open: only the data timeout can notice.
  emu->With([](ImuEmulator& e) { e.SetStreaming(false); });
  h.RunFor(0.7);
  EXPECT_EQ(h.driver->counters().timeouts, 1);
  EXPECT_NE(h.driver->state(), DriverState::kStreaming);
  emu->With([](ImuEmulator& e) { e.SetStreaming(true); });
  ASSERT_TRUE(h.RunUntilMessages(10, 5.0));
  EXPECT_GE(h.driver->counters().reconnects, 1);
  EXPECT_EQ(h.driver->state(), DriverState::kStreaming);
}

// ---------------------------------------------------------------------------------------------
// As processes.

const std::string kConfig = std::string(OMNI_SOURCE_DIR) + "/config/imu_driver.yaml";

// Starts omni-imu-emulator serving `link`, with `args` after --link. With `control`, the
// emulator's stdin is a pipe whose write end is returned there (for Tell); otherwise /dev/null.
// Waits up to 3 s for the link to appear. Returns the child's pid, or -1.
pid_t SpawnEmulator(const std::string& link, const std::vector<std::string>& args, int* control) {
  const std::string bin = ::omni::testing::Bin("omni-imu-emulator");
  std::vector<std::string> words = {"omni-imu-emulator", "--link", link};
  words.insert(words.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& w : words) argv.push_back(w.data());
  argv.push_back(nullptr);
  int to_emu[2] = {-1, -1};
  if (control != nullptr && pipe(to_emu) != 0) return -1;
  const pid_t pid = fork();
  if (pid == 0) {
    const int null = open("/dev/null", O_RDWR);
    dup2(control != nullptr ? to_emu[0] : null, 0);
    dup2(null, 1);
    if (control != nullptr) {
      close(to_emu[0]);
      close(to_emu[1]);
    }
    execv(bin.c_str(), argv.data());
    _exit(127);
  }
  if (control != nullptr) {
    close(to_emu[0]);
    if (pid < 0) {
      close(to_emu[1]);
    } else {
      *control = to_emu[1];
    }
  }
  for (int i = 0; pid > 0 && i < 300 && access(link.c_str(), F_OK) != 0; ++i) usleep(10000);
  return pid;
}

// One line of the emulator's stdin command language ("garbage 40", "vanish 500", "quit").
void Tell(int control, const std::string& line) {
  const std::string l = line + "\n";
  (void)!write(control, l.data(), l.size());
}

// What a driver wrote to its LCM log: IMU messages (each passed to `on_imu`) and heartbeats.
struct DriverLog {
  int imu = 0;
  int heartbeats = 0;
  omni::heartbeat_t last_hb;
};
DriverLog ReadDriverLog(const std::string& path,
                        const std::function<void(const omni::imu_t&)>& on_imu = {}) {
  DriverLog out;
  auto reader = io::LcmLogReader::Open(path);
  if (!reader.ok()) {
    ADD_FAILURE() << reader.error().message;
    return out;
  }
  io::LcmLogEvent ev;
  while (true) {
    auto more = reader->Next(&ev);
    if (!more.ok()) {
      ADD_FAILURE() << more.error().message;
      break;
    }
    if (!*more) break;
    if (ev.channel == "IMU") {
      omni::imu_t m;
      if (m.decode(ev.data.data(), 0, static_cast<int>(ev.data.size())) <= 0) {
        ADD_FAILURE() << "undecodable IMU message in " << path;
        continue;
      }
      if (on_imu) on_imu(m);
      ++out.imu;
    } else if (ev.channel == "HEARTBEAT") {
      if (out.last_hb.decode(ev.data.data(), 0, static_cast<int>(ev.data.size())) <= 0) {
        ADD_FAILURE() << "undecodable heartbeat in " << path;
        continue;
      }
      ++out.heartbeats;
    }
  }
  return out;
}

TEST(ImuProcess, AbsentDeviceIsAClearErrorAndNonZeroExit) {
  const auto r = ::omni::testing::Run(::omni::testing::Bin("omni-imu-driver") + " --config " +
                                      kConfig + " --port /tmp/omni-no-such-imu --lcm-url memq://");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("/tmp/omni-no-such-imu"), std::string::npos) << r.output;
}

TEST(ImuProcess, HelpAndBadOptions) {
  for (const char* bin : {"omni-imu-driver", "omni-imu-emulator"}) {
    auto r = ::omni::testing::Run(::omni::testing::Bin(bin) + " --help");
    EXPECT_EQ(r.exit_code, 0) << bin;
    EXPECT_NE(r.output.find("usage"), std::string::npos) << r.output;
    r = ::omni::testing::Run(::omni::testing::Bin(bin) + " --bogus");
    EXPECT_NE(r.exit_code, 0) << bin;
  }
  const auto r = ::omni::testing::Run(::omni::testing::Bin("omni-imu-driver") +
                                      " --config /tmp/omni-no-such-imu-config.yaml");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("omni-no-such-imu-config.yaml"), std::string::npos) << r.output;
}

TEST(ImuProcess, DriverAndEmulatorProcessesSurviveGarbageAndUnplug) {
  const std::string dir = ::omni::testing::TempDir();
  const std::string link = dir + "/imu";
  const std::string log = dir + "/imu.lcmlog";
  const std::string config = dir + "/imu_driver.yaml";
  {
    std::ofstream c(config);
    c << "port: /dev/imu\nbaud: 115200\ndata_timeout_s: 0.3\nreconnect_interval_s: 0.1\n";
  }
  int control = -1;
  const pid_t emu = SpawnEmulator(link, {"--duration-s", "8"}, &control);
  ASSERT_GT(emu, 0);
  // Faults while the driver runs: garbage at 0.6 s, unplugged for 0.5 s at 1.2 s.
  std::thread faults([control] {
    usleep(600000);
    Tell(control, "garbage 40");
    usleep(600000);
    Tell(control, "vanish 500");
  });
  const auto r = ::omni::testing::Run(::omni::testing::Bin("omni-imu-driver") + " --config " +
                                      config + " --port " + link +
                                      " --duration-s 3.5 --lcm-url 'file://" + log + "?mode=w'");
  faults.join();
  Tell(control, "quit");
  close(control);
  int status = 0;
  waitpid(emu, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int off_gravity = 0;
  const DriverLog got = ReadDriverLog(log, [&](const omni::imu_t& m) {
    if (std::fabs(m.linear_acceleration_m_s2[2] - kGravity) > 0.01) ++off_gravity;
  });
  EXPECT_EQ(off_gravity, 0) << "IMU messages whose vertical acceleration is not gravity";
  const int imu = got.imu;
  const omni::heartbeat_t& last_hb = got.last_hb;
  // 100 Hz for 3.5 s, minus about 0.6 s unplugged and reconnecting.
  EXPECT_GE(imu, 200);
  EXPECT_LE(imu, 360);
  ASSERT_GE(got.heartbeats, 2);
  EXPECT_EQ(last_hb.process, "imu_driver");
  EXPECT_EQ(last_hb.state, omni::heartbeat_t::STATE_STOPPING);
  EXPECT_EQ(Counter(last_hb, "messages"), imu);
  EXPECT_EQ(Counter(last_hb, "reconnects"), 1);
  EXPECT_EQ(Counter(last_hb, "dropped_frames"), 1);
  EXPECT_GE(Counter(last_hb, "resyncs"), 1);
  EXPECT_GT(Counter(last_hb, "connect_failures"), 0);
}

TEST(ImuProcess, DriverSetsAFactoryDeviceToItsConfiguredRateAndBaud) {
  const std::string dir = ::omni::testing::TempDir();
  const std::string link = dir + "/imu_factory";
  const std::string log = dir + "/imu_factory.lcmlog";
  const std::string config = dir + "/imu_configure.yaml";
  {
    std::ofstream c(config);
    c << "port: /dev/imu\nbaud: 9600\nrate_hz: 100\ndata_timeout_s: 0.3\n"
         "reconnect_interval_s: 0.1\nmag_tesla_per_lsb: 1e-7\nconfigure:\n  enabled: true\n"
         "  baud: 115200\n  outputs: [accel, gyro, angle, quaternion]\n  command_gap_ms: 20\n";
  }
  const pid_t emu =
      SpawnEmulator(link, {"--baud", "9600", "--rate-hz", "10", "--duration-s", "8"}, nullptr);
  ASSERT_GT(emu, 0);
  const auto r = ::omni::testing::Run(::omni::testing::Bin("omni-imu-driver") + " --config " +
                                      config + " --port " + link +
                                      " --duration-s 3 --lcm-url 'file://" + log + "?mode=w'");
  kill(emu, SIGTERM);
  int status = 0;
  waitpid(emu, &status, 0);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int off_gravity = 0, with_mag = 0;
  const DriverLog got = ReadDriverLog(log, [&](const omni::imu_t& m) {
    if (std::fabs(m.linear_acceleration_m_s2[2] - kGravity) > 0.01) ++off_gravity;
    // The factory device sends magnetometer frames; the outputs written turned them off.
    if (!std::isnan(m.magnetic_field_t[0])) ++with_mag;
  });
  EXPECT_EQ(off_gravity, 0) << "IMU messages whose vertical acceleration is not gravity";
  EXPECT_EQ(with_mag, 0) << "IMU messages still carrying the magnetometer";
  const int imu = got.imu;
  const omni::heartbeat_t& last_hb = got.last_hb;
  // The driver's 3 s at 100 Hz (10 Hz would give 30), less the connection and the writes.
  EXPECT_GE(imu, 180) << r.output;
  EXPECT_LE(imu, 320);
  EXPECT_EQ(Counter(last_hb, "configurations"), 1) << r.output;
  EXPECT_EQ(Counter(last_hb, "config_failures"), 0);
  EXPECT_EQ(Counter(last_hb, "reconnects"), 0);
  EXPECT_NEAR(static_cast<double>(Counter(last_hb, "measured_rate_hz")), 100.0, 15.0);
  EXPECT_EQ(Counter(last_hb, "rate_mismatches"), 0);
  EXPECT_NE(r.output.find("settings confirmed"), std::string::npos) << r.output;
}

TEST(ImuProcess, SetupWritesAndSavesTheSettingsOnce) {
  const std::string dir = ::omni::testing::TempDir();
  const std::string link = dir + "/imu_setup";
  const std::string log = dir + "/imu_setup.lcmlog";
  const std::string setup_config = dir + "/imu_setup.yaml";
  const std::string run_config = dir + "/imu_run.yaml";
  {
    std::ofstream c(setup_config);
    c << "port: /dev/imu\nbaud: 9600\nrate_hz: 50\ndata_timeout_s: 0.3\n"
         "reconnect_interval_s: 0.1\nconfigure:\n  baud: 115200\n  command_gap_ms: 20\n";
    std::ofstream r(run_config);  // what --setup advises: the new baud, no configure
    r << "port: /dev/imu\nbaud: 115200\nrate_hz: 50\ndata_timeout_s: 0.3\n"
         "reconnect_interval_s: 0.1\n";
  }
  int control = -1;
  const pid_t emu =
      SpawnEmulator(link, {"--baud", "9600", "--rate-hz", "10", "--duration-s", "12"}, &control);
  ASSERT_GT(emu, 0);
  const auto setup = ::omni::testing::Run(::omni::testing::Bin("omni-imu-driver") + " --config " +
                                          setup_config + " --port " + link + " --setup");
  EXPECT_EQ(setup.exit_code, 0) << setup.output;
  EXPECT_NE(setup.output.find("set and saved: 50 Hz at 115200 baud"), std::string::npos)
      << setup.output;
  // Unplugged and back: the device powers up with what was saved.
  Tell(control, "vanish 300");
  usleep(600000);
  const auto r = ::omni::testing::Run(::omni::testing::Bin("omni-imu-driver") + " --config " +
                                      run_config + " --port " + link +
                                      " --duration-s 2.5 --lcm-url 'file://" + log + "?mode=w'");
  Tell(control, "quit");
  close(control);
  int status = 0;
  waitpid(emu, &status, 0);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const DriverLog got = ReadDriverLog(log);
  const int imu = got.imu;
  const omni::heartbeat_t& last_hb = got.last_hb;
  EXPECT_GE(imu, 100) << r.output;  // 50 Hz for 2.5 s (10 Hz unsaved would give 25)
  EXPECT_EQ(Counter(last_hb, "configurations"), 0);
  EXPECT_NEAR(static_cast<double>(Counter(last_hb, "measured_rate_hz")), 50.0, 8.0);
  // A rate the device cannot be set to is refused before anything is written.
  {
    std::ofstream c(setup_config);
    c << "port: /dev/imu\nrate_hz: 30\ndata_timeout_s: 1\n";
  }
  const auto bad = ::omni::testing::Run(::omni::testing::Bin("omni-imu-driver") + " --config " +
                                        setup_config + " --port " + link + " --setup");
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("rate_hz 30"), std::string::npos) << bad.output;
  // baud: 0 finds a factory device at 9600, which cannot carry 200 Hz of three frames: known
  // only once connected, and refused before anything is saved.
  const std::string factory = dir + "/imu_setup_factory";
  const pid_t emu2 =
      SpawnEmulator(factory, {"--baud", "9600", "--rate-hz", "10", "--duration-s", "12"}, nullptr);
  ASSERT_GT(emu2, 0);
  {
    std::ofstream c(setup_config);
    c << "port: /dev/imu\nbaud: 0\nrate_hz: 200\ndata_timeout_s: 1\n";
  }
  const auto unknown_baud =
      ::omni::testing::Run(::omni::testing::Bin("omni-imu-driver") + " --config " + setup_config +
                           " --port " + factory + " --setup");
  kill(emu2, SIGTERM);
  waitpid(emu2, &status, 0);
  EXPECT_NE(unknown_baud.exit_code, 0);
  EXPECT_NE(unknown_baud.output.find("answered at 9600 baud); nothing saved"), std::string::npos)
      << unknown_baud.output;
}

}  // namespace
}  // namespace omni::imu
