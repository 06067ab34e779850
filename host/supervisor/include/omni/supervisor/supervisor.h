// The supervisor: starts the stack's processes, watches them (their exit, and their HEARTBEAT
// on the bus) and restarts them. The library of the supervisor process: no LCM, no clock, no
// fork — the process feeds it heartbeats and the time, and a Launcher starts and signals the
// children (PosixLauncher on the robot, a fake in tests).
//
// Per child:
// - it is started at Start(), and restarted after an exit according to `restart` (always, on
//   failure — a non-zero exit status or a signal —, never), after a backoff that starts at
//   backoff_initial_s and doubles up to backoff_max_s; the backoff goes back to its initial value
//   once a start has lived longer than backoff_max_s;
// - with `heartbeat` set (the `process` name in the child's heartbeat_t), a child whose first
//   heartbeat has not come start_grace_s after its start, or whose heartbeats stop for
//   heartbeat_timeout_s, is hung: it gets SIGTERM, SIGKILL stop_grace_s later if still there,
//   and is restarted (unless `restart: never`);
// - more than max_restarts restarts within restart_window_s: the supervisor gives up on it
//   (state kGaveUp, counted, reported) instead of restarting forever.
// - with `after` (names of other children), it is started only once each of them is running —
//   its first heartbeat has come, or it was started if it has no heartbeat — (state kWaiting
//   until then), so a mapper starts after the drivers and the base bridge are up. It waits
//   only for its first start: later restarts of either side do not cascade. A child that ended
//   for good (exited with no restart to come, or given up) holds no one back, so a one-shot
//   (e.g. bringing a CAN interface up) can come first.
// A child's heartbeat state (e.g. ERROR while a driver's device is away) is reported, not acted
// on: the drivers reconnect by themselves.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "omni/common/config.h"
#include "omni/common/result.h"

namespace omni::supervisor {

enum class RestartPolicy { kAlways, kOnFailure, kNever };

struct ChildSpec {
  std::string name;
  std::vector<std::string> command;  // argv; command[0] by path or looked up in PATH
  std::string heartbeat;             // heartbeat_t.process to watch ("" = exit watching only)
  double heartbeat_timeout_s = 5.0;
  double start_grace_s = 15.0;
  RestartPolicy restart = RestartPolicy::kOnFailure;
  int max_restarts = 5;
  double restart_window_s = 300.0;
  double backoff_initial_s = 1.0;
  double backoff_max_s = 30.0;
  double stop_grace_s = 5.0;
  std::vector<std::string> after;  // children that must be running before the first start
};

// Every omni process heartbeats once a second: a shorter heartbeat_timeout_s than this would
// kill children that are fine (a heartbeat a little late, one lost datagram).
constexpr double kMinHeartbeatTimeoutS = 2.0;
// The channel bus::Heartbeat publishes on, the only one the supervisor can listen to.
constexpr const char* kHeartbeatChannel = "HEARTBEAT";

struct SupervisorOptions {
  std::vector<ChildSpec> children;          // in config order: started in this order
  std::string working_dir;                  // "" = the supervisor's own
  std::string channel = kHeartbeatChannel;  // `channel:` may only say HEARTBEAT
  // `children:` is a map from a name to that child's keys (command required); unknown keys,
  // bad values (a heartbeat_timeout_s under kMinHeartbeatTimeoutS, a channel other than
  // HEARTBEAT), an `after` naming no child (or itself) and a cycle of `after`s are errors naming
  // them.
  static Result<SupervisorOptions> Load(ConfigReader& reader);
};

// A one-shot: a child that runs to its end (`restart: never` and no heartbeat to watch), such
// as bringing can0 up. `after:` waits for it to finish, and its clean exit counts as healthy.
inline bool IsOneShot(const ChildSpec& c) {
  return c.restart == RestartPolicy::kNever && c.heartbeat.empty();
}

struct ExitInfo {
  int code = 0;    // exit status when it exited
  int signal = 0;  // the signal that ended it (0: it exited)
  bool failed() const { return signal != 0 || code != 0; }
};

// Starts and signals child processes.
class Launcher {
 public:
  virtual ~Launcher() = default;
  // Starts `command` in `working_dir` ("" = current); the child's pid.
  virtual Result<int> Start(const std::vector<std::string>& command,
                            const std::string& working_dir) = 0;
  // The child's exit once it has ended (reaped), nullopt while it runs. What it leaves in its
  // process group is the caller's to kill (KillGroup): after a stop was asked, a wrapper's
  // worker may still be writing its map when the wrapper has gone.
  virtual std::optional<ExitInfo> Poll(int pid) = 0;
  virtual void Signal(int pid, int signal) = 0;
  // Whether any process is left in the group of the child `pid` (after Poll gave its exit).
  virtual bool GroupAlive(int pid) {
    (void)pid;
    return false;
  }
  // Kills (SIGKILL) what is left in the group of the child `pid`.
  virtual void KillGroup(int pid) { (void)pid; }
  // Whether a heartbeat that says it comes from `reported_pid` is the child `child_pid`'s: the
  // child itself or a process in its group (a wrapper script's worker).
  virtual bool Owns(int child_pid, int reported_pid) const {
    (void)child_pid;
    (void)reported_pid;
    return true;
  }
};

// fork + execvp; the child gets SIGTERM if the supervisor dies (PR_SET_PDEATHSIG), its own
// process group, the supervisor's stdin/stdout/stderr and no other descriptor (descriptors 3 and
// up, e.g. the supervisor's LCM sockets, are closed before the exec). A command that cannot be
// executed exits 127 (seen as a failure, so restarted with backoff and in the end given up).
// Signals go to the child's whole process group, so the worker of a wrapper (`sh -c '...'`) is
// stopped with it, and what is left of the group when the child has exited is killed by the
// supervisor (an orphan would hold the serial port the restarted driver needs) — after a stop
// it asked for, once the group has ended or the stop grace has passed.
//
// Poll reaps every ended child of this process: the started ones (their exit kept for their
// Poll) and those adopted as their subreaper (BecomeSubreaper), counted as orphans_reaped().
class PosixLauncher final : public Launcher {
 public:
  // Makes this process the subreaper of its descendants (PR_SET_CHILD_SUBREAPER): a process
  // that a child leaves behind outside its group (a daemon that made its own session, the
  // worker of a wrapper whose group was signalled late) is reparented here instead of to init,
  // so Poll reaps it and KillLeftovers can find it.
  static Status BecomeSubreaper();

  Result<int> Start(const std::vector<std::string>& command,
                    const std::string& working_dir) override;
  std::optional<ExitInfo> Poll(int pid) override;
  void Signal(int pid, int signal) override;
  bool Owns(int child_pid, int reported_pid) const override;
  bool GroupAlive(int pid) override;
  void KillGroup(int pid) override;

  // Kills (SIGKILL) and reaps every child process of this one that is not a started child
  // still running — with BecomeSubreaper, what the children left behind — and their
  // descendants (each reparented here in turn), for up to `max_wait_s`. At the end of a stop,
  // once every child has been reaped. Returns how many processes it killed.
  int KillLeftovers(double max_wait_s = 3.0);
  int64_t orphans_reaped() const { return orphans_reaped_; }

 private:
  void Reap();  // waitpid(-1) until nothing more has ended

  std::set<int> running_;     // started and not reaped yet
  std::map<int, int> ended_;  // reaped, wait status not yet returned by Poll
  int64_t orphans_reaped_ = 0;
};

enum class ChildState { kWaiting, kBackoff, kStarting, kRunning, kStopping, kExited, kGaveUp };
const char* ChildStateName(ChildState s);

struct ChildStatus {
  ChildState state = ChildState::kBackoff;
  int pid = -1;
  int64_t starts = 0, restarts = 0, exits = 0, failures = 0, heartbeat_timeouts = 0;
  int64_t start_errors = 0;  // Launcher::Start failed (e.g. fork)
  std::optional<ExitInfo> last_exit;
  int64_t started_us = 0, last_heartbeat_us = 0, stop_deadline_us = 0, next_start_us = 0;
  int8_t heartbeat_state = -1;  // the child's last heartbeat_t.state (-1: none yet)
  std::string heartbeat_text;
  double backoff_s = 0;
  bool restart_after_stop = false;
  bool healthy_when_stopped = false;  // running and not reporting trouble when asked to stop
  std::deque<int64_t> restart_times_us;
  int64_t first_start = -1;  // its place in the order the children were first started
  // Stopping: the child (a wrapper) has ended, what it started in its group has not yet; its
  // exit is held until the group has ended or the stop grace has passed.
  std::optional<ExitInfo> leader_exit;
  int64_t group_killed_us = 0;  // when the SIGKILL went to such a group (waited 3 s at most)
};

class Supervisor {
 public:
  Supervisor(SupervisorOptions options, Launcher* launcher);

  // Starts every child (in order).
  void Start(int64_t now_us);
  // Reaps exits, acts on silent children, kills those past their stop grace, restarts the due.
  void Tick(int64_t now_us);
  // A heartbeat from `process` (its heartbeat_t.process and .pid) with its state and text. One
  // whose pid is not the child's (Launcher::Owns) is not the child's: a stale instance, the
  // same process name on another machine, a replayed log. It is counted, not taken.
  void OnHeartbeat(const std::string& process, int pid, int8_t state, const std::string& text,
                   int64_t now_us);
  int64_t foreign_heartbeats() const { return foreign_heartbeats_; }
  // Stops every child, one at a time, in the reverse of the order they were first started (so
  // a child is stopped before what it waited for with `after`, and a restart does not move it;
  // SIGTERM, SIGKILL after its stop grace; the next once it is gone), and restarts none; keep
  // calling Tick until AllStopped().
  void StopAll(int64_t now_us);
  bool AllStopped() const;
  // Every child running and none reporting DEGRADED or ERROR in its heartbeat.
  bool Healthy() const;
  // A one-shot ran to a clean end (restart: never, no heartbeat, exit 0).
  bool FinishedOneShot(size_t i) const;
  // Nothing left to run: every child exited for good or was given up.
  bool Finished() const;

  const SupervisorOptions& options() const { return o_; }
  const std::vector<ChildStatus>& children() const { return st_; }
  int running() const;  // children in kStarting or kRunning
  int64_t total(int64_t ChildStatus::*field) const;
  int64_t gave_up() const;
  // "all 5 running" or the names of the children that are not, with why.
  std::string Summary() const;

 private:
  int64_t next_first_start_ = 0;
  void Launch(size_t i, int64_t now_us);
  void OnExit(size_t i, const ExitInfo& e, int64_t now_us);
  void Stop(size_t i, int64_t now_us, bool restart);
  void ScheduleRestart(size_t i, int64_t now_us);
  void StopNext(int64_t now_us);
  // The names in child i's `after` that are not running yet ("" when none).
  std::string WaitingFor(size_t i) const;

  SupervisorOptions o_;
  Launcher* launcher_;
  std::vector<ChildStatus> st_;
  bool stopping_all_ = false;
  int64_t foreign_heartbeats_ = 0;
};

}  // namespace omni::supervisor
