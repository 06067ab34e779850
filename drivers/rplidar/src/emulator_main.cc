// omni-rplidar-emulator: a software RPLidar on a pseudo-terminal, for tests and the demo.
//
//   omni-rplidar-emulator --link PATH [--model a1|a2|a3] [--hz HZ] [--capture FILE.bin]
//                         [--duration-s S]
// Commands on stdin (one per line), for tests and field-engineer drills:
//   garbage N      send N random bytes into the stream
//   vanish MS      unplug for MS milliseconds (pty closed, link removed), then plug back in
//   health error|warning|ok   what GET_HEALTH answers (error: scans refused until RESET)
//   quit
#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>

#include "omni/common/log.h"
#include "omni/common/stop_signals.h"
#include "omni/common/time.h"
#include "omni/rplidar/emulator.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-rplidar-emulator --link PATH [--model a1|a2|a3] [--hz HZ]\n"
               "                             [--capture FILE.bin] [--duration-s S]\n"
               "A software RPLidar on a pty; drivers open PATH (a symlink to the pty).\n"
               "It answers every command and streams SCAN (standard) or EXPRESS_SCAN packets at\n"
               "the real rate from a simulated room, or loops the raw nodes of --capture.\n"
               "stdin commands: garbage N | vanish MS | health error|warning|ok | quit\n");
  return code;
}
}  // namespace

int main(int argc, char** argv) {
  omni::rplidar::EmulatorOptions opt;
  double duration_s = -1;
  std::string capture;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(Usage(2));
      }
      return argv[++i];
    };
    if (a == "--help" || a == "-h") return Usage(0);
    if (a == "--link") {
      opt.link_path = next();
    } else if (a == "--model") {
      const std::string m = next();
      if (m == "a1") {
        opt.model = 0x18;
      } else if (m == "a2") {
        opt.model = 0x28;
      } else if (m == "a3") {
        opt.model = 0x31;
      } else {
        std::fprintf(stderr, "--model must be a1, a2 or a3\n");
        return 2;
      }
    } else if (a == "--hz") {
      const std::string v = next();
      char* end = nullptr;
      opt.scan_hz = std::strtod(v.c_str(), &end);
      if (end == v.c_str() || *end != '\0' || !(opt.scan_hz >= 1 && opt.scan_hz <= 100)) {
        std::fprintf(stderr, "--hz '%s' must be in [1, 100]\n", v.c_str());
        return 2;
      }
    } else if (a == "--capture") {
      capture = next();
    } else if (a == "--duration-s") {
      const std::string v = next();
      char* end = nullptr;
      duration_s = std::strtod(v.c_str(), &end);
      if (end == v.c_str() || *end != '\0' || !(duration_s > 0 && duration_s <= 1e9)) {
        std::fprintf(stderr, "--duration-s '%s' must be seconds in (0, 1e9]\n", v.c_str());
        return 2;
      }
    } else {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      return Usage(2);
    }
  }
  if (opt.link_path.empty()) return Usage(2);
  omni::SetLogProcessName("rplidar_emulator");
  if (!capture.empty()) {
    std::ifstream in(capture, std::ios::binary);
    if (!in) {
      LOG_ERROR << "cannot open capture " << capture;
      return 1;
    }
    opt.capture.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  auto emu = omni::rplidar::RplidarEmulator::Create(opt);
  if (!emu.ok()) {
    LOG_ERROR << emu.error().ToString();
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::AlsoStopOnHangup(OnSignal);  // a closed terminal stops it in order too
  LOG_INFO << "RPLidar emulator on " << (*emu)->path();
  std::printf("ready %s\n", (*emu)->path().c_str());
  std::fflush(stdout);
  fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
  std::string line_buf;
  const int64_t start = omni::MonotonicMicros();
  int64_t restore_at = -1;
  bool stdin_open = true;
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
    (*emu)->Step(now);
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
      } else if (what == "health") {
        std::string h;
        cmd >> h;
        (*emu)->SetHealth(h == "error" ? omni::rplidar::kHealthError
                                       : (h == "warning" ? omni::rplidar::kHealthWarning
                                                         : omni::rplidar::kHealthGood),
                          h == "error" ? 0x8001 : 0);
      } else if (what == "quit") {
        g_stop = true;
      } else if (!what.empty()) {
        LOG_WARN << "unknown command '" << what << "'";
      }
      std::printf("ok %s\n", what.c_str());
      std::fflush(stdout);
    }
  }
  return 0;
}
