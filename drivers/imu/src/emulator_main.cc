// omni-imu-emulator: a software WitMotion WT901 on a pseudo-terminal, for tests and drills.
//
//   omni-imu-emulator --link PATH [--rate-hz HZ] [--yaw-rate-deg-s D] [--roll-deg D]
//                     [--pitch-deg D] [--no-mag] [--no-quaternion] [--baud B]
//                     [--ignore-writes] [--duration-s S]
// Configuration writes from the driver (rate, frames, baud, save) are applied and logged; with
// --baud the line must be opened at the device's rate, else both directions are garbled.
// Commands on stdin (one per line), answered "ok CMD" on stdout:
//   garbage N      splice N random bytes into the next frame (that frame is lost)
//   vanish MS      unplug for MS milliseconds (pty closed, link removed), then plug back in
//   silence MS     stop sending for MS milliseconds with the port open
//   quit
#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>

#include "omni/common/log.h"
#include "omni/common/stop_signals.h"
#include "omni/common/time.h"
#include "omni/imu/emulator.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-imu-emulator --link PATH [--rate-hz HZ] [--yaw-rate-deg-s D]\n"
               "                         [--roll-deg D] [--pitch-deg D] [--no-mag]\n"
               "                         [--no-quaternion] [--baud B] [--ignore-writes]\n"
               "                         [--duration-s S]\n"
               "A software WitMotion WT901 on a pty; drivers open PATH (a symlink to the pty).\n"
               "Streams 0x51 accel, 0x52 gyro, 0x53 angles, 0x54 mag, 0x59 quaternion frames\n"
               "at HZ (default 100) of a slow yaw rotation (default 11.5 deg/s), gravity on z.\n"
               "--baud B: the device's serial rate (4800 ... 921600); a reader at another rate\n"
               "gets garbage. Register writes (0xFF 0xAA: rate, frames, baud, save) are applied\n"
               "after the unlock key, unless --ignore-writes. An unplug restores saved settings.\n"
               "stdin commands: garbage N | vanish MS | silence MS | quit\n");
  return code;
}

bool ParseDouble(const std::string& s, double* out) {
  char* end = nullptr;
  *out = std::strtod(s.c_str(), &end);
  return end != s.c_str() && *end == '\0' && std::isfinite(*out);
}
}  // namespace

int main(int argc, char** argv) {
  omni::imu::EmulatorOptions opt;
  double duration_s = -1;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(Usage(2));
      }
      return argv[++i];
    };
    auto number = [&]() -> double {
      const std::string v = next();
      double x = 0;
      if (!ParseDouble(v, &x)) {
        std::fprintf(stderr, "%s: '%s' is not a number\n", a.c_str(), v.c_str());
        std::exit(Usage(2));
      }
      return x;
    };
    if (a == "--help" || a == "-h") return Usage(0);
    if (a == "--link") {
      opt.link_path = next();
    } else if (a == "--rate-hz") {
      opt.rate_hz = number();
    } else if (a == "--yaw-rate-deg-s") {
      opt.yaw_rate_rad_s = number() * M_PI / 180.0;
    } else if (a == "--roll-deg") {
      opt.roll_rad = number() * M_PI / 180.0;
    } else if (a == "--pitch-deg") {
      opt.pitch_rad = number() * M_PI / 180.0;
    } else if (a == "--no-mag") {
      opt.send_mag = false;
    } else if (a == "--no-quaternion") {
      opt.send_quaternion = false;
    } else if (a == "--baud") {
      opt.baud = static_cast<int>(number());
    } else if (a == "--ignore-writes") {
      opt.accept_writes = false;
    } else if (a == "--duration-s") {
      duration_s = number();
    } else {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      return Usage(2);
    }
  }
  if (opt.link_path.empty()) {
    std::fprintf(stderr, "--link is required\n");
    return Usage(2);
  }
  omni::SetLogProcessName("imu_emulator");
  auto emu = omni::imu::ImuEmulator::Create(opt);
  if (!emu.ok()) {
    LOG_ERROR << emu.error().ToString();
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::AlsoStopOnHangup(OnSignal);  // a closed terminal stops it in order too
  LOG_INFO << "WT901 emulator on " << (*emu)->path() << " at " << opt.rate_hz << " Hz";
  std::printf("ready %s\n", (*emu)->path().c_str());
  std::fflush(stdout);
  fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
  std::string line_buf;
  const int64_t start = omni::MonotonicMicros();
  int64_t restore_at = -1, resume_at = -1;
  bool stdin_open = true;
  int64_t writes_seen = 0, saves_seen = 0;
  while (!g_stop) {
    const int64_t now = omni::MonotonicMicros();
    if (duration_s > 0 && now - start > omni::SecondsToUtime(duration_s)) break;
    if (restore_at >= 0 && now >= restore_at) {
      omni::Status st = (*emu)->Restore();
      if (!st.ok()) {
        LOG_ERROR << st.message();
      }
      restore_at = -1;
    }
    if (resume_at >= 0 && now >= resume_at) {
      (*emu)->SetStreaming(true);
      resume_at = -1;
    }
    (*emu)->Step(now);
    if ((*emu)->counters().writes != writes_seen || (*emu)->counters().saves != saves_seen) {
      writes_seen = (*emu)->counters().writes;
      saves_seen = (*emu)->counters().saves;
      const auto& o = (*emu)->options();
      LOG_INFO << "settings now: " << o.rate_hz << " Hz, baud " << o.baud << ", frames"
               << (o.send_time ? " time" : "") << (o.send_accel ? " accel" : "")
               << (o.send_gyro ? " gyro" : "") << (o.send_angle ? " angle" : "")
               << (o.send_mag ? " mag" : "") << (o.send_quaternion ? " quaternion" : "") << " ("
               << saves_seen << " saves)";
    }
    pollfd p[2] = {{(*emu)->fd(), POLLIN, 0}, {stdin_open ? 0 : -1, POLLIN, 0}};
    ::poll(p, 2, 2);
    char buf[256];
    const ssize_t n = stdin_open ? ::read(0, buf, sizeof(buf)) : -1;
    if (n == 0) stdin_open = false;
    if (n > 0) line_buf.append(buf, static_cast<size_t>(n));
    size_t nl;
    while ((nl = line_buf.find('\n')) != std::string::npos) {
      std::istringstream cmd(line_buf.substr(0, nl));
      line_buf.erase(0, nl + 1);
      std::string what;
      cmd >> what;
      if (what == "garbage") {
        size_t count = 0;
        cmd >> count;
        (*emu)->InjectGarbage(count, static_cast<uint32_t>(now));
      } else if (what == "vanish") {
        int ms = 0;
        cmd >> ms;
        (*emu)->Vanish();
        restore_at = omni::MonotonicMicros() + int64_t{ms} * 1000;
      } else if (what == "silence") {
        int ms = 0;
        cmd >> ms;
        (*emu)->SetStreaming(false);
        resume_at = omni::MonotonicMicros() + int64_t{ms} * 1000;
      } else if (what == "quit") {
        g_stop = true;
      } else if (!what.empty()) {
        LOG_WARN << "unknown command '" << what << "'";
      }
      std::printf("ok %s\n", what.c_str());
      std::fflush(stdout);
    }
  }
  const auto& c = (*emu)->counters();
  LOG_INFO << "sent " << c.periods << " periods, " << c.frames << " frames (" << c.frames_corrupted
           << " corrupted), " << c.bytes_dropped << " bytes dropped, " << c.bytes_garbled
           << " bytes garbled by a baud mismatch; " << c.writes << " register writes applied, "
           << c.writes_ignored << " ignored";
  return 0;
}
