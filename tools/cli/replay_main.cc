// omni-replay: publishes an LCM log onto the bus with its original timing (scaled).
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <regex>
#include <string>
#include <thread>

#include "omni/bus/bus.h"
#include "omni/common/time.h"
#include "omni/io/lcm_log.h"

namespace {

volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni replay LOG [--speed X] [--min-gap-us N] [--url LCM_URL] [--channels REGEX] "
      "[--resync]\n"
      "  Publishes every event of LOG on the bus, keeping the log's timing divided by X\n"
      "  (default 1; 0 = as fast as possible). --url defaults to LCM_DEFAULT_URL or LCM's\n"
      "  default multicast. --channels publishes only channels matching REGEX.\n"
      "  --min-gap-us spaces consecutive events by at least N microseconds (default 200) so\n"
      "  bursts of equal timestamps do not overflow UDP receive buffers.\n"
      "  A corrupt log stops the replay with the byte offset, unless --resync skips to\n"
      "  the next intact event.\n");
}

}  // namespace

int main(int argc, char** argv) {
  std::string path, url, channels;
  double speed = 1.0;
  int64_t min_gap_us = 200;
  bool resync = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto need = [&](const char* what) -> const char* {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "omni replay: %s needs a value\n", what);
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--help" || a == "-h") {
      Usage(stdout);
      return 0;
    } else if (a == "--speed") {
      char* end = nullptr;
      const char* v = need("--speed");
      speed = std::strtod(v, &end);
      if (*end != '\0' || !(speed >= 0)) {
        std::fprintf(stderr, "omni replay: --speed '%s' must be a number >= 0\n", v);
        return 2;
      }
    } else if (a == "--min-gap-us") {
      const char* v = need("--min-gap-us");
      char* end = nullptr;
      min_gap_us = std::strtoll(v, &end, 10);
      if (*end != '\0' || min_gap_us < 0) {
        std::fprintf(stderr, "omni replay: --min-gap-us '%s' must be an integer >= 0\n", v);
        return 2;
      }
    } else if (a == "--url" || a == "--lcm-url") {
      url = need(a.c_str());
    } else if (a == "--channels") {
      channels = need("--channels");
    } else if (a == "--resync") {
      resync = true;
    } else if (!a.empty() && a[0] == '-') {
      std::fprintf(stderr, "omni replay: unknown option '%s'\n", a.c_str());
      Usage(stderr);
      return 2;
    } else if (path.empty()) {
      path = a;
    } else {
      Usage(stderr);
      return 2;
    }
  }
  if (path.empty()) {
    Usage(stderr);
    return 2;
  }
  std::regex filter;
  try {
    filter = std::regex(channels.empty() ? ".*" : channels);
  } catch (const std::regex_error&) {
    std::fprintf(stderr, "omni replay: --channels '%s' is not a valid regular expression\n",
                 channels.c_str());
    return 2;
  }
  auto reader = omni::io::LcmLogReader::Open(path);
  if (!reader.ok()) {
    std::fprintf(stderr, "omni replay: %s\n", reader.error().message.c_str());
    return 1;
  }
  auto bus = omni::bus::Bus::Create(url);
  if (!bus.ok()) {
    std::fprintf(stderr, "omni replay: %s\n", bus.error().message.c_str());
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::io::LcmLogEvent ev;
  int64_t first_log = 0, first_wall = 0, published = 0, skipped = 0, last_pub = 0;
  while (!g_stop) {
    auto more = reader->Next(&ev, resync);
    if (!more.ok()) {
      std::fprintf(stderr, "omni replay: %s (after %lld events)\n", more.error().message.c_str(),
                   static_cast<long long>(published));
      return 1;
    }
    if (!*more) break;
    if (!std::regex_match(ev.channel, filter)) {
      ++skipped;
      continue;
    }
    if (speed > 0) {
      const int64_t now = omni::MonotonicMicros();
      if (published == 0) {
        first_log = ev.utime;
        first_wall = now;
      } else {
        const int64_t due =
            first_wall + static_cast<int64_t>(static_cast<double>(ev.utime - first_log) / speed);
        if (due > now) std::this_thread::sleep_for(std::chrono::microseconds(due - now));
      }
    }
    if (min_gap_us > 0 && published > 0) {
      const int64_t next = last_pub + min_gap_us;
      const int64_t now = omni::MonotonicMicros();
      if (next > now) std::this_thread::sleep_for(std::chrono::microseconds(next - now));
    }
    last_pub = omni::MonotonicMicros();
    if (!(*bus)->PublishRaw(ev.channel, ev.data.data(), static_cast<int>(ev.data.size()))) {
      std::fprintf(stderr, "omni replay: publish on %s failed\n", ev.channel.c_str());
      return 1;
    }
    ++published;
  }
  std::printf("replayed %lld events from %s (%lld filtered out, %llu corrupt bytes skipped)%s\n",
              static_cast<long long>(published), path.c_str(), static_cast<long long>(skipped),
              static_cast<unsigned long long>(reader->skipped_bytes()),
              g_stop ? " [interrupted]" : "");
  return g_stop ? 130 : 0;
}
