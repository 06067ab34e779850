// omni-status (./omni status): the health of every omni process on the bus, from their
// HEARTBEAT messages, as a table in the terminal (for a headless robot PC, where lcm-spy's
// window is not at hand) or as JSON for scripts.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>

#include "omni/bus/bus.h"
#include "omni/common/cli.h"
#include "omni/heartbeat_t.hpp"

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-status [--url URL] [--wait S] [--process NAME] [--all-counters] [--json]\n"
      "  Listens to HEARTBEAT for S seconds (default 2.5; processes beat once a second) and\n"
      "  prints each process heard: state, uptime, CPU, memory, bus traffic and errors, its\n"
      "  status text and its non-zero counters (--all-counters: every counter).\n"
      "  Every instance is shown (one name heard from two pids, e.g. a second base bridge\n"
      "  started by hand, is marked DUPLICATE), except one that stopped while a newer one of\n"
      "  the same name runs (a restart).\n"
      "  Exit status: 0 all OK (or starting), 1 one is DEGRADED, ERROR, STOPPING, in an\n"
      "  unknown state or duplicated, 3 none heard, 4 the bus could not be opened.\n");
}

const char* StateName(int8_t s) {
  switch (s) {
    case omni::heartbeat_t::STATE_STARTING:
      return "STARTING";
    case omni::heartbeat_t::STATE_OK:
      return "OK";
    case omni::heartbeat_t::STATE_DEGRADED:
      return "DEGRADED";
    case omni::heartbeat_t::STATE_ERROR:
      return "ERROR";
    case omni::heartbeat_t::STATE_STOPPING:
      return "STOPPING";
    default:
      return "?";
  }
}

// The length of the well-formed UTF-8 sequence at s[i], or 0 (a stray, cut, overlong or
// surrogate sequence, or a lead byte UTF-8 does not have).
size_t Utf8Length(const std::string& s, size_t i) {
  const auto b = [&](size_t k) { return static_cast<unsigned char>(s[k]); };
  const unsigned char c = b(i);
  size_t n = 0;
  unsigned char lo = 0x80, hi = 0xBF;  // the second byte's range
  if (c >= 0xC2 && c <= 0xDF) {
    n = 2;
  } else if (c >= 0xE0 && c <= 0xEF) {
    n = 3;
    if (c == 0xE0) lo = 0xA0;  // overlong
    if (c == 0xED) hi = 0x9F;  // surrogates
  } else if (c >= 0xF0 && c <= 0xF4) {
    n = 4;
    if (c == 0xF0) lo = 0x90;  // overlong
    if (c == 0xF4) hi = 0x8F;  // beyond U+10FFFF
  }
  if (n == 0 || i + n > s.size()) return 0;
  if (b(i + 1) < lo || b(i + 1) > hi) return 0;
  for (size_t k = 2; k < n; ++k)
    if ((b(i + k) & 0xC0) != 0x80) return 0;
  return n;
}

// A JSON string: quotes, backslashes and control bytes escaped, and bytes that are not UTF-8
// (a status text is the process's bytes) replaced by U+FFFD, so the output always parses.
std::string Json(const std::string& s) {
  std::string o = "\"";
  for (size_t i = 0; i < s.size(); ++i) {
    const char c = s[i];
    const auto u = static_cast<unsigned char>(c);
    if (c == '"' || c == '\\') {
      o += '\\';
      o += c;
    } else if (u < 0x20 || u == 0x7F) {
      char b[8];
      std::snprintf(b, sizeof(b), "\\u%04x", u);
      o += b;
    } else if (u < 0x80) {
      o += c;
    } else if (const size_t n = Utf8Length(s, i); n > 0) {
      o.append(s, i, n);
      i += n - 1;
    } else {
      o += "\\ufffd";
    }
  }
  return o + "\"";
}

// JSON has no NaN: a figure a process could not measure (NaN) is written as -1.
double Finite(float v) { return std::isfinite(v) ? static_cast<double>(v) : -1.0; }

std::string Uptime(int64_t us) {
  const int64_t s = us / 1000000;
  char b[32];
  if (s >= 3600)
    std::snprintf(b, sizeof(b), "%lldh%02lldm", static_cast<long long>(s / 3600),
                  static_cast<long long>(s / 60 % 60));
  else
    std::snprintf(b, sizeof(b), "%lldm%02llds", static_cast<long long>(s / 60),
                  static_cast<long long>(s % 60));
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  std::string lcm_url, only;
  double wait_s = 2.5;
  bool all_counters = false, json = false;
  omni::ArgReader args(argc, argv, "omni-status", Usage);
  while (args.Next()) {
    if (args.IsUrl()) {
      lcm_url = args.Value();
    } else if (args.Is("--wait")) {
      wait_s = args.Number(0.1, 3600);
    } else if (args.Is("--process")) {
      only = args.Value();
    } else if (args.Is("--all-counters")) {
      all_counters = true;
    } else if (args.Is("--json")) {
      json = true;
    } else {
      args.Unknown();
    }
  }
  auto bus = omni::bus::Bus::Create(lcm_url);
  if (!bus.ok()) {
    std::fprintf(stderr, "omni-status: %s\n", bus.error().message.c_str());
    return 4;
  }
  // The newest heartbeat of each instance (name and pid), and the stamp of its first.
  std::map<std::pair<std::string, int32_t>, omni::heartbeat_t> heard;
  std::map<std::pair<std::string, int32_t>, int64_t> first_utime;
  (*bus)->Subscribe<omni::heartbeat_t>("HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) {
    if (!only.empty() && m.process != only) return;
    auto& slot = heard[{m.process, m.pid}];
    if (m.utime >= slot.utime) slot = m;
    auto [it, added] = first_utime.emplace(std::make_pair(m.process, m.pid), m.utime);
    if (!added) it->second = std::min(it->second, m.utime);
  });
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                            std::chrono::duration<double>(wait_s));
  while (std::chrono::steady_clock::now() < deadline) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if ((*bus)->HandleTimeout(static_cast<int>(std::max<int64_t>(1, left.count()))) < 0) break;
  }
  const int64_t undecodable = (*bus)->counters().decode_errors;
  // An instance replaced by a newer one of its name was restarted: not shown. Replaced means it
  // said STOPPING before the newer one's last heartbeat, or it fell silent before the newer one
  // first beat (it crashed or was killed, and the supervisor started another). Any other name
  // heard from several pids is a duplicate (two bridges would both command the base).
  auto replaced = [&](const std::pair<std::string, int32_t>& key, const omni::heartbeat_t& m) {
    for (const auto& [other, o] : heard) {
      if (other.first != key.first || other.second == key.second) continue;
      if (m.state == omni::heartbeat_t::STATE_STOPPING && m.utime < o.utime) return true;
      if (m.utime < first_utime[other]) return true;
    }
    return false;
  };
  std::map<std::pair<std::string, int32_t>, omni::heartbeat_t> latest;
  for (const auto& [key, m] : heard)
    if (!replaced(key, m)) latest.emplace(key, m);
  std::map<std::string, int> instances;
  for (const auto& [key, m] : latest) ++instances[key.first];
  auto duplicate = [&](const omni::heartbeat_t& m) { return instances[m.process] > 1; };
  int unhealthy = 0;
  for (const auto& [key, m] : latest)
    unhealthy += m.state == omni::heartbeat_t::STATE_DEGRADED ||
                 m.state == omni::heartbeat_t::STATE_ERROR ||
                 m.state == omni::heartbeat_t::STATE_STOPPING ||
                 std::string(StateName(m.state)) == "?" || duplicate(m);
  if (json) {
    std::printf("{\"processes\": [");
    bool first = true;
    for (const auto& [key, m] : latest) {
      std::printf(
          "%s\n  {\"process\": %s, \"pid\": %d, \"state\": \"%s\", \"duplicate\": %s, "
          "\"status\": %s, "
          "\"uptime_s\": %.1f, \"cpu_percent\": %.1f, \"rss_mb\": %.1f, \"msgs_in\": %lld, "
          "\"msgs_out\": %lld, \"decode_errors\": %lld, \"drops\": %lld, \"counters\": {",
          first ? "" : ",", Json(m.process).c_str(), m.pid, StateName(m.state),
          duplicate(m) ? "true" : "false", Json(m.status_text).c_str(),
          static_cast<double>(m.uptime_us) * 1e-6, Finite(m.cpu_percent), Finite(m.rss_mb),
          static_cast<long long>(m.msgs_in), static_cast<long long>(m.msgs_out),
          static_cast<long long>(m.decode_errors), static_cast<long long>(m.drops));
      for (int i = 0; i < m.num_counters; ++i)
        std::printf("%s%s: %lld", i == 0 ? "" : ", ", Json(m.counter_names[i]).c_str(),
                    static_cast<long long>(m.counter_values[i]));
      std::printf("}}");
      first = false;
    }
    std::printf("\n], \"undecodable_heartbeats\": %lld}\n", static_cast<long long>(undecodable));
  } else if (!latest.empty()) {
    std::printf("%-20s %7s %-9s %8s %5s %7s %9s %9s %6s %6s  %s\n", "PROCESS", "PID", "STATE",
                "UPTIME", "CPU%", "RSS MB", "MSGS IN", "MSGS OUT", "DECERR", "DROPS", "STATUS");
    for (const auto& [key, m] : latest) {
      std::printf("%-20s %7d %-9s %8s %5.1f %7.1f %9lld %9lld %6lld %6lld  %s\n", m.process.c_str(),
                  m.pid, StateName(m.state), Uptime(m.uptime_us).c_str(), Finite(m.cpu_percent),
                  Finite(m.rss_mb), static_cast<long long>(m.msgs_in),
                  static_cast<long long>(m.msgs_out), static_cast<long long>(m.decode_errors),
                  static_cast<long long>(m.drops), m.status_text.c_str());
      if (duplicate(m))
        std::printf("    DUPLICATE: %d instances of %s on this bus\n", instances[m.process],
                    m.process.c_str());
      std::string line;
      for (int i = 0; i < m.num_counters; ++i)
        if (all_counters || m.counter_values[i] != 0)
          line += (line.empty() ? "" : "  ") + m.counter_names[i] + "=" +
                  std::to_string(m.counter_values[i]);
      if (!line.empty()) std::printf("    %s\n", line.c_str());
    }
    if (undecodable > 0)
      std::printf(
          "(%lld HEARTBEAT messages could not be decoded: another program's type on the "
          "channel?)\n",
          static_cast<long long>(undecodable));
  }
  if (latest.empty()) {
    std::fprintf(stderr,
                 "omni-status: no %s heartbeat within %g s (is the stack running, on "
                 "this bus?)\n",
                 only.empty() ? "process's" : only.c_str(), wait_s);
    return 3;
  }
  return unhealthy > 0 ? 1 : 0;
}
