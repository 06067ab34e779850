#include "omni/bus/heartbeat.h"

#include <cstdio>
#include <fstream>
#include <string>

#include <sys/resource.h>
#include <unistd.h>

#include "omni/heartbeat_t.hpp"

namespace omni::bus {

float ResidentMemoryMb() {
  std::ifstream f("/proc/self/statm");
  long pages_total = 0, pages_rss = 0;
  if (!(f >> pages_total >> pages_rss)) return -1.f;
  return static_cast<float>(pages_rss) * static_cast<float>(sysconf(_SC_PAGESIZE)) /
         (1024.f * 1024.f);
}

float PeakResidentMemoryMb() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stof(line.substr(6)) / 1024.f;
  }
  return -1.f;
}

int64_t ProcessCpuMicros() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return (ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) * 1000000LL + ru.ru_utime.tv_usec +
         ru.ru_stime.tv_usec;
}

Heartbeat::Heartbeat(Bus* bus, std::string process_name, const Clock* clock, int64_t period_us)
    : bus_(bus),
      process_(std::move(process_name)),
      clock_(clock),
      period_us_(period_us),
      prev_utime_(clock->NowUtime()) {
  last_cpu_us_ = ProcessCpuMicros();
  last_mono_us_ = MonotonicMicros();
}

void Heartbeat::AddCounter(const std::string& name, std::function<int64_t()> read) {
  counters_.emplace_back(name, std::move(read));
}

void Heartbeat::SetState(int8_t state, std::string text) {
  state_ = state;
  text_ = std::move(text);
}

bool Heartbeat::Tick(bool force) {
  const int64_t now = clock_->NowUtime();
  if (now > prev_utime_) uptime_us_ += now - prev_utime_;
  prev_utime_ = now;
  if (!force && !PeriodDue(now, last_utime_, period_us_)) return false;
  omni::heartbeat_t hb;
  hb.utime = now;
  hb.process = process_;
  hb.pid = static_cast<int32_t>(getpid());
  hb.state = state_;
  hb.status_text = text_;
  hb.uptime_us = uptime_us_;
  const BusCounters& c = bus_->counters();
  hb.msgs_in = c.msgs_in;
  hb.msgs_out = c.msgs_out + 1;  // counts this heartbeat
  hb.decode_errors = c.decode_errors;
  hb.drops = c.drops;
  const int64_t cpu = ProcessCpuMicros();
  const int64_t mono = MonotonicMicros();
  hb.cpu_percent = mono > last_mono_us_ ? 100.f * static_cast<float>(cpu - last_cpu_us_) /
                                              static_cast<float>(mono - last_mono_us_)
                                        : 0.f;
  last_cpu_us_ = cpu;
  last_mono_us_ = mono;
  hb.rss_mb = ResidentMemoryMb();
  for (const auto& [name, read] : counters_) {
    hb.counter_names.push_back(name);
    hb.counter_values.push_back(read());
  }
  hb.counter_names.push_back("publish_errors");
  hb.counter_values.push_back(c.publish_errors);
  if (c.log_framing_errors > 0) {  // only a process reading a corrupt log (file://)
    hb.counter_names.push_back("log_framing_errors");
    hb.counter_values.push_back(c.log_framing_errors);
  }
  hb.num_counters = static_cast<int32_t>(hb.counter_names.size());
  last_utime_ = now;
  if (!bus_->Publish("HEARTBEAT", hb)) return false;
  ++published_;
  return true;
}

}  // namespace omni::bus
