// The supervisor: restart policies, backoff and giving up, heartbeat timeouts with SIGTERM then
// SIGKILL, stopping everything, the options; then the process with real children.
#include <dirent.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "../../integration/tools/run.h"
#include "omni/supervisor/supervisor.h"

namespace omni::supervisor {
namespace {

// Children that run until the test ends them (Exit) or a signal does: SIGKILL always, SIGTERM
// unless the child ignores it.
class FakeLauncher final : public Launcher {
 public:
  Result<int> Start(const std::vector<std::string>& command, const std::string&) override {
    if (fail_starts > 0) {
      --fail_starts;
      return MakeError(ErrorCode::kUnavailable, "fork: no memory");
    }
    const int pid = next_pid++;
    commands[pid] = command;
    started.push_back(pid);
    return pid;
  }
  std::optional<ExitInfo> Poll(int pid) override {
    auto it = exits.find(pid);
    if (it == exits.end()) return std::nullopt;
    ExitInfo e = it->second;
    exits.erase(it);
    return e;
  }
  void Signal(int pid, int sig) override {
    signals.push_back({pid, sig});
    if (sig == SIGKILL || (sig == SIGTERM && !ignores_term.count(pid))) {
      ExitInfo e;
      e.signal = sig;
      exits[pid] = e;
    }
  }
  // A heartbeat's pid 0 stands for "the child's own" in these tests.
  bool Owns(int child_pid, int reported_pid) const override {
    return reported_pid == 0 || reported_pid == child_pid;
  }
  void Exit(int pid, int code) {
    ExitInfo e;
    e.code = code;
    exits[pid] = e;
  }
  bool GroupAlive(int pid) override { return group_alive.count(pid) > 0; }
  void KillGroup(int pid) override {
    groups_killed.push_back(pid);
    group_alive.erase(pid);
  }
  std::set<int> group_alive;  // children whose group outlives them (a wrapper's worker)
  std::vector<int> groups_killed;
  int next_pid = 100;
  int fail_starts = 0;
  std::vector<int> started;
  std::map<int, std::vector<std::string>> commands;
  std::map<int, ExitInfo> exits;
  std::map<int, bool> ignores_term;
  std::vector<std::pair<int, int>> signals;
};

constexpr int64_t kS = 1000000;

ChildSpec Child(const std::string& name, RestartPolicy p) {
  ChildSpec c;
  c.name = name;
  c.command = {"/bin/" + name};
  c.restart = p;
  c.backoff_initial_s = 1.0;
  c.backoff_max_s = 8.0;
  c.max_restarts = 3;
  c.restart_window_s = 100.0;
  return c;
}

TEST(Supervisor, RestartsOnFailureWithADoublingBackoffThenGivesUp) {
  SupervisorOptions o;
  o.children = {Child("crashy", RestartPolicy::kOnFailure)};
  FakeLauncher l;
  Supervisor s(o, &l);
  int64_t t = 0;
  s.Start(t);
  ASSERT_EQ(l.started.size(), 1u);
  // Exits with 2 four times in a row: restarted after 1, 2, 4 s; the fourth failure within the
  // window exceeds max_restarts (3): given up.
  const double waits[] = {1, 2, 4};
  for (int k = 0; k < 3; ++k) {
    l.Exit(l.started.back(), 2);
    s.Tick(t);
    EXPECT_EQ(s.children()[0].state, ChildState::kBackoff);
    s.Tick(t + static_cast<int64_t>(waits[k] * kS) - 1);
    EXPECT_EQ(l.started.size(), static_cast<size_t>(k + 1)) << "restarted too early";
    t += static_cast<int64_t>(waits[k] * kS);
    s.Tick(t);
    EXPECT_EQ(l.started.size(), static_cast<size_t>(k + 2));
    EXPECT_EQ(s.children()[0].state, ChildState::kRunning);
  }
  l.Exit(l.started.back(), 2);
  s.Tick(t);
  EXPECT_EQ(s.children()[0].state, ChildState::kGaveUp);
  s.Tick(t + 1000 * kS);
  EXPECT_EQ(l.started.size(), 4u);
  EXPECT_EQ(s.children()[0].restarts, 3);
  EXPECT_EQ(s.children()[0].failures, 4);
  EXPECT_EQ(s.gave_up(), 1);
  EXPECT_NE(s.Summary().find("crashy gave up (exit 2)"), std::string::npos) << s.Summary();
}

TEST(Supervisor, PoliciesDecideWhatAnExitMeans) {
  SupervisorOptions o;
  o.children = {Child("onfail", RestartPolicy::kOnFailure), Child("always", RestartPolicy::kAlways),
                Child("never", RestartPolicy::kNever)};
  FakeLauncher l;
  Supervisor s(o, &l);
  s.Start(0);
  ASSERT_EQ(l.started.size(), 3u);
  for (int pid : {100, 101, 102}) l.Exit(pid, 0);  // all exit cleanly
  s.Tick(0);
  EXPECT_EQ(s.children()[0].state, ChildState::kExited);   // on-failure: a clean exit is done
  EXPECT_EQ(s.children()[1].state, ChildState::kBackoff);  // always: back after the backoff
  EXPECT_EQ(s.children()[2].state, ChildState::kExited);
  s.Tick(2 * kS);
  EXPECT_EQ(l.started.size(), 4u);
  EXPECT_EQ(l.commands[103], std::vector<std::string>{"/bin/always"});
  // A start that fails (fork) is retried with the backoff too.
  l.fail_starts = 1;
  l.Exit(103, 1);
  s.Tick(3 * kS);
  s.Tick(20 * kS);
  EXPECT_EQ(s.children()[1].start_errors, 1);
  s.Tick(40 * kS);
  EXPECT_EQ(s.children()[1].state, ChildState::kRunning);
}

TEST(Supervisor, TheBackoffStartsAgainAfterAHealthyRun) {
  SupervisorOptions o;
  o.children = {Child("svc", RestartPolicy::kAlways)};
  o.children[0].max_restarts = 100;
  FakeLauncher l;
  Supervisor s(o, &l);
  int64_t t = 0;
  s.Start(t);
  for (int k = 0; k < 3; ++k) {  // quick exits: backoff 1, 2, 4 s
    l.Exit(l.started.back(), 1);
    s.Tick(t);
    t += 10 * kS;
    s.Tick(t);
  }
  EXPECT_DOUBLE_EQ(s.children()[0].backoff_s, 8.0);
  // This start lives longer than backoff_max_s: its exit restarts after the initial backoff.
  t += 60 * kS;
  l.Exit(l.started.back(), 1);
  s.Tick(t);
  EXPECT_EQ(s.children()[0].next_start_us, t + 1 * kS);
}

TEST(Supervisor, ASilentChildIsStoppedKilledIfNeededAndRestarted) {
  SupervisorOptions o;
  ChildSpec c = Child("mapper", RestartPolicy::kOnFailure);
  c.heartbeat = "mapper_proc";
  c.start_grace_s = 10;
  c.heartbeat_timeout_s = 3;
  c.stop_grace_s = 2;
  o.children = {c};
  FakeLauncher l;
  Supervisor s(o, &l);
  s.Start(0);
  EXPECT_EQ(s.children()[0].state, ChildState::kStarting);
  s.Tick(9 * kS);  // within the start grace: nothing
  EXPECT_TRUE(l.signals.empty());
  s.OnHeartbeat("other_proc", 0, 1, "", 9 * kS);  // someone else's heartbeat does not count
  EXPECT_EQ(s.children()[0].state, ChildState::kStarting);
  s.OnHeartbeat("mapper_proc", 0, 2, "queue full", 9 * kS);
  EXPECT_EQ(s.children()[0].state, ChildState::kRunning);
  EXPECT_NE(s.Summary().find("mapper degraded: queue full"), std::string::npos) << s.Summary();
  s.OnHeartbeat("mapper_proc", 0, 1, "mapping", 10 * kS);
  s.Tick(12 * kS);
  EXPECT_TRUE(l.signals.empty());
  EXPECT_EQ(s.Summary(), "all 1 running");
  // Heartbeats stop (hung): SIGTERM after 3 s; it ignores it: SIGKILL 2 s later; restarted.
  l.ignores_term[100] = true;
  s.Tick(13 * kS + 1);
  ASSERT_EQ(l.signals.size(), 1u);
  EXPECT_EQ(l.signals[0], std::make_pair(100, SIGTERM));
  EXPECT_EQ(s.children()[0].state, ChildState::kStopping);
  EXPECT_EQ(s.children()[0].heartbeat_timeouts, 1);
  s.Tick(15 * kS);
  s.Tick(15 * kS + 2);
  ASSERT_EQ(l.signals.size(), 2u);
  EXPECT_EQ(l.signals[1], std::make_pair(100, SIGKILL));
  s.Tick(15 * kS + 3);  // reaped
  EXPECT_EQ(s.children()[0].state, ChildState::kBackoff);
  s.Tick(17 * kS);
  EXPECT_EQ(l.started.size(), 2u);
  // The new start never heartbeats: the start grace runs out, stopped and restarted again.
  s.Tick(17 * kS + 10 * kS + 1);
  EXPECT_EQ(l.signals.back(), std::make_pair(101, SIGTERM));
  EXPECT_EQ(s.children()[0].heartbeat_timeouts, 2);
}

// A heartbeat with the child's name from another pid (a stale instance, the same process on
// another machine of the multicast group, `omni replay` of a log with HEARTBEAT in it) does not
// keep a hung child "running": it is counted and the child is stopped when its own go silent.
TEST(Supervisor, AHeartbeatFromAnotherPidIsNotTheChilds) {
  SupervisorOptions o;
  ChildSpec c = Child("mapper", RestartPolicy::kOnFailure);
  c.heartbeat = "mapper_proc";
  c.start_grace_s = 2;
  c.heartbeat_timeout_s = 3;
  o.children = {c};
  FakeLauncher l;
  Supervisor s(o, &l);
  s.Start(0);
  s.OnHeartbeat("mapper_proc", 100, 1, "", 1 * kS);
  EXPECT_EQ(s.children()[0].state, ChildState::kRunning);
  for (int t = 2; t <= 6; ++t) s.OnHeartbeat("mapper_proc", 4242, 1, "", t * kS);
  EXPECT_EQ(s.foreign_heartbeats(), 5);
  s.Tick(4 * kS + 1);
  ASSERT_EQ(l.signals.size(), 1u);
  EXPECT_EQ(l.signals[0], std::make_pair(100, SIGTERM));
  EXPECT_EQ(s.children()[0].heartbeat_timeouts, 1);
}

// The real launcher signals the child's process group: a wrapper's worker stops with it, and
// what a child leaves behind when it exits is killed (review finding 2026-12-06: the worker of
// `sh -c 'sleep & wait'` outlived its stop, and would have held a driver's serial port).
bool Alive(int pid) {
  std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!std::getline(stat, line)) return false;
  const auto paren = line.rfind(')');
  return paren != std::string::npos && paren + 2 < line.size() && line[paren + 2] != 'Z';
}

int ReadPid(const std::string& path) {
  for (int i = 0; i < 500; ++i) {
    std::ifstream f(path);
    int pid = 0;
    if (f >> pid && pid > 0) return pid;
    usleep(10000);
  }
  return -1;
}

std::optional<ExitInfo> WaitExit(PosixLauncher* l, int pid) {
  for (int i = 0; i < 500; ++i) {
    if (auto e = l->Poll(pid)) return e;
    usleep(10000);
  }
  return std::nullopt;
}

TEST(PosixLauncherTest, SignalsTheChildsWholeGroupAndKillsWhatItLeaves) {
  const std::string dir = ::testing::TempDir() + "/launcher_group";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  PosixLauncher l;
  // A wrapper whose worker is a grandchild: SIGTERM to the group stops both.
  auto wrapper = l.Start({"sh", "-c", "sleep 1000 & echo $! > " + dir + "/w; wait"}, "");
  ASSERT_TRUE(wrapper.ok()) << wrapper.error().message;
  const int worker = ReadPid(dir + "/w");
  ASSERT_GT(worker, 0);
  EXPECT_TRUE(l.Owns(*wrapper, worker)) << "the worker's heartbeat is the child's";
  EXPECT_TRUE(l.Owns(*wrapper, *wrapper));
  EXPECT_FALSE(l.Owns(*wrapper, static_cast<int>(getpid())));
  EXPECT_FALSE(l.Owns(*wrapper, 0));
  l.Signal(*wrapper, SIGTERM);
  ASSERT_TRUE(WaitExit(&l, *wrapper).has_value());
  for (int i = 0; i < 200 && Alive(worker); ++i) usleep(10000);
  EXPECT_FALSE(Alive(worker)) << "the wrapper's worker outlived the stop";
  // A child that exits leaving a process behind: killed when the exit is reaped.
  auto leaver = l.Start({"sh", "-c", "sleep 1000 & echo $! > " + dir + "/o; exit 0"}, "");
  ASSERT_TRUE(leaver.ok());
  const int orphan = ReadPid(dir + "/o");
  ASSERT_GT(orphan, 0);
  auto e = WaitExit(&l, *leaver);
  ASSERT_TRUE(e.has_value());
  EXPECT_EQ(e->code, 0);
  EXPECT_TRUE(l.GroupAlive(*leaver));
  l.KillGroup(*leaver);  // as the supervisor does for an exit it did not ask for
  for (int i = 0; i < 200 && Alive(orphan); ++i) usleep(10000);
  EXPECT_FALSE(Alive(orphan)) << "the child's leftover outlived it";
}

// A wrapper (`sh -c '...; mapper'`, no exec) ends at once on the stop's SIGTERM while its worker
// writes the map: the group is left its stop grace, and the stop is clean when it ends in time.
// Before, the group was killed as soon as the wrapper was reaped (the next tick, about 50 ms).
// One that outlives the grace is killed and the stop counts as not clean.
TEST(Supervisor, AWrappersWorkerIsGivenItsStopGrace) {
  SupervisorOptions o;
  ChildSpec mapper = Child("mapper", RestartPolicy::kAlways);
  mapper.stop_grace_s = 30;
  o.children = {mapper};
  FakeLauncher l;
  Supervisor s(o, &l);
  s.Start(0);
  l.group_alive.insert(100);
  s.StopAll(kS);
  s.Tick(kS + 50000);  // the wrapper has ended on the SIGTERM; its worker writes on
  s.Tick(20 * kS);
  EXPECT_FALSE(s.AllStopped());
  EXPECT_TRUE(l.groups_killed.empty());
  l.group_alive.erase(100);  // the worker is done
  s.Tick(21 * kS);
  EXPECT_TRUE(s.AllStopped());
  EXPECT_EQ(s.children()[0].failures, 0);
  EXPECT_EQ(std::count(l.signals.begin(), l.signals.end(), std::make_pair(100, SIGKILL)), 0);
  // A worker that does not end within the grace: killed, and not a clean stop.
  FakeLauncher m;
  Supervisor t(o, &m);
  t.Start(0);
  m.group_alive.insert(100);
  t.StopAll(kS);
  t.Tick(kS + 50000);
  t.Tick(31 * kS + 1);
  EXPECT_EQ(std::count(m.signals.begin(), m.signals.end(), std::make_pair(100, SIGKILL)), 1);
  m.group_alive.erase(100);  // the SIGKILL took it
  t.Tick(32 * kS);
  EXPECT_TRUE(t.AllStopped());
  EXPECT_EQ(t.children()[0].failures, 1);
  // One the SIGKILL does not end either (stuck on a hung disk): the stop goes on 3 s later.
  FakeLauncher k;
  Supervisor v(o, &k);
  v.Start(0);
  k.group_alive.insert(100);
  v.StopAll(kS);
  v.Tick(kS + 50000);
  v.Tick(31 * kS + 1);
  for (int64_t t_us = 32 * kS; t_us <= 34 * kS; t_us += kS) v.Tick(t_us);
  EXPECT_FALSE(v.AllStopped());
  v.Tick(35 * kS);
  EXPECT_TRUE(v.AllStopped());
  EXPECT_EQ(v.children()[0].failures, 1);
  // A child (not a wrapper) that exits cleanly on the SIGTERM, leaving a helper that ignores it:
  // its stop is done at once and clean, the helper killed with the group.
  FakeLauncher x;
  Supervisor w(o, &x);
  w.Start(0);
  x.group_alive.insert(100);
  x.ignores_term[100] = true;
  w.StopAll(kS);
  x.Exit(100, 0);
  w.Tick(kS + 50000);
  EXPECT_TRUE(w.AllStopped());
  EXPECT_EQ(w.children()[0].failures, 0);
  EXPECT_EQ(x.groups_killed, std::vector<int>{100});
  // An exit nobody asked for (a crash) takes what it leaves in its group at once.
  FakeLauncher n;
  Supervisor u(o, &n);
  u.Start(0);
  n.group_alive.insert(100);
  n.Exit(100, 1);
  u.Tick(kS);
  EXPECT_EQ(n.groups_killed, std::vector<int>{100});
}

TEST(Supervisor, StopAllStopsNewestFirstAndRestartsNothing) {
  SupervisorOptions o;
  o.children = {Child("driver", RestartPolicy::kAlways), Child("mapper", RestartPolicy::kAlways),
                Child("crashed", RestartPolicy::kAlways)};
  FakeLauncher l;
  Supervisor s(o, &l);
  s.Start(0);
  l.Exit(102, 1);
  s.Tick(0);  // "crashed" is waiting to restart
  l.ignores_term[100] = true;
  l.ignores_term[101] = true;
  s.StopAll(kS);
  ASSERT_EQ(l.signals.size(), 1u);
  EXPECT_EQ(l.signals[0], std::make_pair(101, SIGTERM));  // newest first, alone
  s.Tick(2 * kS);
  EXPECT_EQ(l.signals.size(), 1u);  // the mapper takes its time: the driver is not asked yet
  l.Exit(101, 0);
  s.Tick(3 * kS);  // gone: now the driver
  ASSERT_EQ(l.signals.size(), 2u);
  EXPECT_EQ(l.signals[1], std::make_pair(100, SIGTERM));
  s.Tick(4 * kS);
  EXPECT_FALSE(s.AllStopped());  // the driver ignores SIGTERM
  s.Tick(3 * kS + o.children[0].stop_grace_s * kS);
  EXPECT_EQ(l.signals.back(), std::make_pair(100, SIGKILL));
  s.Tick(3 * kS + o.children[0].stop_grace_s * kS + 1);
  EXPECT_TRUE(s.AllStopped());
  s.Tick(100 * kS);
  EXPECT_EQ(l.started.size(), 3u);  // nothing restarted
}

// A one-shot (restart: never, no heartbeat, e.g. `ip link set can0 up`) is waited for until it
// has finished, its clean exit leaves the stack healthy, and children ended by the supervisor's
// own SIGTERM during a stop are not failures.
TEST(Supervisor, OneShotsAreWaitedForAndAStopIsNotAFailure) {
  SupervisorOptions o;
  ChildSpec setup = Child("setup", RestartPolicy::kNever);  // no heartbeat: a one-shot
  ChildSpec bridge = Child("bridge", RestartPolicy::kAlways);
  bridge.after = {"setup"};
  o.children = {setup, bridge};
  FakeLauncher l;
  Supervisor s(o, &l);
  s.Start(0);
  s.Tick(kS);
  ASSERT_EQ(l.started.size(), 1u) << "the bridge waits while the one-shot still runs";
  EXPECT_NE(s.Summary().find("bridge waiting for setup"), std::string::npos) << s.Summary();
  l.Exit(l.started[0], 0);
  s.Tick(2 * kS);
  ASSERT_EQ(l.started.size(), 2u);
  s.Tick(3 * kS);
  s.OnHeartbeat("bridge", 0, 1, "", 3 * kS);  // (no heartbeat configured: ignored)
  EXPECT_TRUE(s.Healthy()) << s.Summary();
  EXPECT_EQ(s.Summary(), "all 1 running (1 one-shot done)");
  s.StopAll(4 * kS);
  for (int k = 0; k < 10 && !s.AllStopped(); ++k) s.Tick((5 + k) * kS);
  ASSERT_TRUE(s.AllStopped());
  EXPECT_EQ(s.children()[1].failures, 0);
  ASSERT_TRUE(s.children()[1].last_exit.has_value());
  EXPECT_FALSE(s.children()[1].last_exit->failed());
}

// `after`: a mapper waits for its driver's first heartbeat, a child that has no heartbeat to wait
// for counts as up once started, a stop while some wait ends them too, and a dependency's later
// restart does not restart what depends on it.
TEST(Supervisor, AfterStartsAChildOnceWhatItWaitsForRuns) {
  SupervisorOptions o;
  ChildSpec driver = Child("driver", RestartPolicy::kAlways);
  driver.heartbeat = "driver";
  ChildSpec logger = Child("logger", RestartPolicy::kAlways);  // no heartbeat
  ChildSpec mapper = Child("mapper", RestartPolicy::kAlways);
  mapper.after = {"driver", "logger"};
  ChildSpec fusion = Child("fusion", RestartPolicy::kAlways);
  fusion.after = {"logger"};
  o.children = {mapper, driver, logger, fusion};
  FakeLauncher l;
  Supervisor s(o, &l);
  s.Start(0);
  // driver (100), logger (101) and fusion (102, its logger is up at once) start; the mapper waits.
  ASSERT_EQ(l.started.size(), 3u);
  EXPECT_EQ(l.commands[100][0], "/bin/driver");
  EXPECT_EQ(l.commands[102][0], "/bin/fusion");
  EXPECT_EQ(s.children()[0].state, ChildState::kWaiting);
  EXPECT_NE(s.Summary().find("mapper waiting for driver"), std::string::npos) << s.Summary();
  s.Tick(kS);
  EXPECT_EQ(l.started.size(), 3u);
  s.OnHeartbeat("driver", 0, 1, "", 2 * kS);
  s.Tick(2 * kS);
  ASSERT_EQ(l.started.size(), 4u);
  EXPECT_EQ(l.commands[103][0], "/bin/mapper");
  EXPECT_EQ(s.children()[0].state, ChildState::kRunning);
  // The driver crashes and comes back: the mapper is left alone.
  l.Exit(100, 1);
  s.Tick(3 * kS);
  s.Tick(4 * kS + 1);
  EXPECT_EQ(l.started.size(), 5u);
  EXPECT_EQ(l.commands[104][0], "/bin/driver");
  EXPECT_TRUE(l.signals.empty());
  // The stop goes in the reverse of the first starts: the mapper (listed first, started last)
  // before fusion, the logger and the driver it waited for, which its restart does not move.
  // (By the list's order the driver went first, under a mapper still writing its map.)
  s.StopAll(5 * kS);
  for (int k = 0; k < 10 && !s.AllStopped(); ++k) s.Tick((6 + k) * kS);
  EXPECT_TRUE(s.AllStopped());
  std::vector<int> order;
  for (const auto& [pid, sig] : l.signals)
    if (sig == SIGTERM) order.push_back(pid);
  EXPECT_EQ(order, (std::vector<int>{103, 102, 101, 104}));
  l.signals.clear();
  // A stop while a child still waits: it is done at once, nothing is started.
  Supervisor t(o, &l);
  t.Start(10 * kS);
  ASSERT_EQ(t.children()[0].state, ChildState::kWaiting);
  t.StopAll(11 * kS);
  for (int k = 0; k < 10 && !t.AllStopped(); ++k) t.Tick((12 + k) * kS);
  EXPECT_TRUE(t.AllStopped());
  EXPECT_TRUE(t.Finished());
  EXPECT_EQ(t.children()[0].starts, 0);
  // What it waits for ends for good (a one-shot that exits, a driver given up): it starts
  // anyway instead of waiting for ever.
  SupervisorOptions p;
  ChildSpec setup = Child("setup", RestartPolicy::kNever);
  setup.heartbeat = "setup";  // never sends one: it is a one-shot
  ChildSpec user = Child("user", RestartPolicy::kNever);
  user.after = {"setup"};
  p.children = {setup, user};
  FakeLauncher m;
  Supervisor u(p, &m);
  u.Start(0);
  ASSERT_EQ(m.started.size(), 1u);
  m.Exit(m.started[0], 0);
  u.Tick(kS);
  ASSERT_EQ(m.started.size(), 2u);
  EXPECT_EQ(m.commands[m.started[1]][0], "/bin/user");
}

TEST(SupervisorOptions, AfterNamesOtherChildrenWithoutACycle) {
  auto load = [](const std::string& yaml) {
    auto r = ConfigReader::FromString(yaml, "after.yaml");
    EXPECT_TRUE(r.ok());
    return SupervisorOptions::Load(*r);
  };
  auto ok = load("children:\n  a:\n    command: [x]\n  b:\n    command: [y]\n    after: [a]\n");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->children[1].after, std::vector<std::string>{"a"});
  auto unknown = load("children:\n  a:\n    command: [x]\n    after: [b]\n");
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.error().message.find("'b' is not one of the children"), std::string::npos)
      << unknown.error().message;
  auto self = load("children:\n  a:\n    command: [x]\n    after: [a]\n");
  ASSERT_FALSE(self.ok());
  EXPECT_NE(self.error().message.find("cannot wait for itself"), std::string::npos);
  auto cycle = load(
      "children:\n  a:\n    command: [x]\n    after: [c]\n  b:\n    command: [y]\n"
      "    after: [a]\n  c:\n    command: [z]\n    after: [b]\n");
  ASSERT_FALSE(cycle.ok());
  EXPECT_NE(cycle.error().message.find("form a cycle"), std::string::npos) << cycle.error().message;
}

TEST(SupervisorOptions, ChildrenByNameAndMistakesNamed) {
  auto r = ConfigReader::FromString(
      "working_dir: /tmp\nchildren:\n  rbpf_mapper:\n    command: [build/bin/rbpf_mapper, "
      "--config, config/rbpf_mapper.yaml]\n    heartbeat: rbpf_mapper\n    restart: always\n"
      "  logger:\n    command: [lcm-logger, logs/omni.lcmlog]\n",
      "sup.yaml");
  ASSERT_TRUE(r.ok());
  auto o = SupervisorOptions::Load(*r);
  ASSERT_TRUE(o.ok()) << o.error().message;
  ASSERT_EQ(o->children.size(), 2u);
  EXPECT_EQ(o->children[0].name, "rbpf_mapper");  // file order
  EXPECT_EQ(o->children[0].command.size(), 3u);
  EXPECT_EQ(o->children[0].restart, RestartPolicy::kAlways);
  EXPECT_EQ(o->children[1].heartbeat, "");
  EXPECT_EQ(o->working_dir, "/tmp");
  auto bad = ConfigReader::FromString(
      "children:\n  a:\n    heartbeat: x\n  b:\n    command: [x]\n    restart: sometimes\n"
      "    hearbeat_timeout_s: 3\n",
      "bad.yaml");
  ASSERT_TRUE(bad.ok());
  auto e = SupervisorOptions::Load(*bad);
  ASSERT_FALSE(e.ok());
  for (const char* key :
       {"children.a.command", "children.b.restart", "children.b.hearbeat_timeout_s"})
    EXPECT_NE(e.error().message.find(key), std::string::npos) << key << "\n" << e.error().message;
  auto none = ConfigReader::FromString("working_dir: /tmp\n", "none.yaml");
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(SupervisorOptions::Load(*none).ok());
  auto shipped = ConfigReader::FromFile(std::string(OMNI_SOURCE_DIR) + "/config/supervisor.yaml");
  ASSERT_TRUE(shipped.ok()) << shipped.error().message;
  auto so = SupervisorOptions::Load(*shipped);
  ASSERT_TRUE(so.ok()) << so.error().message;
  EXPECT_GE(so->children.size(), 5u);
}

// bus::Heartbeat publishes on HEARTBEAT only: a supervisor listening on another channel would
// hear no child and restart each one for ever (review finding 2026-12-06). Refused, named.
TEST(SupervisorOptions, TheHeartbeatChannelCanOnlyBeHEARTBEAT) {
  auto load = [](const std::string& yaml) {
    auto r = ConfigReader::FromString(yaml, "channel.yaml");
    EXPECT_TRUE(r.ok());
    return SupervisorOptions::Load(*r);
  };
  auto ok = load("channel: HEARTBEAT\nchildren:\n  a:\n    command: [x]\n");
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_EQ(ok->channel, "HEARTBEAT");
  auto other = load("channel: HB_X\nchildren:\n  a:\n    command: [x]\n");
  ASSERT_FALSE(other.ok());
  EXPECT_NE(other.error().message.find("key 'channel' = 'HB_X': must be HEARTBEAT"),
            std::string::npos)
      << other.error().message;
}

// Heartbeats come once a second: a timeout under 2 s killed healthy children now and then
// (review finding 2026-12-06). The key is named; the built-in default is above the floor.
TEST(SupervisorOptions, AHeartbeatTimeoutUnderTwoSecondsIsAnError) {
  EXPECT_GE(ChildSpec{}.heartbeat_timeout_s, kMinHeartbeatTimeoutS);
  auto load = [](const std::string& timeout) {
    auto r = ConfigReader::FromString(
        "children:\n  a:\n    command: [x]\n    heartbeat: a\n    heartbeat_timeout_s: " + timeout +
            "\n",
        "timeout.yaml");
    EXPECT_TRUE(r.ok());
    return SupervisorOptions::Load(*r);
  };
  for (const char* bad : {"0.1", "1", "1.5", "1.99"}) {
    auto e = load(bad);
    ASSERT_FALSE(e.ok()) << bad;
    EXPECT_NE(e.error().message.find("key 'children.a.heartbeat_timeout_s'"), std::string::npos)
        << e.error().message;
    EXPECT_NE(e.error().message.find("must be in [2, 3600]"), std::string::npos)
        << e.error().message;
  }
  auto two = load("2");
  ASSERT_TRUE(two.ok()) << two.error().message;
  EXPECT_DOUBLE_EQ(two->children[0].heartbeat_timeout_s, 2.0);
}

TEST(SupervisorProcess, RestartsRealChildrenAndGivesUp) {
  const std::string dir = ::testing::TempDir() + "/supervisor_proc";
  std::filesystem::create_directories(dir);
  {
    std::ofstream f(dir + "/sup.yaml");
    f << "children:\n"
         "  crashy:\n    command: [sh, -c, 'exit 3']\n    backoff_initial_s: 0.1\n"
         "    backoff_max_s: 0.4\n    max_restarts: 2\n"
         "  oneshot:\n    command: [sh, -c, 'exit 0']\n"
         "  hung:\n    command: [sleep, '100']\n    heartbeat: hung_proc\n"
         "    start_grace_s: 0.3\n    restart: never\n    stop_grace_s: 0.5\n"
         "  missing:\n    command: [/nonexistent/omni-thing]\n    backoff_initial_s: 0.1\n"
         "    max_restarts: 1\n";
  }
  auto r = testing::Run("timeout 30 " + testing::Bin("supervisor") + " --url memq:// --config " +
                        dir + "/sup.yaml");
  EXPECT_EQ(r.exit_code, 1) << r.output;  // children given up / failed
  EXPECT_NE(
      r.output.find("crashy: 3 starts, 2 restarts, 3 failures, 0 heartbeat timeouts, given up"),
      std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("oneshot: 1 starts, 0 restarts, 0 failures"), std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("hung: 1 starts, 0 restarts, 1 failures, 1 heartbeat timeouts"),
            std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("missing: 2 starts, 1 restarts, 2 failures"), std::string::npos)
      << r.output;
  // A missing or bad config is an error naming it.
  EXPECT_EQ(testing::Run(testing::Bin("supervisor")).exit_code, 2);
  {
    std::ofstream f(dir + "/bad.yaml");
    f << "children:\n  x:\n    comand: [true]\n";
  }
  auto bad =
      testing::Run(testing::Bin("supervisor") + " --url memq:// --config " + dir + "/bad.yaml");
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find("children.x.comand"), std::string::npos) << bad.output;
}

// The supervisor's --url is its children's bus too (LCM_DEFAULT_URL): on different buses it
// would never hear their heartbeats and would kill each as hung.
TEST(SupervisorProcess, ChildrenRunOnTheSupervisorsBus) {
  const std::string dir = ::testing::TempDir() + "/supervisor_url";
  std::filesystem::create_directories(dir);
  std::filesystem::remove(dir + "/url.txt");
  {
    std::ofstream f(dir + "/sup.yaml");
    f << "children:\n  tell:\n    command: [sh, -c, 'echo \"$LCM_DEFAULT_URL\" > " << dir
      << "/url.txt']\n";
  }
  testing::Run("timeout 30 " + testing::Bin("supervisor") +
               " --url 'memq://' --duration-s 2 --config " + dir + "/sup.yaml");
  std::ifstream in(dir + "/url.txt");
  std::string got;
  std::getline(in, got);
  EXPECT_EQ(got, "memq://");
}

// The descriptors of a child that ran `ls -l /proc/self/fd` (its output), other than stdin,
// stdout, stderr and ls's own handle on that directory: "9 -> /dev/null".
std::vector<std::string> ExtraFds(const std::string& output) {
  std::vector<std::string> extra;
  std::istringstream in(output);
  std::string line;
  while (std::getline(in, line)) {
    const auto arrow = line.find(" -> ");
    if (arrow == std::string::npos) continue;
    const auto space = line.rfind(' ', arrow - 1);
    const std::string fd = line.substr(space + 1, arrow - space - 1);
    const std::string target = line.substr(arrow + 4);
    if (fd == "0" || fd == "1" || fd == "2") continue;
    if (target.rfind("/proc/", 0) == 0 && target.size() > 3 &&
        target.compare(target.size() - 3, 3, "/fd") == 0)
      continue;  // ls's own
    extra.push_back(fd + " -> " + target);
  }
  return extra;
}

// A child gets stdin, stdout and stderr and no other descriptor of the supervisor's (review
// finding 2026-12-06: its LCM sockets and pipes, and whatever it inherited, went to every
// child). Here descriptor 9, which the supervisor inherits open; over UDP, its LCM sockets below.
TEST(SupervisorProcess, ChildrenGetOnlyStdinStdoutAndStderr) {
  const std::string dir = ::testing::TempDir() + "/supervisor_fds";
  std::filesystem::create_directories(dir);
  {
    std::ofstream f(dir + "/sup.yaml");
    f << "children:\n  fds:\n    command: [ls, -l, /proc/self/fd]\n    restart: never\n";
  }
  auto r = testing::Run("timeout 30 " + testing::Bin("supervisor") + " --url memq:// --config " +
                        dir + "/sup.yaml 9</dev/null");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  ASSERT_NE(r.output.find(" 1 -> "), std::string::npos) << "no listing:\n" << r.output;
  const auto extra = ExtraFds(r.output);
  EXPECT_TRUE(extra.empty()) << "the child inherited " << extra.size() << " more, e.g. "
                             << extra.front() << ":\n"
                             << r.output;
}

TEST(SupervisorProcess, WatchesARealProcessHeartbeatOverUdpInANetns) {
  if (testing::Run("unshare -n true").exit_code != 0)
    GTEST_SKIP() << "cannot create a private network namespace (unshare -n needs root)";
  const std::string dir = ::testing::TempDir() + "/supervisor_netns";
  std::filesystem::create_directories(dir);
  {
    // odom_mapper heartbeats at 1 Hz: never restarted (margins wide enough for a loaded
    // sanitizer run). A `sleep` that claims to heartbeat as "ghost" never does: stopped after
    // its grace and restarted.
    std::ofstream f(dir + "/sup.yaml");
    f << "children:\n"
         "  odom_mapper:\n    command: ["
      << testing::Bin("odom_mapper") << ", --out, " << dir
      << "/odom]\n    heartbeat: odom_mapper\n    heartbeat_timeout_s: 5\n"
         "    start_grace_s: 8\n"
         "  ghost:\n    command: [sleep, '100']\n    heartbeat: ghost\n    start_grace_s: 1\n"
         "    stop_grace_s: 0.5\n    backoff_initial_s: 0.2\n"
         "  fds:\n    command: [ls, -l, /proc/self/fd]\n    restart: never\n";
    std::ofstream s(dir + "/run.sh");
    s << "ip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0'\n"
      << testing::Bin("supervisor") << " --config " << dir << "/sup.yaml --duration-s 7\n";
  }
  auto r = testing::Run("timeout 60 unshare -n bash " + dir + "/run.sh");
  EXPECT_EQ(r.exit_code, 1) << r.output;  // the ghost never beat: killed and restarted
  // Stopped before any scan arrived, odom_mapper has lost nothing: a clean exit, not restarted.
  EXPECT_NE(r.output.find("odom_mapper: 1 starts, 0 restarts, 0 failures, 0 heartbeat timeouts"),
            std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("ghost: "), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("ghost: 1 starts"), std::string::npos) << r.output;  // restarted
  EXPECT_EQ(r.output.find("ghost: 0 heartbeat"), std::string::npos) << r.output;
  // The supervisor's UDP sockets (and LCM's pipe) are not the children's.
  ASSERT_NE(r.output.find(" 1 -> "), std::string::npos) << "no listing:\n" << r.output;
  const auto extra = ExtraFds(r.output);
  EXPECT_TRUE(extra.empty()) << "the child inherited " << extra.size() << " more, e.g. "
                             << extra.front() << ":\n"
                             << r.output;
}

// --- A hangup (review finding 2026-12-06: an SSH session dropping killed the supervisor at
// once; its children got SIGTERM together and the workers of wrapper commands lived on). ---

// The live processes whose environment holds `tag` (NAME=VALUE): the supervisor started by
// SpawnTagged and everything under it, wherever it was reparented.
std::map<int, std::string> Tagged(const std::string& tag) {
  std::map<int, std::string> found;  // pid -> command line
  DIR* proc = opendir("/proc");
  if (proc == nullptr) return found;
  while (const dirent* d = readdir(proc)) {
    const int pid = std::atoi(d->d_name);
    if (pid <= 0 || !Alive(pid)) continue;
    std::ifstream env(std::string("/proc/") + d->d_name + "/environ");
    std::string var;
    bool has = false;
    while (std::getline(env, var, '\0'))
      if (var == tag) has = true;
    if (!has) continue;
    std::ifstream cmd(std::string("/proc/") + d->d_name + "/cmdline");
    std::string arg, line;
    while (std::getline(cmd, arg, '\0')) line += (line.empty() ? "" : " ") + arg;
    found[pid] = line;
  }
  closedir(proc);
  return found;
}

bool AnyRuns(const std::map<int, std::string>& procs, const std::string& cmdline) {
  for (const auto& [pid, line] : procs)
    if (line == cmdline) return true;
  return false;
}

enum class Output { kFile, kDeadPipe, kNohup };

// Starts `argv` with `tag` in its environment and its stdout and stderr into `out` (kFile,
// kNohup) or a pipe (its read end returned in *pipe_read), with SIGHUP ignored for kNohup.
pid_t SpawnTagged(const std::vector<std::string>& argv, const std::string& tag,
                  const std::string& out, Output mode, int* pipe_read) {
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  std::string env = tag;
  int p[2] = {-1, -1};
  if (mode == Output::kDeadPipe && pipe(p) != 0) return -1;
  const pid_t pid = fork();
  if (pid == 0) {
    const int fd =
        mode == Output::kDeadPipe ? p[1] : open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    dup2(fd, 1);
    dup2(fd, 2);
    if (mode == Output::kDeadPipe) close(p[0]);  // the test's: once it closes it, none is left
    putenv(env.data());
    for (int sig : {SIGHUP, SIGINT, SIGQUIT, SIGTERM, SIGPIPE}) signal(sig, SIG_DFL);
    if (mode == Output::kNohup) signal(SIGHUP, SIG_IGN);
    execv(args[0], args.data());
    _exit(127);
  }
  if (mode == Output::kDeadPipe) {
    close(p[1]);
    *pipe_read = p[0];
  }
  return pid;
}

double Seconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// A supervisor in the foreground gets SIGHUP: it stops its children in order, newest first,
// and leaves none of their processes. `c` leaves a process in a session of its own (out of its
// group: found as an adopted orphan and killed at the end), `b` ignores SIGTERM (killed after
// its 1 s grace), `a` is a wrapper whose worker would have outlived a SIGTERM to the shell alone.
void HangupStopsEverything(Output mode) {
  const std::string dir = ::testing::TempDir() + "/supervisor_hup";
  std::filesystem::create_directories(dir);
  {
    std::ofstream f(dir + "/sup.yaml");
    f << "children:\n"
         "  a:\n    command: [sh, -c, 'sleep 321; echo done']\n    stop_grace_s: 5\n"
         "  b:\n    command: [sh, -c, 'trap \"\" TERM; exec sleep 322']\n    stop_grace_s: 1\n"
         "  c:\n    command: [sh, -c, 'setsid sleep 323 & exec sleep 324']\n"
         "    stop_grace_s: 5\n";
  }
  const std::string tag = "OMNI_SUPERVISOR_TEST=hup-" + std::to_string(getpid()) + "-" +
                          std::to_string(static_cast<int>(mode));
  const std::string out = dir + "/out.txt";
  int pipe_read = -1;
  const pid_t sup =
      SpawnTagged({testing::Bin("supervisor"), "--url", "memq://", "--config", dir + "/sup.yaml"},
                  tag, out, mode, &pipe_read);
  ASSERT_GT(sup, 0);
  const std::vector<std::string> sleeps = {"sleep 321", "sleep 322", "sleep 323", "sleep 324"};
  bool up = false;
  for (int i = 0; i < 1000 && !up; ++i) {
    const auto procs = Tagged(tag);
    up = true;
    for (const auto& s : sleeps) up = up && AnyRuns(procs, s);
    if (!up) usleep(10000);
  }
  EXPECT_TRUE(up) << "the children did not start";
  if (mode == Output::kDeadPipe) close(pipe_read);  // as a `| tee` ended by the same hangup
  kill(sup, SIGHUP);
  if (mode == Output::kNohup) {  // ignored (`nohup supervisor`): it carries on
    usleep(500000);
    int status = 0;
    EXPECT_EQ(waitpid(sup, &status, WNOHANG), 0) << "a nohup'ed supervisor ended on SIGHUP";
    for (const auto& s : sleeps) EXPECT_TRUE(AnyRuns(Tagged(tag), s)) << s;
    kill(sup, SIGTERM);
  }
  // When each of the children's processes goes (for at most 3 s after the supervisor's end).
  const double t0 = Seconds();
  std::map<std::string, double> gone;
  int status = 0;
  double exited_at = -1;
  while (Seconds() - t0 < 30) {
    const auto procs = Tagged(tag);
    for (const auto& s : sleeps)
      if (!gone.count(s) && !AnyRuns(procs, s)) gone[s] = Seconds() - t0;
    if (exited_at < 0 && waitpid(sup, &status, WNOHANG) == sup) exited_at = Seconds();
    if (exited_at >= 0 && (gone.size() == sleeps.size() || Seconds() - exited_at > 3)) break;
    usleep(5000);
  }
  // Nothing of theirs is left, reparented anywhere (and nothing is left behind by this test).
  for (const auto& [pid, line] : Tagged(tag)) {
    ADD_FAILURE() << "left running: " << pid << " " << line;
    kill(pid, SIGKILL);
  }
  if (exited_at < 0) {
    kill(sup, SIGKILL);
    waitpid(sup, &status, 0);
    FAIL() << "the supervisor did not end";
  }
  std::ifstream in(out);
  const std::string log((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_TRUE(WIFEXITED(status)) << "the supervisor died of signal "
                                 << (WIFSIGNALED(status) ? WTERMSIG(status) : 0) << "\n"
                                 << log;
  if (WIFEXITED(status)) {
    EXPECT_EQ(WEXITSTATUS(status), 1) << log;  // b needed the SIGKILL
  }
  // Newest first: c's worker, then b after its 1 s grace, then a; c's escapee at the end.
  ASSERT_EQ(gone.size(), sleeps.size()) << log;
  EXPECT_LT(gone["sleep 324"], gone["sleep 322"]);
  // The times are those of /proc scans, which are slow under load and not atomic: a scan may
  // see two deaths a few ms apart in either order, hence the slack.
  EXPECT_GT(gone["sleep 322"] - gone["sleep 324"], 0.5) << "b was not given its grace";
  EXPECT_LE(gone["sleep 322"], gone["sleep 321"] + 0.3) << "a was stopped before b was gone";
  EXPECT_LE(gone["sleep 321"], gone["sleep 323"] + 0.3) << "c's escapee was killed before the stop";
  if (mode != Output::kDeadPipe) {
    for (const char* name : {"a", "b", "c"})
      EXPECT_NE(log.find(std::string("supervisor: ") + name + ": 1 starts, 0 restarts"),
                std::string::npos)
          << name << "\n"
          << log;
    EXPECT_NE(log.find("killed 1 processes the children left behind"), std::string::npos) << log;
    EXPECT_NE(log.find("c: 1 starts, 0 restarts, 0 failures, 0 heartbeat timeouts, stopped"),
              std::string::npos)
        << log;
  }
}

TEST(SupervisorProcess, AHangupStopsTheChildrenInOrderAndLeavesNoneOfTheirProcesses) {
  HangupStopsEverything(Output::kFile);
}

// The same with its output into a pipe whose reader the hangup ended too (`supervisor | tee`):
// a log line must not kill the supervisor half way through the stop (SIGPIPE).
TEST(SupervisorProcess, AHangupStopsInOrderWithTheOutputPipeGone) {
  HangupStopsEverything(Output::kDeadPipe);
}

// Started with SIGHUP ignored (`nohup`), the supervisor outlives a hangup; SIGTERM stops it.
TEST(SupervisorProcess, ANohupedSupervisorOutlivesAHangup) {
  HangupStopsEverything(Output::kNohup);
}

}  // namespace
}  // namespace omni::supervisor
