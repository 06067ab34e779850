#include "omni/bus/node_loop.h"

#include <signal.h>

#include <csignal>

#include "omni/common/log.h"
#include "omni/common/stop_signals.h"
#include "omni/common/time.h"

namespace omni::bus {
namespace {
volatile std::sig_atomic_t g_stop = 0;
void OnStopSignal(int) { g_stop = 1; }
}  // namespace

void InstallStopSignals() {
  struct sigaction sa {};
  sa.sa_handler = OnStopSignal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;
  for (const int sig : {SIGINT, SIGTERM, SIGQUIT}) sigaction(sig, &sa, nullptr);
  AlsoStopOnHangup(OnStopSignal);
}

bool StopRequested() { return g_stop != 0; }

const char* LoopEndName(LoopEnd e) {
  switch (e) {
    case LoopEnd::kSignal:
      return "signal";
    case LoopEnd::kBusEnded:
      return "end of input";
    case LoopEnd::kIdle:
      return "idle";
  }
  return "?";
}

LoopEnd RunNodeLoop(Bus& bus, const NodeLoopOptions& options, const std::function<int()>& process,
                    const std::function<void()>& tick) {
  int64_t last_msg_us = 0;
  bool bus_ended = false;
  int processed = 0;
  while (!g_stop) {
    // Block (briefly) only when the last round found nothing to do.
    int r = bus_ended ? 0 : bus.HandleTimeout(processed > 0 ? 0 : 100);
    while (r > 0 && !g_stop) {
      last_msg_us = MonotonicMicros();
      r = bus.HandleTimeout(0);
    }
    if (r < 0 && !g_stop && !bus_ended) {
      LOG_INFO << "bus ended (end of log) or failed; finishing the queue";
      bus_ended = true;
    }
    processed = process();
    tick();
    if (bus_ended && processed == 0) return LoopEnd::kBusEnded;
    if (options.idle_exit_s > 0 && last_msg_us > 0 && processed == 0 &&
        MonotonicMicros() - last_msg_us > static_cast<int64_t>(options.idle_exit_s * 1e6))
      return LoopEnd::kIdle;
  }
  return LoopEnd::kSignal;
}

}  // namespace omni::bus
