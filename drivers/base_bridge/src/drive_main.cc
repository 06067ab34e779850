// omni-drive: sends the base a command on the bus (BASE_CMD, base_cmd_t), for bring-up on the
// robot and for driving the simulator (`omni-sim --drive bus`).
//
//   omni-drive [--url URL] [--channel NAME] --vx 0.2 [--vy 0] [--omega 0] [--duration 2]
//   omni-drive [--url URL] --estop | --clear-faults | --stop
//   omni-drive [--url URL] --keys        (keyboard teleop, omni/base_bridge/teleop.h)
//
// A twist is repeated at --rate (the bridge stops the base when commands go stale, after its
// command_timeout_s, 0.3 s as shipped), then one zero twist ends the motion at --duration.
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#include "omni/base_bridge/teleop.h"
#include "omni/base_cmd_t.hpp"
#include "omni/base_status_t.hpp"
#include "omni/bus/bus.h"
#include "omni/common/cli.h"
#include "omni/common/stop_signals.h"
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
      "       omni-drive [--url URL] [--channel NAME] --estop [--wait S] [--status-channel NAME]\n"
      "       omni-drive [--url URL] [--channel NAME] --clear-faults | --stop\n"
      "       omni-drive [--url URL] [--channel NAME] --keys [--rate HZ] [--key-timeout S]\n"
      "  Publishes base_cmd_t on NAME (default BASE_CMD): the body twist (x forward, y left,\n"
      "  counter-clockwise; default 0) every 1/HZ s (default 20, at least 5: the bridge stops a\n"
      "  base whose twist is older than its 0.3 s command timeout) for S s (default 1), then a\n"
      "  zero twist; or an e-stop (motors off until --clear-faults), clear-faults or zero twist,\n"
      "  each sent 5 times 20 ms apart (a lost datagram must not lose it). --estop then waits up\n"
      "  to S s (default 1; 0: no wait) for the bridge's BASE_STATUS to show the e-stop, and\n"
      "  exits 1 saying NOT CONFIRMED if it does not. The bridge clamps the twist to its limits;\n"
      "  Ctrl-C, SIGTERM or a hangup stop early (zero twist sent).\n"
      "  --keys: keyboard teleop, the twist sent at HZ until you quit; with no key for S s\n"
      "  (--key-timeout, default 0.75; 0: the twist holds until space) the base stops:\n  %s",
      omni::base_bridge::TeleopHelp());
}

// Keyboard teleop: the terminal in raw mode (restored on the way out); a held direction key
// moves the base, and the twist (zero once keys stop coming: TeleopOptions::key_timeout_s) is
// sent every 1 / rate_hz s; while e-stopped the e-stop itself is repeated instead, so one lost
// datagram cannot leave the base running. Stdin that is not a terminal (a pipe) is read as it
// is, and its end quits.
template <typename Send>
int Teleop(const Send& send, double rate_hz, double key_timeout_s, const std::string& channel) {
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
  omni::base_bridge::TeleopOptions opt;
  opt.key_timeout_s = key_timeout_s;
  omni::base_bridge::TeleopState state(opt);
  omni::base_bridge::TeleopKeyReader reader;
  const auto t0 = std::chrono::steady_clock::now();
  auto now_s = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  };
  const auto period = std::chrono::duration<double>(1.0 / rate_hz);
  auto next = std::chrono::steady_clock::now();
  int64_t sent = 0;
  bool quit = false;
  std::vector<char> keys;
  auto escape_since = std::chrono::steady_clock::now();  // when the pending ESC came
  while (!quit && !g_stop) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= next) {
      if (state.estopped()) {
        send(omni::base_cmd_t::MODE_ESTOP, 0, 0, 0);
      } else {
        const omni::base_bridge::TeleopTwist t = state.TwistAt(now_s());
        send(omni::base_cmd_t::MODE_TWIST, t.vx_m_s, t.vy_m_s, t.omega_rad_s);
      }
      ++sent;
      if (state.TimedOutNow(now_s()))
        std::fprintf(stderr, "%sno key for %.2f s: stopped (hold a key to move)%s", line_start,
                     key_timeout_s, line_end);
      next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
      if (next < now) next = now;  // a stall (a suspended terminal) is not made up in a burst
      continue;
    }
    pollfd p{STDIN_FILENO, POLLIN, 0};
    int ms = static_cast<int>(
                 std::chrono::duration_cast<std::chrono::milliseconds>(next - now).count()) +
             1;
    // An ESC with nothing after it is the Esc key once 50 ms passed since it came without the
    // rest of a sequence (not at the first timeout, which may be the next send's).
    const auto escape_due = escape_since + std::chrono::milliseconds(50);
    if (reader.escape_pending())
      ms = std::min<int>(
          ms,
          static_cast<int>(std::max<int64_t>(
              0, std::chrono::duration_cast<std::chrono::milliseconds>(escape_due - now).count() +
                     1)));
    const int ready = poll(&p, 1, ms);
    keys.clear();
    if (ready <= 0) {
      if (ready == 0 && reader.escape_pending() && std::chrono::steady_clock::now() >= escape_due)
        reader.Flush(&keys);
      if (keys.empty()) continue;
    } else {
      if (p.revents & (POLLERR | POLLNVAL)) break;  // stdin is gone: stop, do not spin
      if ((p.revents & (POLLIN | POLLHUP)) == 0) continue;
      char buf[64];
      const ssize_t n = read(STDIN_FILENO, buf, sizeof(buf));
      if (n <= 0) {  // end of input
        reader.Flush(&keys);
        quit = true;
      } else {
        const bool was_pending = reader.escape_pending();
        reader.Feed(buf, static_cast<size_t>(n), &keys);
        if (reader.escape_pending() && !was_pending)
          escape_since = std::chrono::steady_clock::now();
      }
    }
    for (char key : keys) {
      const double t = now_s();
      switch (state.Key(key, t)) {
        case omni::base_bridge::TeleopAction::kEstop:
          send(omni::base_cmd_t::MODE_ESTOP, 0, 0, 0);
          std::fprintf(stderr, "%se-stop sent, repeated until c clears faults\n", line_start);
          break;
        case omni::base_bridge::TeleopAction::kClearFaults:
          send(omni::base_cmd_t::MODE_CLEAR_FAULTS, 0, 0, 0);
          std::fprintf(stderr, "%sclear-faults sent (stopped; hold a key to move)\n", line_start);
          break;
        case omni::base_bridge::TeleopAction::kRefused:
          std::fprintf(stderr, "%se-stopped: c clears faults before the base can move%s",
                       line_start, line_end);
          break;
        case omni::base_bridge::TeleopAction::kQuit:
          quit = true;
          break;
        case omni::base_bridge::TeleopAction::kTwist: {
          const omni::base_bridge::TeleopTwist tw = state.TwistAt(t);
          std::fprintf(stderr, "%svx %+.2f m/s  vy %+.2f m/s  omega %+.2f rad/s%s", line_start,
                       tw.vx_m_s, tw.vy_m_s, tw.omega_rad_s, line_end);
          break;
        }
        case omni::base_bridge::TeleopAction::kSpeed:
          std::fprintf(stderr, "%sspeeds %.2f m/s, %.2f rad/s%s", line_start,
                       state.linear_speed_m_s(), state.angular_speed_rad_s(), line_end);
          break;
        case omni::base_bridge::TeleopAction::kNone:
          break;
      }
      if (quit) break;
    }
  }
  if (!state.estopped()) send(omni::base_cmd_t::MODE_TWIST, 0, 0, 0);
  RestoreTerminal();
  std::printf("\nomni-drive: teleop ended, %lld commands sent, then %s\n",
              static_cast<long long>(sent),
              state.estopped() ? "none (the base stays e-stopped)" : "a zero twist");
  return 0;
}

// Sleeps until `until`, in slices, so a signal ends the wait at once. False when stopped.
bool SleepUntil(std::chrono::steady_clock::time_point until) {
  while (!g_stop) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= until) return true;
    std::this_thread::sleep_for(
        std::min<std::chrono::steady_clock::duration>(until - now, std::chrono::milliseconds(10)));
  }
  return false;
}

}  // namespace

int main(int argc, char** argv) {
  std::string lcm_url, channel = "BASE_CMD", status_channel = "BASE_STATUS";
  double vx = 0, vy = 0, omega = 0, duration_s = 1.0, rate_hz = 20, wait_s = 1.0;
  double key_timeout_s = omni::base_bridge::TeleopOptions().key_timeout_s;
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
    } else if (args.Is("--status-channel")) {
      status_channel = args.Value();
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
      // At least 5 Hz: the bridge stops a base whose last twist is older than its
      // command_timeout_s (0.3 s as shipped), so a slower stream would drive it in bursts.
      rate_hz = args.Number(5, 1000);
    } else if (args.Is("--key-timeout")) {
      key_timeout_s = args.Number(0, 10);
    } else if (args.Is("--wait")) {
      wait_s = args.Number(0, 60);
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
  std::signal(SIGQUIT, OnSignal);
  omni::AlsoStopOnHangup(OnSignal);  // a closed SSH session stops the base, terminal restored
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
    const char* what = mode == omni::base_cmd_t::MODE_ESTOP          ? "e-stop"
                       : mode == omni::base_cmd_t::MODE_CLEAR_FAULTS ? "clear-faults"
                                                                     : "zero twist";
    // The bridge's BASE_STATUS says whether an e-stop took hold; heard from the start, so a
    // status already on its way counts only if it shows the e-stop.
    // Only a status with the firmware alive counts: the bridge keeps the last state it heard
    // while the board is silent, so an old ESTOP could "confirm" one that never arrived.
    int64_t statuses = 0;
    int8_t last_state = -1;
    bool alive = false;
    (*bus)->Subscribe<omni::base_status_t>(status_channel,
                                           [&](const omni::base_status_t& st, int64_t) {
                                             ++statuses;
                                             last_state = st.state;
                                             alive = st.firmware_alive;
                                           });
    auto confirmed = [&] { return alive && last_state == omni::base_status_t::STATE_ESTOP; };
    // A datagram can be lost: the command is idempotent, so it goes out five times, 20 ms apart.
    for (int i = 0; i < 5; ++i) {  // not cut short by Ctrl-C: an e-stop must go out
      send(mode, 0, 0, 0);
      (*bus)->HandleTimeout(20);
    }
    std::printf("omni-drive: sent %s on %s\n", what, channel.c_str());
    if (mode != omni::base_cmd_t::MODE_ESTOP || wait_s <= 0) return 0;
    const auto until = std::chrono::steady_clock::now() +
                       std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                           std::chrono::duration<double>(wait_s));
    while (!g_stop && std::chrono::steady_clock::now() < until && !confirmed())
      (*bus)->HandleTimeout(20);
    if (confirmed()) {
      std::printf("omni-drive: the base bridge reports the base e-stopped (%s)\n",
                  status_channel.c_str());
      return 0;
    }
    if (statuses == 0)
      std::fprintf(stderr,
                   "omni-drive: NOT CONFIRMED: no %s heard within %.1f s; is the base bridge "
                   "running on this bus (LCM_DEFAULT_URL, --url, --channel)?\n",
                   status_channel.c_str(), wait_s);
    else if (!alive)
      std::fprintf(stderr,
                   "omni-drive: NOT CONFIRMED: %s says the firmware is silent (no heartbeat): "
                   "the e-stop may not have reached the board\n",
                   status_channel.c_str());
    else
      std::fprintf(stderr,
                   "omni-drive: NOT CONFIRMED: %s still shows state %d, not ESTOP (5), after "
                   "%.1f s\n",
                   status_channel.c_str(), last_state, wait_s);
    return 1;
  }
  if (keys) return Teleop(send, rate_hz, key_timeout_s, channel);
  const auto start = std::chrono::steady_clock::now();
  const auto period = std::chrono::duration<double>(1.0 / rate_hz);
  auto at_s = [&](double t) {
    return start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                       std::chrono::duration<double>(t));
  };
  int64_t n = 0;
  for (; !g_stop; ++n) {
    const double t = n * period.count();
    if (t >= duration_s) break;
    if (!SleepUntil(at_s(t))) break;  // stopped while waiting: no further twist
    send(omni::base_cmd_t::MODE_TWIST, vx, vy, omega);
  }
  // The last twist holds until the duration is over, then the zero twist ends it.
  SleepUntil(at_s(duration_s));
  send(omni::base_cmd_t::MODE_TWIST, 0, 0, 0);
  std::printf("omni-drive: sent %lld twists (%.3f, %.3f, %.3f) on %s, then a zero twist%s\n",
              static_cast<long long>(n), vx, vy, omega, channel.c_str(),
              g_stop ? " (interrupted)" : "");
  return 0;
}
