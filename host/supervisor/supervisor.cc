#include "omni/supervisor/supervisor.h"

#include <dirent.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>

namespace omni::supervisor {

namespace {
constexpr int64_t kUs = 1000000;
int64_t Us(double s) { return static_cast<int64_t>(s * 1e6); }
}  // namespace

Result<SupervisorOptions> SupervisorOptions::Load(ConfigReader& r) {
  SupervisorOptions o;
  r.Get("working_dir", &o.working_dir, Optional());
  // bus::Heartbeat always publishes on HEARTBEAT: listening anywhere else, the supervisor would
  // hear no child and restart each one after its grace, for ever.
  r.Get("channel", &o.channel, Optional(), Rule<std::string>([](const std::string& v) {
          return v == kHeartbeatChannel
                     ? std::string()
                     : std::string(
                           "must be HEARTBEAT: every omni process publishes its heartbeat "
                           "there (no other channel can be heard)");
        }));
  auto children = r.Section("children");
  for (const std::string& name : children.Keys()) {
    ChildSpec c;
    c.name = name;
    auto s = children.Section(name);
    s.Get("command", &c.command, Required());
    if (s.Has("command") && c.command.empty()) s.AddError("command", "must not be empty");
    s.Get("heartbeat", &c.heartbeat, Optional());
    s.Get("heartbeat_timeout_s", &c.heartbeat_timeout_s, Optional(),
          Rule<double>([](const double& v) {
            return v >= kMinHeartbeatTimeoutS && v <= 3600.0
                       ? std::string()
                       : std::string(
                             "must be in [2, 3600] s: heartbeats come once a second, so a "
                             "shorter timeout kills children that are fine");
          }));
    s.Get("start_grace_s", &c.start_grace_s, Optional(), InRange(0.1, 3600.0));
    std::string restart = "on-failure";
    s.Get("restart", &restart, Optional(), OneOf({"always", "on-failure", "never"}));
    c.restart = restart == "always"  ? RestartPolicy::kAlways
                : restart == "never" ? RestartPolicy::kNever
                                     : RestartPolicy::kOnFailure;
    s.Get("max_restarts", &c.max_restarts, Optional(), InRange(0, 100000));
    s.Get("restart_window_s", &c.restart_window_s, Optional(), InRange(1.0, 1e6));
    s.Get("backoff_initial_s", &c.backoff_initial_s, Optional(), InRange(0.0, 3600.0));
    s.Get("backoff_max_s", &c.backoff_max_s, Optional(), InRange(0.0, 3600.0));
    s.Get("stop_grace_s", &c.stop_grace_s, Optional(), InRange(0.0, 600.0));
    s.Get("after", &c.after, Optional());
    for (const std::string& a : c.after) {
      const auto keys = children.Keys();
      if (a == name)
        s.AddError("after", "a process cannot wait for itself");
      else if (std::find(keys.begin(), keys.end(), a) == keys.end())
        s.AddError("after", "'" + a + "' is not one of the children");
    }
    if (c.backoff_max_s < c.backoff_initial_s)
      s.AddError("backoff_max_s", "must be >= backoff_initial_s");
    o.children.push_back(std::move(c));
  }
  if (o.children.empty()) r.AddError("children", "must name at least one process to supervise");
  // A cycle of `after`s would leave its children waiting for ever.
  const size_t n = o.children.size();
  auto index_of = [&](const std::string& name) {
    for (size_t k = 0; k < n; ++k)
      if (o.children[k].name == name) return k;
    return n;
  };
  std::vector<int> mark(n, 0);  // 0 unvisited, 1 on the path, 2 done
  std::function<bool(size_t)> cyclic = [&](size_t k) {
    if (mark[k] == 1) return true;
    if (mark[k] == 2) return false;
    mark[k] = 1;
    for (const std::string& a : o.children[k].after) {
      const size_t j = index_of(a);
      if (j < n && cyclic(j)) return true;
    }
    mark[k] = 2;
    return false;
  };
  for (size_t k = 0; k < n; ++k)
    if (mark[k] == 0 && cyclic(k)) {
      children.Section(o.children[k].name)
          .AddError("after", "the children's `after`s form a cycle through here");
      break;
    }
  if (Status st = r.Finish(); !st.ok()) return st.error();
  return o;
}

namespace {
// heartbeat_t::STATE_DEGRADED = 2, STATE_ERROR = 3: running, but saying something is wrong.
bool ReportsTrouble(const ChildStatus& s) {
  return s.heartbeat_state == 2 || s.heartbeat_state == 3;
}
}  // namespace

Result<int> PosixLauncher::Start(const std::vector<std::string>& command,
                                 const std::string& working_dir) {
  if (command.empty()) return MakeError(ErrorCode::kInvalidArgument, "empty command");
  std::vector<char*> argv;
  for (const auto& a : command) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  // Written by the child when exec fails (built here: the child only calls write and _exit).
  std::string cwd_note = working_dir.empty() ? std::string() : " (in " + working_dir + ")";
  const std::string exec_failed = "supervisor: cannot run '" + command[0] + "'" + cwd_note + ": ";
  const std::string chdir_failed =
      "supervisor: cannot enter the working directory '" + working_dir + "'\n";
  const bool path_given = command[0].find('/') != std::string::npos;
  // For closing the inherited descriptors where close_range is missing (a kernel before 5.9).
  const long open_max = sysconf(_SC_OPEN_MAX);
  const int last_fd = open_max > 0 && open_max < INT_MAX ? static_cast<int>(open_max) - 1 : 65535;
  const pid_t parent = getpid();
  // The stop signals wait until the child has its own dispositions: between fork and exec it has
  // the supervisor's handlers, and a SIGTERM then (a stop right after a restart, the death signal
  // when the supervisor dies) only set a flag in the child's copy, and the process ran on.
  constexpr int kStopSignals[] = {SIGINT, SIGTERM, SIGQUIT, SIGHUP, SIGPIPE};
  sigset_t stop_set, old_mask;
  sigemptyset(&stop_set);
  for (const int sig : kStopSignals) sigaddset(&stop_set, sig);
  pthread_sigmask(SIG_BLOCK, &stop_set, &old_mask);
  const pid_t pid = fork();
  if (pid != 0) pthread_sigmask(SIG_SETMASK, &old_mask, nullptr);
  if (pid < 0)
    return MakeError(ErrorCode::kUnavailable, std::string("fork: ") + std::strerror(errno));
  if (pid > 0) {
    setpgid(pid, pid);  // also here, so a signal right after Start finds the group
    running_.insert(pid);
  }
  if (pid == 0) {
    // Child: the default action for the stop signals the supervisor handles (one ignored by
    // whoever started the supervisor, e.g. nohup's SIGHUP, stays ignored, as exec would keep it),
    // then any that came meanwhile is delivered.
    for (const int sig : kStopSignals) {
      struct sigaction cur {};
      if (sigaction(sig, nullptr, &cur) == 0 && cur.sa_handler != SIG_IGN) {
        struct sigaction dfl {};
        dfl.sa_handler = SIG_DFL;
        sigemptyset(&dfl.sa_mask);
        sigaction(sig, &dfl, nullptr);
      }
    }
    sigprocmask(SIG_SETMASK, &old_mask, nullptr);
    // Die with the supervisor, own process group (a terminal's Ctrl-C goes to the supervisor,
    // which stops the children in order).
    prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (getppid() != parent) _exit(126);
    setpgid(0, 0);
    if (!working_dir.empty() && chdir(working_dir.c_str()) != 0) {
      ssize_t w = write(2, chdir_failed.data(), chdir_failed.size());
      (void)w;
      _exit(126);
    }
    // Only stdin, stdout and stderr (the supervisor's) go to the child: not the supervisor's LCM
    // sockets and pipes, nor whatever it inherited (a child holding them keeps them open after
    // the supervisor is gone, and can read or write on its bus sockets).
    if (close_range(3, ~0U, 0) != 0)
      for (int fd = 3; fd <= last_fd; ++fd) close(fd);
    execvp(argv[0], argv.data());
    // Say why (not found, not executable) on the supervisor's stderr, which the child shares:
    // a bare exit 127 restarted in a loop tells nobody that a relative path was wrong.
    const int e = errno;
    const char* not_found =
        path_given ? "not found (a relative path is taken from the working directory)\n"
                   : "not found on PATH\n";
    const char* why = e == ENOENT ? not_found : e == EACCES ? "not executable\n" : "exec failed\n";
    ssize_t w = write(2, exec_failed.data(), exec_failed.size());
    w = write(2, why, std::strlen(why));
    (void)w;
    _exit(127);
  }
  return static_cast<int>(pid);
}

Status PosixLauncher::BecomeSubreaper() {
  if (prctl(PR_SET_CHILD_SUBREAPER, 1) != 0)
    return MakeError(ErrorCode::kUnavailable,
                     std::string("prctl(PR_SET_CHILD_SUBREAPER): ") + std::strerror(errno));
  return Status::Ok();
}

void PosixLauncher::Reap() {
  int status = 0;
  pid_t r;
  while ((r = waitpid(-1, &status, WNOHANG)) > 0) {
    if (running_.erase(r) > 0)
      ended_[r] = status;
    else
      ++orphans_reaped_;  // adopted (subreaper): what a child left behind
  }
}

std::optional<ExitInfo> PosixLauncher::Poll(int pid) {
  Reap();
  ExitInfo e;
  auto it = ended_.find(pid);
  if (it == ended_.end()) {
    if (running_.count(pid) > 0) return std::nullopt;
    e.code = 255;  // not our child (should not happen): treat as a failed exit
    return e;
  }
  const int status = it->second;
  ended_.erase(it);
  if (WIFSIGNALED(status)) e.signal = WTERMSIG(status);
  if (WIFEXITED(status)) e.code = WEXITSTATUS(status);
  return e;
}

// (A group's id stays taken while any member lives, so these reach no unrelated process.)
bool PosixLauncher::GroupAlive(int pid) {
  Reap();  // a worker that ended, adopted here (subreaper), is a zombie in the group until then
  return pid > 0 && kill(-pid, 0) == 0;
}

void PosixLauncher::KillGroup(int pid) {
  if (pid > 0) kill(-pid, SIGKILL);
}

void PosixLauncher::Signal(int pid, int sig) {
  if (pid <= 0) return;
  if (kill(-pid, sig) == 0) return;  // the group
  // The child itself if it has no group yet; not one already reaped (by another child's Poll):
  // its pid may have been given to an unrelated process since.
  if (running_.count(pid) > 0) kill(pid, sig);
}

namespace {
// The processes whose parent is `parent` and that have not ended (from /proc/PID/stat).
std::vector<int> LiveChildrenOf(pid_t parent) {
  std::vector<int> kids;
  DIR* proc = opendir("/proc");
  if (proc == nullptr) return kids;
  while (const dirent* d = readdir(proc)) {
    char* end = nullptr;
    const long pid = std::strtol(d->d_name, &end, 10);
    if (pid <= 0 || *end != '\0') continue;
    std::ifstream stat(std::string("/proc/") + d->d_name + "/stat");
    std::string line;
    if (!std::getline(stat, line)) continue;
    // pid (comm) state ppid ...: comm may hold spaces and parentheses, so parse after the last ')'.
    const auto paren = line.rfind(')');
    if (paren == std::string::npos || paren + 2 >= line.size()) continue;
    const char state = line[paren + 2];
    const long ppid = std::strtol(line.c_str() + paren + 3, nullptr, 10);
    if (ppid == parent && state != 'Z' && state != 'X') kids.push_back(static_cast<int>(pid));
  }
  closedir(proc);
  return kids;
}
}  // namespace

int PosixLauncher::KillLeftovers(double max_wait_s) {
  std::set<int> killed;
  const pid_t self = getpid();
  const int rounds = std::max(1, static_cast<int>(max_wait_s * 100));
  for (int k = 0; k < rounds; ++k) {
    Reap();
    bool any = false;
    for (const int pid : LiveChildrenOf(self)) {
      if (running_.count(pid) > 0) continue;  // a started child: stopped by its own Signal
      kill(pid, SIGKILL);  // (its own children come here in turn, and go the next round)
      killed.insert(pid);
      any = true;
    }
    if (!any) break;
    usleep(10000);
  }
  Reap();
  return static_cast<int>(killed.size());
}

bool PosixLauncher::Owns(int child_pid, int reported_pid) const {
  if (reported_pid <= 0 || child_pid <= 0) return false;
  return reported_pid == child_pid || getpgid(reported_pid) == child_pid;
}

const char* ChildStateName(ChildState s) {
  switch (s) {
    case ChildState::kWaiting:
      return "waiting";
    case ChildState::kBackoff:
      return "waiting to restart";
    case ChildState::kStarting:
      return "starting";
    case ChildState::kRunning:
      return "running";
    case ChildState::kStopping:
      return "stopping";
    case ChildState::kExited:
      return "exited";
    case ChildState::kGaveUp:
      return "gave up";
  }
  return "?";
}

Supervisor::Supervisor(SupervisorOptions options, Launcher* launcher)
    : o_(std::move(options)), launcher_(launcher), st_(o_.children.size()) {
  for (size_t i = 0; i < st_.size(); ++i) st_[i].backoff_s = o_.children[i].backoff_initial_s;
}

void Supervisor::Start(int64_t now_us) {
  for (size_t i = 0; i < st_.size(); ++i) {
    if (o_.children[i].after.empty())
      Launch(i, now_us);
    else
      st_[i].state = ChildState::kWaiting;
  }
  Tick(now_us);  // those whose `after`s run without heartbeats can start at once
}

std::string Supervisor::WaitingFor(size_t i) const {
  std::string names;
  for (const std::string& a : o_.children[i].after)
    for (size_t k = 0; k < st_.size(); ++k) {
      if (o_.children[k].name != a) continue;
      // A child that ended for good (a one-shot that exited, or one given up) holds no one back:
      // waiting for it would be for ever. A one-shot (restart: never, no heartbeat) is waited
      // for until it has finished, not merely started: `ip link set can0 up` must be done.
      const bool one_shot = IsOneShot(o_.children[k]);
      const bool ended = st_[k].state == ChildState::kExited || st_[k].state == ChildState::kGaveUp;
      const bool up = st_[k].state == ChildState::kRunning && !one_shot;
      if (!ended && !up) names += (names.empty() ? "" : ", ") + a;
    }
  return names;
}

void Supervisor::Launch(size_t i, int64_t now_us) {
  ChildStatus& s = st_[i];
  auto pid = launcher_->Start(o_.children[i].command, o_.working_dir);
  if (!pid.ok()) {
    ++s.start_errors;
    ScheduleRestart(i, now_us);
    return;
  }
  s.pid = *pid;
  if (s.first_start < 0) s.first_start = next_first_start_++;
  ++s.starts;
  s.started_us = now_us;
  s.last_heartbeat_us = 0;
  s.heartbeat_state = -1;
  s.restart_after_stop = false;
  s.state = o_.children[i].heartbeat.empty() ? ChildState::kRunning : ChildState::kStarting;
}

void Supervisor::ScheduleRestart(size_t i, int64_t now_us) {
  const ChildSpec& c = o_.children[i];
  ChildStatus& s = st_[i];
  while (!s.restart_times_us.empty() &&
         now_us - s.restart_times_us.front() > Us(c.restart_window_s))
    s.restart_times_us.pop_front();
  if (static_cast<int>(s.restart_times_us.size()) >= c.max_restarts) {
    s.state = ChildState::kGaveUp;
    s.pid = -1;
    return;
  }
  // A start that lived longer than the longest backoff was a healthy run: begin again.
  if (s.starts > 0 && now_us - s.started_us > Us(c.backoff_max_s))
    s.backoff_s = c.backoff_initial_s;
  s.restart_times_us.push_back(now_us);
  if (s.starts > 0) ++s.restarts;
  s.next_start_us = now_us + Us(s.backoff_s);
  s.backoff_s = std::min(c.backoff_max_s, std::max(s.backoff_s * 2, 0.05));
  s.state = ChildState::kBackoff;
  s.pid = -1;
}

void Supervisor::OnExit(size_t i, const ExitInfo& e, int64_t now_us) {
  const ChildSpec& c = o_.children[i];
  ChildStatus& s = st_[i];
  ++s.exits;
  const bool was_stopping = s.state == ChildState::kStopping;
  // Ending on our own SIGTERM while the stack stops is the clean end it was asked for, for a
  // child that was running well (one still starting, hung or in trouble, or one that needed
  // the SIGKILL after its grace, did not end cleanly and still counts).
  const bool asked = stopping_all_ && was_stopping && e.signal == SIGTERM && s.healthy_when_stopped;
  if (e.failed() && !asked) ++s.failures;
  s.last_exit = asked ? ExitInfo{} : e;
  bool restart = false;
  if (stopping_all_) {
    restart = false;
  } else if (was_stopping) {
    restart = s.restart_after_stop;  // a hung child we stopped
  } else {
    restart = c.restart == RestartPolicy::kAlways ||
              (c.restart == RestartPolicy::kOnFailure && e.failed());
  }
  if (restart) {
    ScheduleRestart(i, now_us);
  } else {
    s.state = ChildState::kExited;
    s.pid = -1;
  }
}

void Supervisor::Stop(size_t i, int64_t now_us, bool restart) {
  ChildStatus& s = st_[i];
  if (s.pid <= 0) return;
  launcher_->Signal(s.pid, SIGTERM);
  s.healthy_when_stopped = s.state == ChildState::kRunning && !ReportsTrouble(s);
  s.state = ChildState::kStopping;
  s.stop_deadline_us = now_us + Us(o_.children[i].stop_grace_s);
  s.restart_after_stop = restart;
}

void Supervisor::Tick(int64_t now_us) {
  for (size_t i = 0; i < st_.size(); ++i) {
    const ChildSpec& c = o_.children[i];
    ChildStatus& s = st_[i];
    if (s.pid > 0) {
      if (s.leader_exit) {
        // A wrapper gone on our SIGTERM: its worker (still in the group) writes its map within
        // the stop grace; the wrapper's exit stands for both once the group has ended. Before,
        // the group was killed as soon as the wrapper was reaped, about 50 ms into the grace.
        if (!launcher_->GroupAlive(s.pid)) {
          const ExitInfo e = *s.leader_exit;
          s.leader_exit.reset();
          OnExit(i, e, now_us);
          continue;
        }
      } else if (auto e = launcher_->Poll(s.pid)) {
        // (Only a leader our SIGTERM ended, as a shell without a trap: a child that exits on it
        // and leaves a helper that ignores it is done, as before, and the helper goes.)
        if (s.state == ChildState::kStopping && e->signal == SIGTERM &&
            now_us < s.stop_deadline_us && launcher_->GroupAlive(s.pid)) {
          s.leader_exit = *e;
        } else {
          launcher_->KillGroup(s.pid);  // what an exit not asked for leaves goes with it
          OnExit(i, *e, now_us);
          continue;
        }
      }
    }
    switch (s.state) {
      case ChildState::kStarting:
      case ChildState::kRunning: {
        if (c.heartbeat.empty()) break;
        const bool silent = s.last_heartbeat_us == 0
                                ? now_us - s.started_us > Us(c.start_grace_s)
                                : now_us - s.last_heartbeat_us > Us(c.heartbeat_timeout_s);
        if (silent) {
          ++s.heartbeat_timeouts;
          Stop(i, now_us, c.restart != RestartPolicy::kNever);
        }
        break;
      }
      case ChildState::kStopping:
        if (s.leader_exit && s.leader_exit->signal == SIGKILL &&
            now_us >= s.group_killed_us + 3 * kUs) {
          // A worker the SIGKILL has not ended in 3 s (stuck in the kernel on a hung disk, or a
          // zombie whose parent lives outside the group): the stop goes on without it, or the
          // children after it would never be stopped.
          const ExitInfo e = *s.leader_exit;
          s.leader_exit.reset();
          OnExit(i, e, now_us);
          continue;
        }
        if (now_us >= s.stop_deadline_us && s.pid > 0) {
          // (A wrapper's worker that needed it makes the stop not clean.)
          if (s.leader_exit && s.leader_exit->signal != SIGKILL) {
            s.leader_exit->signal = SIGKILL;
            s.group_killed_us = now_us;
          }
          launcher_->Signal(s.pid, SIGKILL);
          s.stop_deadline_us = now_us + kUs;  // and again each second until it is reaped
        }
        break;
      case ChildState::kBackoff:
        if (!stopping_all_ && now_us >= s.next_start_us) Launch(i, now_us);
        break;
      case ChildState::kWaiting:
        if (!stopping_all_ && WaitingFor(i).empty()) Launch(i, now_us);
        break;
      case ChildState::kExited:
      case ChildState::kGaveUp:
        break;
    }
  }
  if (stopping_all_) StopNext(now_us);
}

void Supervisor::OnHeartbeat(const std::string& process, int pid, int8_t state,
                             const std::string& text, int64_t now_us) {
  for (size_t i = 0; i < st_.size(); ++i) {
    if (o_.children[i].heartbeat != process) continue;
    ChildStatus& s = st_[i];
    if (s.state != ChildState::kStarting && s.state != ChildState::kRunning) continue;
    if (!launcher_->Owns(s.pid, pid)) {
      ++foreign_heartbeats_;
      continue;
    }
    s.last_heartbeat_us = now_us;
    s.heartbeat_state = state;
    s.heartbeat_text = text;
    s.state = ChildState::kRunning;
  }
}

void Supervisor::StopAll(int64_t now_us) {
  stopping_all_ = true;
  for (auto& s : st_)
    if (s.state == ChildState::kBackoff || s.state == ChildState::kWaiting)
      s.state = ChildState::kExited;
  StopNext(now_us);
}

void Supervisor::StopNext(int64_t now_us) {
  // One at a time, the last first started first: each child is gone before the one started
  // before it is asked, so a process listed early (e.g. map_fusion) still receives what the
  // later ones (the mappers' final maps) publish as they stop, and a child that waited for
  // another (`after`, even one listed below it) stops while what it waited for still runs.
  // (By the config's order, a driver listed after its mapper was stopped first, and the mapper
  // lost its input during its final optimisation.)
  for (const auto& s : st_)
    if (s.state == ChildState::kStopping) return;
  size_t next = st_.size();
  for (size_t k = 0; k < st_.size(); ++k)
    if (st_[k].pid > 0 && (next == st_.size() || st_[k].first_start > st_[next].first_start))
      next = k;
  if (next < st_.size()) Stop(next, now_us, false);
}

bool Supervisor::AllStopped() const {
  return std::all_of(st_.begin(), st_.end(), [](const ChildStatus& s) { return s.pid <= 0; });
}

bool Supervisor::Healthy() const {
  for (size_t i = 0; i < st_.size(); ++i) {
    const ChildStatus& s = st_[i];
    if (!FinishedOneShot(i) && !(s.state == ChildState::kRunning && !ReportsTrouble(s)))
      return false;
  }
  return true;
}

bool Supervisor::Finished() const {
  return std::all_of(st_.begin(), st_.end(), [](const ChildStatus& s) {
    return s.state == ChildState::kExited || s.state == ChildState::kGaveUp;
  });
}

int Supervisor::running() const {
  return static_cast<int>(std::count_if(st_.begin(), st_.end(), [](const ChildStatus& s) {
    return s.state == ChildState::kStarting || s.state == ChildState::kRunning;
  }));
}

int64_t Supervisor::total(int64_t ChildStatus::*field) const {
  int64_t n = 0;
  for (const auto& s : st_) n += s.*field;
  return n;
}

int64_t Supervisor::gave_up() const {
  return std::count_if(st_.begin(), st_.end(),
                       [](const ChildStatus& s) { return s.state == ChildState::kGaveUp; });
}

bool Supervisor::FinishedOneShot(size_t i) const {
  const ChildStatus& s = st_[i];
  return IsOneShot(o_.children[i]) && s.state == ChildState::kExited && s.last_exit &&
         !s.last_exit->failed();
}

std::string Supervisor::Summary() const {
  std::string down;
  size_t done = 0;
  for (size_t i = 0; i < st_.size(); ++i) {
    const ChildStatus& s = st_[i];
    if (FinishedOneShot(i)) {  // did its job: nothing to report
      ++done;
      continue;
    }
    if (s.state == ChildState::kRunning) {
      if (ReportsTrouble(s)) {
        if (!down.empty()) down += ", ";
        down += o_.children[i].name + (s.heartbeat_state == 3 ? " reports ERROR" : " degraded") +
                (s.heartbeat_text.empty() ? "" : ": " + s.heartbeat_text);
      }
      continue;
    }
    if (!down.empty()) down += ", ";
    down += o_.children[i].name + " " + ChildStateName(s.state);
    if (s.state == ChildState::kWaiting) down += " for " + WaitingFor(i);
    if (s.last_exit && s.state != ChildState::kStarting) {
      down += s.last_exit->signal ? " (signal " + std::to_string(s.last_exit->signal) + ")"
                                  : " (exit " + std::to_string(s.last_exit->code) + ")";
    }
  }
  if (down.empty())
    return "all " + std::to_string(st_.size() - done) + " running" +
           (done > 0 ? " (" + std::to_string(done) + " one-shot done)" : "");
  const bool all_running = std::all_of(
      st_.begin(), st_.end(), [](const ChildStatus& c) { return c.state == ChildState::kRunning; });
  if (all_running) return "all running; " + down;
  return down;
}

}  // namespace omni::supervisor
