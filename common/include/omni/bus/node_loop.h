// The main loop shared by the mapper processes (rbpf_mapper, pose_graph_mapper): wait for bus
// traffic only when nothing is ready, empty the socket into the node's queues before each unit of
// work (so a slow update never leaves datagrams to overflow the kernel's receive buffer), tick
// the node, and stop on SIGINT/SIGTERM/SIGHUP/SIGQUIT, at the end of a file:// log once the
// queues are empty, or after an idle period without messages.
#pragma once

#include <functional>

#include "omni/bus/bus.h"
#include "omni/common/stop_signals.h"

namespace omni::bus {

// SIGINT, SIGTERM, SIGHUP (the terminal or SSH session went away) and SIGQUIT (Ctrl+backslash)
// set a flag that StopRequested() reads (and that ends RunNodeLoop), so the process stops in
// order (a mapper writes its map) instead of dying at once. A SIGHUP ignored when this is called
// (`nohup`) stays ignored. SIGPIPE is ignored: a log line to a closed pipe fails instead of
// killing the process mid-stop.
void InstallStopSignals();
// For a process with its own stop handler: omni/common/stop_signals.h.
using omni::AlsoStopOnHangup;
bool StopRequested();

enum class LoopEnd { kSignal, kBusEnded, kIdle };
const char* LoopEndName(LoopEnd e);

// The exit status of a mapper that has nothing to write: 0 when it was stopped (systemctl stop,
// Ctrl-C) before any input arrived (nothing lost), 1 otherwise (input came and none of it could
// be used, or a log ended with nothing mapped: a fault to see).
inline int NothingToWriteExit(LoopEnd end, int64_t inputs_in) {
  return end == LoopEnd::kSignal && inputs_in == 0 ? 0 : 1;
}

struct NodeLoopOptions {
  double idle_exit_s = 0;  // > 0: stop this long after the last message once nothing is ready
};

// `process` does one unit of queued work and returns how many items it handled (0: nothing was
// ready); `tick` runs after every round (heartbeat, periodic publications).
LoopEnd RunNodeLoop(Bus& bus, const NodeLoopOptions& options, const std::function<int()>& process,
                    const std::function<void()>& tick);

}  // namespace omni::bus
