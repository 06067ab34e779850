// omni-drive: sends the base a command on the bus (BASE_CMD, base_cmd_t), for bring-up on the
// robot and for driving the simulator (`omni-sim --drive bus`).
//
//   omni-drive [--lcm-url URL] [--channel NAME] --vx 0.2 [--vy 0] [--omega 0] [--duration 2]
//   omni-drive [--lcm-url URL] --estop | --clear-faults | --stop
//
// A twist is repeated at --rate (the bridge stops the base when commands go stale, after its
// command_timeout_s, 0.3 s as shipped), then one zero twist ends the motion.
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include "omni/base_cmd_t.hpp"
#include "omni/bus/bus.h"
#include "omni/common/time.h"

namespace {

std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(
      code == 0 ? stdout : stderr,
      "usage: omni-drive [--lcm-url URL] [--channel NAME] [--vx M_S] [--vy M_S] [--omega RAD_S]\n"
      "                  [--duration S] [--rate HZ]\n"
      "       omni-drive [--lcm-url URL] [--channel NAME] --estop | --clear-faults | --stop\n"
      "  Publishes base_cmd_t on NAME (default BASE_CMD): the body twist (x forward, y left,\n"
      "  counter-clockwise; default 0) every 1/HZ s (default 20) for S s (default 1), then a zero\n"
      "  twist; or one e-stop (motors off until --clear-faults), clear-faults or zero twist.\n"
      "  The base bridge clamps the twist to its limits; Ctrl-C stops early (zero twist sent).\n");
  return code;
}

bool ParseNumber(const std::string& v, double* out) {
  char* end = nullptr;
  *out = std::strtod(v.c_str(), &end);
  return !v.empty() && *end == '\0' && std::isfinite(*out);
}

}  // namespace

int main(int argc, char** argv) {
  std::string lcm_url, channel = "BASE_CMD";
  double vx = 0, vy = 0, omega = 0, duration_s = 1.0, rate_hz = 20;
  int8_t mode = omni::base_cmd_t::MODE_TWIST;
  bool twist_given = false, single = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto val = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "omni-drive: %s needs a value\n", a.c_str());
        std::exit(Usage(2));
      }
      return argv[++i];
    };
    auto num = [&](double lo, double hi) {
      const std::string v = val();
      double x = 0;
      if (!ParseNumber(v, &x) || x < lo || x > hi) {
        std::fprintf(stderr, "omni-drive: %s expects a number in [%g, %g], got '%s'\n", a.c_str(),
                     lo, hi, v.c_str());
        std::exit(2);
      }
      return x;
    };
    if (a == "--help" || a == "-h") return Usage(0);
    if (a == "--lcm-url") {
      lcm_url = val();
    } else if (a == "--channel") {
      channel = val();
    } else if (a == "--vx") {
      vx = num(-10, 10);
      twist_given = true;
    } else if (a == "--vy") {
      vy = num(-10, 10);
      twist_given = true;
    } else if (a == "--omega") {
      omega = num(-20, 20);
      twist_given = true;
    } else if (a == "--duration") {
      duration_s = num(0, 3600);
    } else if (a == "--rate") {
      rate_hz = num(1, 1000);
    } else if (a == "--estop") {
      mode = omni::base_cmd_t::MODE_ESTOP;
      single = true;
    } else if (a == "--clear-faults") {
      mode = omni::base_cmd_t::MODE_CLEAR_FAULTS;
      single = true;
    } else if (a == "--stop") {
      single = true;
    } else {
      std::fprintf(stderr, "omni-drive: unknown option '%s'\n", a.c_str());
      return Usage(2);
    }
  }
  if (single && twist_given) {
    std::fprintf(stderr, "omni-drive: --estop, --clear-faults and --stop take no twist\n");
    return 2;
  }
  auto bus = omni::bus::Bus::Create(lcm_url);
  if (!bus.ok()) {
    std::fprintf(stderr, "omni-drive: %s\n", bus.error().message.c_str());
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  int64_t seq = 0;
  auto send = [&](int8_t m, double x, double y, double w) {
    omni::base_cmd_t c{};
    c.utime = omni::SystemClock().NowUtime();
    c.seq = seq++;
    c.mode = m;
    c.vx_m_s = x;
    c.vy_m_s = y;
    c.omega_rad_s = w;
    if (!(*bus)->Publish(channel, c)) {
      std::fprintf(stderr, "omni-drive: publishing on %s failed\n", channel.c_str());
      std::exit(1);
    }
  };
  if (single) {
    send(mode, 0, 0, 0);
    std::printf("omni-drive: sent %s on %s\n",
                mode == omni::base_cmd_t::MODE_ESTOP          ? "e-stop"
                : mode == omni::base_cmd_t::MODE_CLEAR_FAULTS ? "clear-faults"
                                                              : "zero twist",
                channel.c_str());
    return 0;
  }
  const auto start = std::chrono::steady_clock::now();
  const auto period = std::chrono::duration<double>(1.0 / rate_hz);
  int64_t n = 0;
  for (; !g_stop; ++n) {
    const auto at =
        start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(n * period);
    if (std::chrono::duration<double>(at - start).count() >= duration_s) break;
    std::this_thread::sleep_until(at);
    send(omni::base_cmd_t::MODE_TWIST, vx, vy, omega);
  }
  send(omni::base_cmd_t::MODE_TWIST, 0, 0, 0);
  std::printf("omni-drive: sent %lld twists (%.3f, %.3f, %.3f) on %s, then a zero twist%s\n",
              static_cast<long long>(n), vx, vy, omega, channel.c_str(),
              g_stop ? " (interrupted)" : "");
  return 0;
}
