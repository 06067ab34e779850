// The heartbeat every process publishes on HEARTBEAT about once a second: state, bus
// counters, CPU and memory, and the process's own counters (checksum errors, resyncs, ...).
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/common/time.h"

namespace omni::bus {

class Heartbeat {
 public:
  Heartbeat(Bus* bus, std::string process_name, const Clock* clock, int64_t period_us = 1000000);

  // A named counter read at every heartbeat (e.g. "checksum_errors").
  void AddCounter(const std::string& name, std::function<int64_t()> read);
  // heartbeat_t::STATE_* and a short text shown by lcm-spy and the supervisor.
  void SetState(int8_t state, std::string text);
  // Publishes when at least one period passed since the last one (or `force`), or when the
  // clock was set back since (the period then counts from the step). Returns true when it
  // published. `uptime_us` adds up the clock's forward steps between calls, so a clock set back
  // neither makes it negative nor holds it.
  bool Tick(bool force = false);
  int64_t published() const { return published_; }

 private:
  Bus* bus_;
  std::string process_;
  const Clock* clock_;
  int64_t period_us_;
  int64_t prev_utime_;  // the clock at the previous Tick
  int64_t uptime_us_ = 0;
  int64_t last_utime_ = 0;
  int64_t last_cpu_us_ = 0;
  int64_t last_mono_us_ = 0;
  int8_t state_ = 0;
  std::string text_;
  int64_t published_ = 0;
  std::vector<std::pair<std::string, std::function<int64_t()>>> counters_;
};

// Resident memory of this process in MiB (from /proc/self/statm), -1 if unknown.
float ResidentMemoryMb();
// Peak resident memory of this process in MiB (VmHWM), -1 if unknown.
float PeakResidentMemoryMb();
// User+system CPU time of this process, microseconds.
int64_t ProcessCpuMicros();

}  // namespace omni::bus
