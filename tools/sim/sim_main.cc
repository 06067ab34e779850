// omni-sim: the built-in simulator. Drives the three-wheel omni base around a world and writes
// what its sensors would put on the bus (LIDAR_SCAN, WHEEL_ODOM, IMU, DEPTH) to an LCM log, or
// publishes it live, plus the true trajectory for the evaluator.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "omni/base_bridge/base_bridge.h"
#include "omni/base_bridge/messages.h"
#include "omni/base_cmd_t.hpp"
#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/bus/node_loop.h"
#include "omni/common/cli.h"
#include "omni/common/time.h"
#include "omni/firmware/firmware.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/grid.h"
#include "omni/io/lcm_log.h"
#include "omni/io/trajectory_io.h"
#include "omni/sim/simulator.h"

namespace {

std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

// The world as an occupancy grid at 5 cm in the frame whose origin is `origin` (a world pose):
// occupied where a box that stands in the robot's way (from 3 cm to 2 m above the floor, so the
// low boxes the lidar's plane misses too) covers the cell's centre, free elsewhere inside the
// boxes' bounding rectangle (the outer walls), unknown outside it.
omni::io::GridMap TruthMap(const std::vector<omni::sim::Box>& boxes, const omni::Pose2& origin) {
  constexpr double kRes = 0.05;
  double x0 = 1e9, y0 = 1e9, x1 = -1e9, y1 = -1e9;
  for (const auto& b : boxes) {
    x0 = std::min(x0, b.x0);
    y0 = std::min(y0, b.y0);
    x1 = std::max(x1, b.x1);
    y1 = std::max(y1, b.y1);
  }
  omni::io::GridMap m;
  m.resolution_m = kRes;
  if (boxes.empty()) return m;
  // The bounding rectangle's corners in the map frame give the grid's extent.
  const omni::Pose2 inv = origin.Inverse();
  double mx0 = 1e9, my0 = 1e9, mx1 = -1e9, my1 = -1e9;
  for (const auto& c : {Eigen::Vector2d(x0, y0), Eigen::Vector2d(x1, y0), Eigen::Vector2d(x0, y1),
                        Eigen::Vector2d(x1, y1)}) {
    const Eigen::Vector2d p = inv.Transform(c);
    mx0 = std::min(mx0, p.x());
    my0 = std::min(my0, p.y());
    mx1 = std::max(mx1, p.x());
    my1 = std::max(my1, p.y());
  }
  m.origin_x_m = std::floor(mx0 / kRes) * kRes;
  m.origin_y_m = std::floor(my0 / kRes) * kRes;
  m.width = static_cast<int>(std::ceil((mx1 - m.origin_x_m) / kRes));
  m.height = static_cast<int>(std::ceil((my1 - m.origin_y_m) / kRes));
  m.cells.assign(static_cast<size_t>(m.width) * m.height, -1);
  for (int row = 0; row < m.height; ++row)
    for (int col = 0; col < m.width; ++col) {
      const Eigen::Vector2d w =
          origin.Transform({m.origin_x_m + (col + 0.5) * kRes, m.origin_y_m + (row + 0.5) * kRes});
      if (w.x() < x0 || w.x() > x1 || w.y() < y0 || w.y() > y1) continue;
      int8_t v = 0;
      for (const auto& b : boxes)
        if (b.z1 > 0.03 && b.z0 < 2.0 && w.x() >= b.x0 && w.x() <= b.x1 && w.y() >= b.y0 &&
            w.y() <= b.y1) {
          v = 100;
          break;
        }
      m.at(col, row) = v;
    }
  return m;
}

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-sim --out DIR [--world FILE] [--seed N] [--laps N] [--duration S]\n"
      "                [--still S] [--base firmware|ideal] [--slip A,B,C] [--slip-noise S]\n"
      "                [--instant-scans] [--no-depth] [--depth-hz HZ]\n"
      "                [--live URL [--speed X]] [--drive tour|bus] [--cmd-channel NAME]\n"
      "                [--bridge-config FILE] [--walkers N [--walker-speed M]]\n"
      "  Simulates the omni base touring a world (built-in: a 20 x 14 m floor with an inner\n"
      "  room, alcoves, pillars and low obstacles) and writes DIR/sim.lcmlog (LIDAR_SCAN 10 Hz,\n"
      "  WHEEL_ODOM from slipping wheel encoders, IMU 100 Hz, DEPTH 320x240 at 5 Hz) and\n"
      "  DIR/truth.txt (true pose at every scan: index timestamp x y theta) and\n"
      "  DIR/truth_map.{pgm,yaml} (the world at 5 cm in the mappers' frame, for omni eval map).\n"
      "  --base firmware  (default) the base firmware's control loop on the plant model,\n"
      "                 linked by CAN frames to the base bridge, in simulated time:\n"
      "                 WHEEL_ODOM (100 Hz), WHEEL_ENCODERS and BASE_STATUS are the bridge's\n"
      "  --base ideal   kinematic base, encoder scale errors and noise; WHEEL_ODOM at 50 Hz\n"
      "  --still S      stand still S seconds before the tour (default 0), as a robot does\n"
      "                 after power-up (mappers fusing the gyro learn its bias then)\n"
      "  --slip A,B,C   each wheel's mean slip, the fraction of rim motion lost at the ground\n"
      "                 (firmware base; default 0.026,0.010,0.020), redrawn every 5 ms with\n"
      "                 sigma --slip-noise (default 0.01)\n"
      "  --instant-scans  every beam of a scan at one instant (default: over the lidar's 0.1 s\n"
      "                 revolution as the base moves, as a spinning lidar measures them)\n"
      "  --world FILE   YAML `boxes: [[x0, y0, x1, y1, z0, z1], ...]` (the tour is built for\n"
      "                 the built-in world; other worlds must leave its path free)\n"
      "  --walkers N    N people (0-100, default 0) walking back and forth on straight tracks\n"
      "                 of 2.5-10 m drawn from the seed: 0.4 m wide, 1.75 m tall cylinders the\n"
      "                 lidar and the camera see and the truth map leaves out; they wait for\n"
      "                 and step away from the base, which does not steer around them\n"
      "  --walker-speed M  their mean speed (0.1-2 m/s, default 0.8; each +-25 %%)\n"
      "  --live URL     also publish on the bus at X times real time (default 1); URL \"\":\n"
      "                 LCM's default (LCM_DEFAULT_URL)\n"
      "  --drive tour   (default) the built-in tour's waypoint follower drives the base\n"
      "  --drive bus    BASE_CMD (base_cmd_t) from the --live bus drives it, as on the robot:\n"
      "                 a twist holds for the bridge's command timeout, e-stop and clear\n"
      "                 faults work; runs until --duration or SIGINT/SIGTERM (`omni drive`\n"
      "                 sends commands; received commands are not logged)\n"
      "  --cmd-channel NAME  channel of --drive bus (default: the bridge config's, BASE_CMD)\n"
      "  --bridge-config FILE  the base bridge's YAML (config/base_bridge.yaml form): its\n"
      "                 limits, timing, covariances and channels; geometry stays the sim's\n"
      "                 (default: the values config/base_bridge.yaml ships)\n");
}

bool ParseNumber(const std::string& v, double* out) {
  char* end = nullptr;
  *out = std::strtod(v.c_str(), &end);
  return !v.empty() && *end == '\0' && std::isfinite(*out);
}

}  // namespace

int main(int argc, char** argv) {
  std::string out_dir, world_path, live_url, drive = "tour", cmd_channel, bridge_config;
  bool slip_given = false, walker_speed_given = false;
  bool live = false;
  double speed = 1.0;
  omni::sim::SimOptions opt;
  omni::ArgReader args(argc, argv, "omni-sim", Usage);
  while (args.Next()) {
    if (args.Is("--out")) {
      out_dir = args.Value();
    } else if (args.Is("--world")) {
      world_path = args.Value();
    } else if (args.Is("--seed")) {
      opt.seed = static_cast<uint64_t>(args.Integer(0, 1000000000000000));
    } else if (args.Is("--laps")) {
      opt.laps = static_cast<int>(args.Integer(1, 100));
    } else if (args.Is("--duration")) {
      opt.max_duration_s = args.Number(0.1, 1e6);
    } else if (args.Is("--instant-scans")) {
      opt.lidar_sweep = false;
    } else if (args.Is("--no-depth")) {
      opt.depth = false;
    } else if (args.Is("--depth-hz")) {
      opt.depth_hz = args.Number(0.1, 60);
    } else if (args.Is("--base")) {
      const std::string v = args.Value();
      if (v == "firmware") {
        opt.base = omni::sim::SimOptions::Base::kFirmware;
      } else if (v == "ideal") {
        opt.base = omni::sim::SimOptions::Base::kIdeal;
      } else {
        args.Fail("--base expects 'firmware' or 'ideal', got '" + v + "'");
      }
    } else if (args.Is("--slip")) {
      // Three comma-separated fractions in [0, 0.5): each wheel's mean slip (firmware base).
      const std::string v = args.Value();
      std::string rest = v;
      for (int w = 0; w < 3; ++w) {
        const size_t comma = rest.find(',');
        double x = 0;
        if ((w < 2) != (comma != std::string::npos) || !ParseNumber(rest.substr(0, comma), &x) ||
            x < 0 || x >= 0.5)
          args.Fail("--slip expects three fractions in [0, 0.5) like 0.026,0.010,0.020, got '" + v +
                    "'");
        opt.wheel_slip[w] = x;
        slip_given = true;
        rest = comma == std::string::npos ? "" : rest.substr(comma + 1);
      }
    } else if (args.Is("--walkers")) {
      opt.walkers = static_cast<int>(args.Integer(0, 100));
    } else if (args.Is("--walker-speed")) {
      opt.walker_speed_m_s = args.Number(0.1, 2.0);
      walker_speed_given = true;
    } else if (args.Is("--still")) {
      opt.still_s = args.Number(0, 3600);
    } else if (args.Is("--slip-noise")) {
      opt.wheel_slip_noise = args.Number(0, 0.2);
    } else if (args.Is("--live")) {
      live_url = args.Value();
      live = true;
    } else if (args.Is("--speed")) {
      speed = args.Number(0.01, 1000);
    } else if (args.Is("--drive")) {
      drive = args.Value();
      if (drive != "tour" && drive != "bus")
        args.Fail("--drive expects 'tour' or 'bus', got '" + drive + "'");
    } else if (args.Is("--cmd-channel")) {
      cmd_channel = args.Value();
    } else if (args.Is("--bridge-config")) {
      bridge_config = args.Value();
    } else {
      args.Unknown();
    }
  }
  if (out_dir.empty()) {
    std::fprintf(stderr, "omni-sim: --out DIR is required\n");
    Usage(stderr);
    return 2;
  }
  if (speed != 1.0 && !live) {
    std::fprintf(stderr,
                 "omni-sim: --speed paces a --live run; without --live the log is written as fast "
                 "as it can be\n");
    return 2;
  }
  // Options that would be ignored are refused, so a run is what its command line says.
  if ((slip_given || !cmd_channel.empty()) &&
      (slip_given ? opt.base != omni::sim::SimOptions::Base::kFirmware : drive != "bus")) {
    std::fprintf(stderr, "omni-sim: %s\n",
                 slip_given
                     ? "--slip models the firmware base's wheels; it needs --base firmware"
                     : "--cmd-channel is where --drive bus takes its commands; add --drive bus");
    return 2;
  }
  if (walker_speed_given && opt.walkers == 0) {
    std::fprintf(stderr, "omni-sim: --walker-speed sets the walkers' pace; add --walkers N\n");
    return 2;
  }
  if (opt.still_s > 0 && drive == "bus") {
    std::fprintf(stderr,
                 "omni-sim: --still is the tour's wait; with --drive bus the commands decide\n");
    return 2;
  }
  if (drive == "bus" && !live) {
    std::fprintf(stderr, "omni-sim: --drive bus needs --live URL (the bus the commands come on)\n");
    return 2;
  }
  if (!bridge_config.empty()) {
    auto b = omni::base_bridge::LoadBaseBridgeOptions(bridge_config);
    if (!b.ok()) {
      std::fprintf(stderr, "omni-sim: %s\n", b.error().message.c_str());
      return 1;
    }
    opt.bridge = *b;
  }
  if (cmd_channel.empty())
    cmd_channel =
        opt.bridge ? opt.bridge->cmd_channel : omni::base_bridge::BaseBridgeOptions().cmd_channel;
  omni::sim::World world = omni::sim::World::BuiltIn();
  if (!world_path.empty()) {
    auto w = omni::sim::World::Load(world_path);
    if (!w.ok()) {
      std::fprintf(stderr, "omni-sim: %s\n", w.error().message.c_str());
      return 1;
    }
    world = std::move(*w);
  }
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) {
    std::fprintf(stderr, "omni-sim: cannot create '%s': %s\n", out_dir.c_str(),
                 ec.message().c_str());
    return 1;
  }
  auto log = omni::io::LcmLogWriter::Open(out_dir + "/sim.lcmlog");
  if (!log.ok()) {
    std::fprintf(stderr, "omni-sim: %s\n", log.error().message.c_str());
    return 1;
  }
  std::unique_ptr<omni::bus::Bus> bus;
  if (live) {
    auto b = omni::bus::Bus::Create(live_url);
    if (!b.ok()) {
      std::fprintf(stderr, "omni-sim: %s\n", b.error().message.c_str());
      return 1;
    }
    bus = std::move(*b);
  }
  // Live, the simulator stands in for the drivers and the base bridge: it says so on HEARTBEAT
  // (process omni_sim) like every omni process, so `omni status` and the supervisor see it.
  omni::SystemClock hb_clock;
  std::unique_ptr<omni::bus::Heartbeat> hb;
  int64_t events_published = 0, commands_in = 0;
  if (bus) {
    hb = std::make_unique<omni::bus::Heartbeat>(bus.get(), "omni_sim", &hb_clock);
    hb->AddCounter("events_published", [&] { return events_published; });
    hb->AddCounter("commands_in", [&] { return commands_in; });
    hb->SetState(omni::heartbeat_t::STATE_OK,
                 drive == "bus" ? "simulating, driven on " + cmd_channel : "simulating the tour");
  }
  omni::Status write_status;
  const auto wall_start = std::chrono::steady_clock::now();
  auto sink = [&](const omni::sim::SimEvent& e) {
    if (write_status.ok())
      write_status = log->Write(e.utime, e.channel, e.payload.data(), e.payload.size());
    if (bus) {
      const double sim_s = static_cast<double>(e.utime - opt.start_utime) * 1e-6;
      std::this_thread::sleep_until(wall_start + std::chrono::duration<double>(sim_s / speed));
      bus->PublishRaw(e.channel, e.payload.data(), static_cast<int>(e.payload.size()));
      ++events_published;
      hb->Tick();
    }
  };
  std::vector<omni::io::TrajectoryEntry> truth;
  const std::vector<omni::sim::Box> boxes = world.boxes();
  omni::sim::Simulator sim(std::move(world), opt);
  // --drive bus: BASE_CMD from the bus, received as simulated time catches up with the wall
  // clock (the run is paced to it), handed to the base at the step it arrived in.
  std::vector<omni::base_bridge::Command> inbox;
  if (drive == "bus") {
    bus->Subscribe<omni::base_cmd_t>(cmd_channel, [&](const omni::base_cmd_t& m, int64_t) {
      inbox.push_back(omni::base_bridge::FromMessage(m));
      ++commands_in;
    });
    sim.set_command_source([&](int64_t utime, std::vector<omni::base_bridge::Command>* cmds) {
      const double sim_s = static_cast<double>(utime - opt.start_utime) * 1e-6;
      std::this_thread::sleep_until(wall_start + std::chrono::duration<double>(sim_s / speed));
      while (bus->HandleTimeout(0) > 0) {
      }
      cmds->insert(cmds->end(), inbox.begin(), inbox.end());
      inbox.clear();
      return !g_stop;
    });
  }
  // Ctrl-C or a supervisor's SIGTERM ends the run at the next step; the log is closed and the
  // truth written for what was simulated (the process used to die with neither).
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::bus::AlsoStopOnHangup(OnSignal);  // and SIGPIPE ignored (node_loop.h)
  sim.set_stop_flag(&g_stop);
  const omni::sim::SimStats st =
      sim.Run(sink, [&](int64_t index, int64_t utime, const omni::Pose2& p) {
        truth.push_back(omni::io::MakeEntry2D(index, omni::UtimeToSeconds(utime), p));
      });
  if (hb) {  // the last word on the bus: gone on purpose, not hung
    hb->SetState(omni::heartbeat_t::STATE_STOPPING, "simulation over");
    hb->Tick(true);
  }
  if (write_status.ok()) write_status = log->Close();
  if (write_status.ok())
    write_status = omni::io::WriteTrajectory2D(
        out_dir + "/truth.txt", truth, "scan_index timestamp x y theta (simulated ground truth)");
  // The ground-truth map for `omni eval map`, in the frame the mappers build theirs in (the
  // robot's pose at the first scan is the origin).
  if (write_status.ok() && !truth.empty())
    write_status =
        omni::io::WriteMapServer(TruthMap(boxes, truth.front().pose2()), out_dir + "/truth_map");
  // The walkers' tracks, in the same frame, for looking up what a map kept of them.
  if (write_status.ok() && !sim.walker_tracks().empty() && !truth.empty()) {
    const omni::Pose2 inv = truth.front().pose2().Inverse();
    std::string text =
        "# walker ax ay bx by speed_m_s (track ends in the map frame: the robot's "
        "pose at the first scan)\n";
    char line[160];
    for (size_t i = 0; i < sim.walker_tracks().size(); ++i) {
      const auto& t = sim.walker_tracks()[i];
      const Eigen::Vector2d a = inv.Transform({t.ax, t.ay}), b = inv.Transform({t.bx, t.by});
      std::snprintf(line, sizeof(line), "%zu %.3f %.3f %.3f %.3f %.3f\n", i, a.x(), a.y(), b.x(),
                    b.y(), t.speed_m_s);
      text += line;
    }
    std::FILE* f = std::fopen((out_dir + "/walkers.txt").c_str(), "w");
    if (f == nullptr || std::fputs(text.c_str(), f) < 0 || std::fclose(f) != 0)
      write_status = omni::MakeError(omni::ErrorCode::kIo, out_dir + "/walkers.txt: cannot write");
  }
  if (!write_status.ok()) {
    std::fprintf(stderr, "omni-sim: %s\n", write_status.message().c_str());
    return 1;
  }
  std::printf(
      "omni-sim: %.1f s simulated (%s), %.1f m driven, %.1f rad turned: %lld scans, %lld "
      "odometry, %lld IMU, %lld depth frames -> %s/{sim.lcmlog,truth.txt,truth_map.*}\n",
      st.duration_s,
      st.tour_finished ? "tour finished"
      : st.stopped     ? "stopped by a signal"
                       : "stopped by --duration",
      st.distance_m, st.rotation_rad, static_cast<long long>(st.scans),
      static_cast<long long>(st.odometry), static_cast<long long>(st.imu),
      static_cast<long long>(st.depth_frames), out_dir.c_str());
  if (st.walkers > 0) {
    std::printf(
        "omni-sim: %d walkers, %.1f m walked; %.1f walker-seconds spent waiting for or "
        "stepping away from the base, %.2f touching it\n",
        st.walkers, st.walker_distance_m, static_cast<double>(st.walker_yields) / opt.physics_hz,
        static_cast<double>(st.walker_contacts) / opt.physics_hz);
  }
  if (st.walkers < opt.walkers)
    std::fprintf(stderr, "omni-sim: the world had free floor for only %d of %d walkers\n",
                 st.walkers, opt.walkers);
  if (drive == "bus") {
    const int64_t bad_commands = bus->counters().decode_errors;
    std::printf(
        "omni-sim: driven from %s on the bus: %lld commands, %lld refused by the base, "
        "%lld undecodable messages\n",
        cmd_channel.c_str(), static_cast<long long>(st.commands),
        static_cast<long long>(st.commands_rejected), static_cast<long long>(bad_commands));
  }
  if (opt.base == omni::sim::SimOptions::Base::kFirmware) {
    static const char* kStates[] = {"BOOT", "IDLE", "RUNNING", "STOPPING", "FAULT", "ESTOP"};
    const char* state =
        st.firmware_state >= 0 && st.firmware_state < 6 ? kStates[st.firmware_state] : "unknown";
    std::printf(
        "omni-sim: firmware in the loop: %lld CAN frames, %lld encoder and %lld status messages; "
        "firmware %s, fault bits 0x%x, %u watchdog stops; bridge: %s\n",
        static_cast<long long>(st.can_frames), static_cast<long long>(st.encoders),
        static_cast<long long>(st.base_status), state, st.firmware_faults, st.watchdog_trips,
        st.base_problem.empty() ? "ok" : st.base_problem.c_str());
    // The watchdog and bad-command bits are warnings (a watchdog stop after the last command
    // is the base doing its job); latched faults and an unhealthy bridge are not.
    // Driven from the bus, an e-stop left on at the end is the operator's choice, not a fault
    // (the bridge reports it as a fault bit, so its health text is not a problem either then).
    const uint32_t latched = st.firmware_faults & omni::firmware::kLatchedFaults;
    if (drive == "bus" && latched == omni::firmware::kFaultEstop) {
      std::printf("omni-sim: the base ends e-stopped, as commanded on %s\n", cmd_channel.c_str());
    } else if (!st.base_problem.empty() || latched != 0) {
      std::fprintf(stderr, "omni-sim: the simulated base ended unhealthy (see above)\n");
      return 1;
    }
  }
  return 0;
}
