// supervisor process: starts the processes of config/supervisor.yaml, restarts them when they
// exit or their HEARTBEAT stops, reports in its own HEARTBEAT, and stops them all on
// SIGINT/SIGTERM/SIGHUP/SIGQUIT.

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/bus/node_loop.h"
#include "omni/common/cli.h"
#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/common/time.h"
#include "omni/heartbeat_t.hpp"
#include "omni/supervisor/supervisor.h"

namespace {

void IgnoreSignal(int) {}

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: supervisor --config FILE [--url LCM_URL] [--duration-s S]\n"
      "  Starts every process of FILE's `children` (in order), watches its exit and, when the\n"
      "  child has a `heartbeat` name, its HEARTBEAT on the bus; restarts it per `restart`\n"
      "  (always | on-failure | never) with a doubling backoff, kills and restarts a child whose\n"
      "  heartbeat stops, gives up on one that keeps failing. Publishes HEARTBEAT (process\n"
      "  \"supervisor\": children running, starts, restarts, failures, heartbeat timeouts, given\n"
      "  up; the text names the children that are down). SIGINT/SIGTERM/SIGHUP/SIGQUIT (or S\n"
      "  seconds) stops the children one at a time, newest first (SIGTERM, then SIGKILL after\n"
      "  their stop_grace_s), then kills what they left behind. Exits by itself when no child is\n"
      "  left to run. Exit status 0 when every child's last exit was clean, 1 otherwise.\n");
}

}  // namespace

int main(int argc, char** argv) {
  std::string config_path, url;
  double duration_s = 0;
  omni::ArgReader args(argc, argv, "supervisor", Usage);
  while (args.Next()) {
    if (args.Is("--config")) {
      config_path = args.Value();
    } else if (args.IsUrl()) {
      url = args.Value();
    } else if (args.Is("--duration-s")) {
      duration_s = args.Number(0, 1e9);
    } else {
      args.Unknown();
    }
  }
  if (config_path.empty()) {
    std::fprintf(stderr, "supervisor: --config FILE is required (see config/supervisor.yaml)\n");
    return 2;
  }
  omni::SetLogProcessName("supervisor");
  auto reader = omni::ConfigReader::FromFile(config_path);
  if (!reader.ok()) {
    std::fprintf(stderr, "supervisor: %s\n", reader.error().message.c_str());
    return 1;
  }
  auto opt = omni::supervisor::SupervisorOptions::Load(*reader);
  if (!opt.ok()) {
    std::fprintf(stderr, "supervisor: bad config:\n%s\n", opt.error().message.c_str());
    return 1;
  }
  auto bus_or = omni::bus::Bus::Create(url);
  if (!bus_or.ok()) {
    std::fprintf(stderr, "supervisor: %s\n", bus_or.error().message.c_str());
    return 1;
  }
  // The children run on the supervisor's bus: it hears their heartbeats only there (with --url
  // on another bus than theirs, each would have been killed as hung after its grace time). A
  // child's own --url in its command line still wins.
  if (!url.empty()) setenv("LCM_DEFAULT_URL", url.c_str(), 1);
  auto& bus = **bus_or;
  omni::SystemClock clock;
  // What a child leaves behind outside its process group (the worker of a wrapper, a daemon) is
  // reparented here instead of to init: reaped, and killed when the stop is done.
  if (omni::Status st = omni::supervisor::PosixLauncher::BecomeSubreaper(); !st.ok()) {
    LOG_WARN << st.error().message << ": what the children leave behind may outlive them";
  }
  omni::supervisor::PosixLauncher launcher;
  omni::supervisor::Supervisor sup(*opt, &launcher);
  bus.Subscribe<omni::heartbeat_t>(opt->channel, [&](const omni::heartbeat_t& h, int64_t) {
    if (h.process != "supervisor")
      sup.OnHeartbeat(h.process, h.pid, h.state, h.status_text, omni::MonotonicMicros());
  });
  omni::bus::Heartbeat hb(&bus, "supervisor", &clock);
  hb.AddCounter("children", [&] { return static_cast<int64_t>(sup.children().size()); });
  hb.AddCounter("running", [&] { return static_cast<int64_t>(sup.running()); });
  using CS = omni::supervisor::ChildStatus;
  hb.AddCounter("starts", [&] { return sup.total(&CS::starts); });
  hb.AddCounter("restarts", [&] { return sup.total(&CS::restarts); });
  hb.AddCounter("failures", [&] { return sup.total(&CS::failures); });
  hb.AddCounter("heartbeat_timeouts", [&] { return sup.total(&CS::heartbeat_timeouts); });
  hb.AddCounter("start_errors", [&] { return sup.total(&CS::start_errors); });
  hb.AddCounter("gave_up", [&] { return sup.gave_up(); });
  hb.AddCounter("foreign_heartbeats", [&] { return sup.foreign_heartbeats(); });
  omni::bus::InstallStopSignals();
  omni::FixMallocThresholds();  // large buffers go back to the system when freed
  // A log line written to a pipe whose reader is gone (`supervisor | tee`, with tee ended by the
  // same hangup) must not end the stop half way: the write fails instead. (A handler, not
  // SIG_IGN, so that the children get the default back at exec.)
  std::signal(SIGPIPE, IgnoreSignal);
  const int64_t t0 = omni::MonotonicMicros();
  sup.Start(t0);
  LOG_INFO << "started " << sup.children().size() << " processes (bus "
           << (url.empty() ? "default" : url) << ")";
  std::string last_summary;
  auto report = [&] {
    const std::string summary = sup.Summary();
    hb.SetState(sup.Healthy()       ? omni::heartbeat_t::STATE_OK
                : sup.gave_up() > 0 ? omni::heartbeat_t::STATE_ERROR
                                    : omni::heartbeat_t::STATE_DEGRADED,
                summary);
    if (summary != last_summary) {
      LOG_INFO << summary;
    }
    last_summary = summary;
  };
  bool done = false;
  while (!omni::bus::StopRequested() && !done) {
    bus.HandleTimeout(50);
    const int64_t now = omni::MonotonicMicros();
    sup.Tick(now);
    report();
    hb.Tick();
    if (duration_s > 0 && now - t0 > static_cast<int64_t>(duration_s * 1e6)) break;
    done = sup.Finished();
  }
  LOG_INFO << (done ? "no process left to run" : "stopping every process");
  hb.SetState(omni::heartbeat_t::STATE_STOPPING, "stopping the processes");
  hb.Tick(true);
  sup.StopAll(omni::MonotonicMicros());
  while (!sup.AllStopped()) {
    bus.HandleTimeout(20);
    sup.Tick(omni::MonotonicMicros());
    hb.Tick();  // still visible (STOPPING) while the mappers write their maps
  }
  if (const int left = launcher.KillLeftovers(); left > 0) {
    LOG_INFO << "killed " << left << " processes the children left behind";
  }
  int exit_code = 0;
  for (size_t i = 0; i < sup.children().size(); ++i) {
    const CS& s = sup.children()[i];
    std::printf(
        "supervisor: %s: %lld starts, %lld restarts, %lld failures, %lld heartbeat "
        "timeouts, %s\n",
        opt->children[i].name.c_str(), static_cast<long long>(s.starts),
        static_cast<long long>(s.restarts), static_cast<long long>(s.failures),
        static_cast<long long>(s.heartbeat_timeouts),
        s.state == omni::supervisor::ChildState::kGaveUp ? "given up" : "stopped");
    if (s.state == omni::supervisor::ChildState::kGaveUp || (s.last_exit && s.last_exit->failed()))
      exit_code = 1;
  }
  return exit_code;
}
