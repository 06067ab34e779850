// omni-save-map (./omni save-map): asks the running mappers to write their maps now, while they
// keep mapping, and prints their answers (MAP_SAVE / MAP_SAVE_REPLY, see omni/bus/map_save.h).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/bus/bus.h"
#include "omni/bus/map_save.h"
#include "omni/common/cli.h"
#include "omni/common/time.h"
#include "omni/map_save_reply_t.hpp"
#include "omni/map_save_request_t.hpp"

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-save-map [--url URL] [--process NAME] [--dir DIR] [--wait S]\n"
      "  Asks the running mappers (rbpf_mapper, pose_graph_mapper, odom_mapper, map_fusion,\n"
      "  octomap_builder) to write their maps now, without stopping, and prints each answer.\n"
      "  --process NAME  only this process (default: every mapper on the bus)\n"
      "  --dir DIR       where, on the mappers' machine (default: each one's --out folder;\n"
      "                  for every mapper, DIR/<process>)\n"
      "  --wait S        how long to wait for answers (default 10); stops early when the named\n"
      "                  process answered, or 2 s after the last answer from every mapper\n"
      "  Exit status: 0 all answers ok, 1 a mapper could not write, 3 nobody answered.\n");
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
    return 1;
  }
  omni::map_save_request_t req{};
  req.utime = omni::SystemClock().NowUtime();
  // Answers to another sender's request carry its number, not ours.
  req.seq = (static_cast<int64_t>(getpid()) << 32) ^ (req.utime & 0xffffffff);
  req.process = process;
  req.directory = dir;
  int answers = 0, failures = 0;
  const auto hard_deadline = std::chrono::steady_clock::now() +
                             std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                 std::chrono::duration<double>(wait_s));
  auto deadline = hard_deadline;
  (*bus)->Subscribe<omni::map_save_reply_t>(
      omni::bus::kMapSaveReplyChannel, [&](const omni::map_save_reply_t& m, int64_t) {
        if (m.seq != req.seq) return;
        ++answers;
        failures += !m.ok;
        std::printf("%s: %s: %s\n", m.process.c_str(), m.ok ? "saved" : "FAILED",
                    m.message.c_str());
        // Every mapper answers within a loop round (seconds at most, during a global
        // optimisation): 2 s without a new answer ends the wait.
        deadline =
            std::min(hard_deadline, std::chrono::steady_clock::now() + std::chrono::seconds(2));
      });
  if (!(*bus)->Publish(omni::bus::kMapSaveChannel, req)) {
    std::fprintf(stderr, "omni-save-map: publishing on %s failed\n", omni::bus::kMapSaveChannel);
    return 1;
  }
  while (std::chrono::steady_clock::now() < deadline && !(!process.empty() && answers > 0)) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if ((*bus)->HandleTimeout(static_cast<int>(std::max<int64_t>(1, left.count()))) < 0) break;
  }
  if (answers == 0) {
    std::fprintf(stderr, "omni-save-map: no %s answered within %g s\n",
                 process.empty() ? "mapper" : process.c_str(), wait_s);
    return 3;
  }
  return failures > 0 ? 1 : 0;
}
