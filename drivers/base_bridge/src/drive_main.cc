// omni-drive: sends the base a command on the bus (BASE_CMD, base_cmd_t), for bring-up on the
// robot and for driving the simulator (`omni-sim --drive bus`).
//
//   omni-drive [--url URL] [--channel NAME] --vx 0.2 [--vy 0] [--omega 0] [--duration 2]
//   omni-drive [--url URL] --estop | --clear-faults | --stop
//   omni-drive [--url URL] --keys        (keyboard teleop, omni/base_bridge/teleop.h)
//
// A twist is repeated at --rate (the bridge stops the base when commands go stale, after its
// command_timeout_s, 0.3 s as shipped), then one zero twist ends the motion.
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include "omni/base_bridge/teleop.h"
#include "omni/base_cmd_t.hpp"
#include "omni/bus/bus.h"
#include "omni/common/cli.h"
#include "omni/common/time.h"

namespace {

std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

// The terminal as it was before --keys made it raw; restored on every way out.
termios g_saved_terminal{};
bool g_restore_terminal = false;
void RestoreTerminal() {
  if (g_restore_terminal) tcsetattr(STDIN_FILENO, TCSANOW, &g_saved_terminal);
  g_restore_terminal = false;
}

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-drive [--url URL] [--channel NAME] [--vx M_S] [--vy M_S] [--omega RAD_S]\n"
      "                  [--duration S] [--rate HZ]\n"
      "       omni-drive [--url URL] [--channel NAME] --estop | --clear-faults | --stop\n"
      "       omni-drive [--url URL] [--channel NAME] --keys [--rate HZ]\n"
      "  Publishes base_cmd_t on NAME (default BASE_CMD): the body twist (x forward, y left,\n"
      "  counter-clockwise; default 0) every 1/HZ s (default 20) for S s (default 1), then a zero\n"
      "  twist; or one e-stop (motors off until --clear-faults), clear-faults or zero twist.\n"
      "  The base bridge clamps the twist to its limits; Ctrl-C stops early (zero twist sent).\n"
      "  --keys: keyboard teleop; the current twist is sent at HZ until you quit:\n  %s",
      omni::base_bridge::TeleopHelp());
}

// Keyboard teleop: the terminal in raw mode (restored on the way out), keys change the twist,
// which is sent every 1 / rate_hz s; stdin that is not a terminal (a pipe) is read as it is,
// and its end quits.
template <typename Send>
int Teleop(const Send& send, double rate_hz, const std::string& channel) {
  if (isatty(STDIN_FILENO) != 0 && tcgetattr(STDIN_FILENO, &g_saved_terminal) == 0) {
    termios raw = g_saved_terminal;
    raw.c_lflag &= static_cast<tcflag_t>(~(ICANON | ECHO | ISIG));
    raw.c_cc[VMIN] = 0;
    raw.c_cc[VTIME] = 0;
    if (tcsetattr(STDIN_FILENO, TCSANOW, &raw) == 0) {
      g_restore_terminal = true;
      std::atexit(RestoreTerminal);  // also on an exit from a failed publish
    }
  }
  std::fprintf(stderr, "omni-drive: teleop on %s\n%s", channel.c_str(),
               omni::base_bridge::TeleopHelp());
  // On a terminal the twist is one line rewritten in place; otherwise one line per change.
  const char* const line_start = isatty(STDERR_FILENO) != 0 ? "\r\x1b[K" : "";
  const char* const line_end = isatty(STDERR_FILENO) != 0 ? "" : "\n";
  const omni::base_bridge::TeleopOptions opt;
  omni::base_bridge::TeleopTwist twist;
  const auto period = std::chrono::duration<double>(1.0 / rate_hz);
  auto next = std::chrono::steady_clock::now();
  int64_t sent = 0;
  bool quit = false;
  while (!quit && !g_stop) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= next) {
      send(omni::base_cmd_t::MODE_TWIST, twist.vx_m_s, twist.vy_m_s, twist.omega_rad_s);
      ++sent;
      next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
      continue;
    }
    pollfd p{STDIN_FILENO, POLLIN, 0};
    const int ms = static_cast<int>(
                       std::chrono::duration_cast<std::chrono::milliseconds>(next - now).count()) +
                   1;
    if (poll(&p, 1, ms) <= 0) continue;
    if (p.revents & (POLLERR | POLLNVAL)) break;  // stdin is gone: stop, do not spin
    if ((p.revents & (POLLIN | POLLHUP)) == 0) continue;
    char buf[64];
    ssize_t n = read(STDIN_FILENO, buf, sizeof(buf));
    if (n <= 0) {  // end of input
      quit = true;
      break;
    }
    // A key like an arrow sends an escape sequence (ESC [ A): not the Esc key that quits. Esc
    // alone is the last byte read with nothing following within 50 ms.
    if (buf[n - 1] == 27) {
      pollfd more{STDIN_FILENO, POLLIN, 0};
      if (poll(&more, 1, 50) > 0 && (more.revents & POLLIN)) {
        char rest[64];
        const ssize_t m = read(STDIN_FILENO, rest, sizeof(rest));
        if (m > 0) {
          --n;  // the ESC starts a sequence whose rest was `rest`: drop both
        }
      }
    }
    for (ssize_t i = 0; i < n && !quit; ++i) {
      if (buf[i] == 27 && i + 1 < n) break;  // an escape sequence: the rest of this read
      switch (omni::base_bridge::ApplyTeleopKey(buf[i], opt, &twist)) {
        case omni::base_bridge::TeleopAction::kEstop:
          send(omni::base_cmd_t::MODE_ESTOP, 0, 0, 0);
          std::fprintf(stderr, "%se-stop sent (c clears faults)\n", line_start);
          break;
        case omni::base_bridge::TeleopAction::kClearFaults:
          send(omni::base_cmd_t::MODE_CLEAR_FAULTS, 0, 0, 0);
          std::fprintf(stderr, "%sclear-faults sent\n", line_start);
          break;
        case omni::base_bridge::TeleopAction::kQuit:
          quit = true;
          break;
        case omni::base_bridge::TeleopAction::kTwist:
          std::fprintf(stderr, "%svx %+.2f m/s  vy %+.2f m/s  omega %+.2f rad/s%s", line_start,
                       twist.vx_m_s, twist.vy_m_s, twist.omega_rad_s, line_end);
          break;
        case omni::base_bridge::TeleopAction::kNone:
          break;
      }
    }
  }
  send(omni::base_cmd_t::MODE_TWIST, 0, 0, 0);
  RestoreTerminal();
  std::printf("\nomni-drive: teleop ended, %lld twists sent, then a zero twist\n",
              static_cast<long long>(sent));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::string lcm_url, channel = "BASE_CMD";
  double vx = 0, vy = 0, omega = 0, duration_s = 1.0, rate_hz = 20;
  int8_t mode = omni::base_cmd_t::MODE_TWIST;
  bool twist_given = false, single = false, keys = false;
  std::string single_flag;  // the one-shot command given (two are refused: which one was meant?)
  auto one_shot = [&](omni::ArgReader& a) {
    if (single && single_flag != a.arg())
      a.Fail(single_flag + " and " + a.arg() + " are two commands; send one at a time");
    single = true;
    single_flag = a.arg();
  };
  omni::ArgReader args(argc, argv, "omni-drive", Usage);
  while (args.Next()) {
    if (args.IsUrl()) {
      lcm_url = args.Value();
    } else if (args.Is("--channel")) {
      channel = args.Value();
    } else if (args.Is("--vx")) {
      vx = args.Number(-10, 10);
      twist_given = true;
    } else if (args.Is("--vy")) {
      vy = args.Number(-10, 10);
      twist_given = true;
    } else if (args.Is("--omega")) {
      omega = args.Number(-20, 20);
      twist_given = true;
    } else if (args.Is("--duration")) {
      duration_s = args.Number(0, 3600);
    } else if (args.Is("--rate")) {
      rate_hz = args.Number(1, 1000);
    } else if (args.Is("--estop")) {
      one_shot(args);
      mode = omni::base_cmd_t::MODE_ESTOP;
    } else if (args.Is("--clear-faults")) {
      one_shot(args);
      mode = omni::base_cmd_t::MODE_CLEAR_FAULTS;
    } else if (args.Is("--stop")) {
      one_shot(args);
    } else if (args.Is("--keys")) {
      keys = true;
    } else {
      args.Unknown();
    }
  }
  if ((single || keys) && twist_given)
    args.Fail("--estop, --clear-faults, --stop and --keys take no twist");
  if (single && keys) args.Fail("--keys is not one command; leave out --estop etc.");
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
  if (keys) return Teleop(send, rate_hz, channel);
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
