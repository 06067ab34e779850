// omni-replay: publishes an LCM log onto the bus with its original timing (scaled).
#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <regex>
#include <string>
#include <thread>

#include "omni/bus/bus.h"
#include "omni/common/stop_signals.h"
#include "omni/common/time.h"
#include "omni/io/lcm_log.h"

namespace {

volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

// Sleeps until the monotonic time `until_us`, in slices, so a signal stops a long wait at once
// (sleep_for restarts itself after a signal). False when stopped.
bool SleepUntil(int64_t until_us) {
  for (int64_t now = omni::MonotonicMicros(); now < until_us && !g_stop;
       now = omni::MonotonicMicros())
    std::this_thread::sleep_for(
        std::chrono::microseconds(std::min<int64_t>(until_us - now, 50000)));
  return !g_stop;
}

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
      "  the next intact event. A log that ends inside an event (a recording cut short) is\n"
      "  replayed up to it with a warning, exit status 0.\n"
      "  --max-gap S: a jump forward of the log's time by more than S seconds (default 5; two\n"
      "  recordings joined, a clock set forward) is replayed as S; a jump back (a clock set\n"
      "  back) as no gap. Both are counted and said at the end.\n");
}

}  // namespace

int main(int argc, char** argv) {
  std::string path, url, channels;
  double speed = 1.0;
  int64_t min_gap_us = 200;
  double max_gap_s = 5.0;
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
      if (*end != '\0' || !(speed == 0 || (speed >= 1e-3 && speed <= 1e6))) {
        std::fprintf(stderr, "omni replay: --speed '%s' must be 0 or in [0.001, 1e6]\n", v);
        return 2;
      }
    } else if (a == "--max-gap") {
      char* end = nullptr;
      const char* v = need("--max-gap");
      max_gap_s = std::strtod(v, &end);
      if (*end != '\0' || !(max_gap_s >= 0 && max_gap_s <= 86400)) {
        std::fprintf(stderr, "omni replay: --max-gap '%s' must be seconds in [0, 86400]\n", v);
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
  omni::AlsoStopOnHangup(OnSignal);  // a closed terminal stops it in order too
  omni::io::LcmLogEvent ev;
  int64_t published = 0, skipped = 0, last_pub = 0;
  bool truncated_tail = false;
  // The schedule: the log time `anchor_log` is due at the monotonic time `anchor_wall`; each
  // event is due after it by its log time's distance / speed. A jump of the log's time (back,
  // or forward by more than --max-gap) moves the anchor instead of the schedule following it.
  int64_t anchor_log = 0, anchor_wall = 0, prev_log = 0, jumps_back = 0, gaps_cut = 0;
  const int64_t max_gap_us = static_cast<int64_t>(max_gap_s * 1e6);
  while (!g_stop) {
    auto more = reader->Next(&ev, resync);
    if (!more.ok()) {
      std::fprintf(stderr, "omni replay: %s (after %lld events)\n", more.error().message.c_str(),
                   static_cast<long long>(published));
      // A log cut short while recording: every complete event is replayed, the partial last
      // one cannot be; a warning, not a failed replay.
      if (reader->truncated_tail()) {
        truncated_tail = true;
        break;
      }
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
        anchor_log = ev.utime;
        anchor_wall = now;
      } else if (ev.utime < prev_log) {
        if (jumps_back++ == 0)
          std::fprintf(stderr, "omni replay: the log's time goes back by %.3f s at event %lld\n",
                       1e-6 * static_cast<double>(prev_log - ev.utime),
                       static_cast<long long>(published));
        anchor_log = ev.utime;
        anchor_wall = std::max(now, anchor_wall);
      } else if (ev.utime - prev_log > max_gap_us) {
        if (gaps_cut++ == 0)
          std::fprintf(stderr,
                       "omni replay: the log's time jumps forward by %.3f s at event %lld: "
                       "replayed as %g s (--max-gap)\n",
                       1e-6 * static_cast<double>(ev.utime - prev_log),
                       static_cast<long long>(published), max_gap_s);
        // Due max_gap after the previous event.
        anchor_wall += static_cast<int64_t>(static_cast<double>(prev_log - anchor_log) / speed) +
                       static_cast<int64_t>(static_cast<double>(max_gap_us) / speed);
        anchor_log = ev.utime;
      }
      const int64_t due =
          anchor_wall + static_cast<int64_t>(static_cast<double>(ev.utime - anchor_log) / speed);
      if (!SleepUntil(due)) break;
    }
    prev_log = ev.utime;
    if (min_gap_us > 0 && published > 0) {
      const int64_t next = last_pub + min_gap_us;
      const int64_t now = omni::MonotonicMicros();
      if (next > now && !SleepUntil(next)) break;
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
  if (truncated_tail)
    std::printf(
        "  the log ends inside an event (cut while recording?): that partial event is "
        "not replayed\n");
  if (jumps_back + gaps_cut > 0)
    std::printf("  log time: %lld jumps back, %lld gaps over %g s shortened\n",
                static_cast<long long>(jumps_back), static_cast<long long>(gaps_cut), max_gap_s);
  return g_stop ? 130 : 0;
}
