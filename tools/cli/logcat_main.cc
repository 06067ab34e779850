// omni-logcat: summarises an LCM log (events per channel, time span) and checks its integrity.
#include <cstdio>
#include <cstring>
#include <map>
#include <string>

#include "omni/io/lcm_log.h"

int main(int argc, char** argv) {
  if (argc != 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h")) {
    std::fprintf(
        argc == 2 ? stdout : stderr,
        "usage: omni logcat LOG\n  Prints events per channel and the time span of an LCM log;\n"
        "  a corrupt or truncated log is an error naming the byte offset.\n");
    return argc == 2 ? 0 : 2;
  }
  auto reader = omni::io::LcmLogReader::Open(argv[1]);
  if (!reader.ok()) {
    std::fprintf(stderr, "omni logcat: %s\n", reader.error().message.c_str());
    return 1;
  }
  std::map<std::string, std::pair<long long, long long>> per_channel;  // events, bytes
  omni::io::LcmLogEvent ev;
  long long n = 0;
  int64_t t0 = 0, t1 = 0, backwards = 0, last = 0;
  for (;;) {
    auto more = reader->Next(&ev);
    if (!more.ok()) {
      std::fprintf(stderr, "omni logcat: %s (after %lld good events)\n",
                   more.error().message.c_str(), n);
      return 1;
    }
    if (!*more) break;
    if (n == 0) t0 = ev.utime;
    if (n > 0 && ev.utime < last) ++backwards;
    last = ev.utime;
    t1 = ev.utime;
    auto& pc = per_channel[ev.channel];
    ++pc.first;
    pc.second += static_cast<long long>(ev.data.size());
    ++n;
  }
  std::printf("%s: %lld events over %.3f s", argv[1], n,
              (static_cast<double>(t1) - static_cast<double>(t0)) * 1e-6);  // no int64 overflow
  std::printf(backwards ? ", %lld timestamps going backwards\n" : "\n",
              static_cast<long long>(backwards));
  for (const auto& [ch, v] : per_channel)
    std::printf("  %-20s %8lld events %12lld bytes\n", ch.c_str(), v.first, v.second);
  return 0;
}
