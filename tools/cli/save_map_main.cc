// omni-save-map (./omni save-map): asks the running mappers to write their maps now, while they
// keep mapping, and prints their answers (MAP_SAVE / MAP_SAVE_REPLY, see omni/bus/map_save.h).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <set>
#include <string>

#include "omni/bus/bus.h"
#include "omni/bus/channels.h"
#include "omni/bus/map_save.h"
#include "omni/common/cli.h"
#include "omni/common/time.h"
#include "omni/heartbeat_t.hpp"
#include "omni/map_save_reply_t.hpp"
#include "omni/map_save_request_t.hpp"

namespace {

// Heartbeats come once a second: after this long every running mapper has been heard.
constexpr double kListenS = 1.2;

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-save-map [--url URL] [--process NAME] [--dir DIR] [--wait S]\n"
      "  Asks the running mappers (rbpf_mapper, pose_graph_mapper, odom_mapper, map_fusion,\n"
      "  octomap_builder) to write their maps now, without stopping, and prints each answer.\n"
      "  --process NAME  only this process (default: every mapper on the bus)\n"
      "  --dir DIR       where (default: each one's --out folder; for every mapper,\n"
      "                  DIR/<process>). A relative DIR is taken from this shell's folder;\n"
      "                  give an absolute one when the mappers run on another machine\n"
      "  --wait S        how long to wait for answers (default 10); stops early when the named\n"
      "                  process answered, or when every mapper whose heartbeat was heard in\n"
      "                  the first %.1f s answered\n"
      "  Exit status: 0 all answers ok, 1 a mapper could not write or did not answer,\n"
      "  3 nobody answered, 4 the request could not be sent (the bus, --dir).\n",
      kListenS);
}

}  // namespace

int main(int argc, char** argv) {
  std::string lcm_url, process, dir;
  double wait_s = 10;
  omni::ArgReader args(argc, argv, "omni-save-map", Usage);
  while (args.Next()) {
    if (args.IsUrl()) {
      lcm_url = args.Value();
    } else if (args.Is("--process")) {
      process = args.Value();
    } else if (args.Is("--dir")) {
      dir = args.Value();
    } else if (args.Is("--wait")) {
      wait_s = args.Number(0.01, 3600);
    } else {
      args.Unknown();
    }
  }
  auto bus = omni::bus::Bus::Create(lcm_url);
  if (!bus.ok()) {
    std::fprintf(stderr, "omni-save-map: %s\n", bus.error().message.c_str());
    return 4;
  }
  if (!dir.empty() && dir.front() != '/') {
    // The mappers' working folders are theirs (the supervisor's, a service's): a relative
    // folder means this shell's.
    std::error_code ec;
    const std::filesystem::path abs = std::filesystem::absolute(dir, ec);
    if (ec) {
      std::fprintf(stderr, "omni-save-map: cannot resolve --dir '%s': %s\n", dir.c_str(),
                   ec.message().c_str());
      return 4;
    }
    dir = abs.lexically_normal().string();
  }
  omni::map_save_request_t req{};
  req.utime = omni::SystemClock().NowUtime();
  // Answers to another sender's request carry its number, not ours.
  req.seq = (static_cast<int64_t>(getpid()) << 32) ^ (req.utime & 0xffffffff);
  req.process = process;
  req.directory = dir;
  int answers = 0, failures = 0;
  // The processes that serve map saves (their heartbeat carries maps_saved), heard in the first
  // kListenS s (a mapper that starts later, e.g. restarted by the supervisor, never got the
  // request: it is not waited for, nor reported as not answering), and those that answered.
  std::set<std::string> serving, answered;
  std::chrono::steady_clock::time_point listen_end = std::chrono::steady_clock::time_point::max();
  (*bus)->Subscribe<omni::heartbeat_t>(
      omni::channels::kHeartbeat, [&](const omni::heartbeat_t& h, int64_t) {
        if (std::chrono::steady_clock::now() >= listen_end) return;
        if (h.state == omni::heartbeat_t::STATE_STOPPING) return;
        if (!process.empty() && h.process != process) return;
        if (std::find(h.counter_names.begin(), h.counter_names.end(), "maps_saved") !=
            h.counter_names.end())
          serving.insert(h.process);
      });
  const auto start = std::chrono::steady_clock::now();
  const auto listened = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                    std::chrono::duration<double>(kListenS));
  listen_end = listened;
  const auto deadline = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                    std::chrono::duration<double>(wait_s));
  // Without any heartbeat (none on this bus, or a mapper too busy to send one), the old rule:
  // 2 s without a new answer ends the wait.
  auto quiet_deadline = deadline;
  (*bus)->Subscribe<omni::map_save_reply_t>(
      omni::bus::kMapSaveReplyChannel, [&](const omni::map_save_reply_t& m, int64_t) {
        if (m.seq != req.seq) return;
        ++answers;
        failures += !m.ok;
        answered.insert(m.process);
        std::printf("%s: %s: %s\n", m.process.c_str(), m.ok ? "saved" : "FAILED",
                    m.message.c_str());
        quiet_deadline =
            std::min(deadline, std::chrono::steady_clock::now() + std::chrono::seconds(2));
      });
  if (!(*bus)->Publish(omni::bus::kMapSaveChannel, req)) {
    std::fprintf(stderr, "omni-save-map: publishing on %s failed\n", omni::bus::kMapSaveChannel);
    return 4;
  }
  auto done = [&] {
    const auto now = std::chrono::steady_clock::now();
    if (now >= deadline) return true;
    if (!process.empty()) return answers > 0;
    if (now < listened) return false;
    if (serving.empty()) return answers > 0 && now >= quiet_deadline;
    for (const std::string& p : serving)
      if (answered.count(p) == 0) return false;
    return true;
  };
  while (!done()) {
    const auto now = std::chrono::steady_clock::now();
    const auto next = now < listened ? std::min(listened, deadline) : deadline;
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(next - now);
    if ((*bus)->HandleTimeout(static_cast<int>(std::clamp<int64_t>(left.count(), 1, 100))) < 0)
      break;
  }
  if (answers == 0) {
    std::fprintf(stderr, "omni-save-map: no %s answered within %g s\n",
                 process.empty() ? "mapper" : process.c_str(), wait_s);
    return 3;
  }
  int silent = 0;
  for (const std::string& p : serving) {
    if (answered.count(p) != 0) continue;
    std::printf("%s: NO ANSWER within %g s (its heartbeat was heard)\n", p.c_str(), wait_s);
    ++silent;
  }
  return failures > 0 || silent > 0 ? 1 : 0;
}
