// omni-firmware-sim: the firmware core running on Linux against the plant model. It is wired
// to a CAN bus exactly as the board is (same frames, same timing) and publishes nothing else.
//
//   omni-firmware-sim --config config/firmware_sim.yaml [--can shm:NAME] [--slip a,b,c]
//                     [--truth-out FILE] [--duration-s S] [--param-store FILE]
//
// --truth-out writes, every 10 ms, CSV lines t_s,x_m,y_m,theta_rad,distance_m,cmd_x_m,
// cmd_y_m,cmd_theta_rad: the plant's true pose, and the pose the firmware was commanded to
// reach (its wheel targets integrated through the forward kinematics in firmware time), so
// tests can compare odometry with both the truth and the command as the base received it.
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <sstream>
#include <string>
#include <thread>

#include "host_hal.h"
#include "omni/can/can_bus.h"
#include "omni/common/cli.h"
#include "omni/common/log.h"
#include "omni/common/stop_signals.h"
#include "omni/firmware/can_protocol.h"
#include "omni/firmware/firmware.h"
#include "plant.h"
#include "sim_config.h"

namespace {

std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

void Usage(std::FILE* f) {
  std::fprintf(f,
               "usage: omni-firmware-sim --config FILE [--can URL] [--slip s1,s2,s3]\n"
               "                         [--truth-out FILE] [--duration-s S] [--param-store FILE]\n"
               "Runs the base firmware against a simulated motor/wheel plant on a CAN bus\n"
               "(URL shm:NAME for the user-space bus, socketcan:IF for a real interface).\n"
               "--param-store FILE: the board's parameter flash (SAVE_PARAMS writes it, the next\n"
               "start reads it; default: in memory, empty at start).\n");
}

// As the board's controller hands frames over (hal_stm32f4.cc): an extended or remote (RTR)
// frame is the unknown id 0x7FF with no data, counted by the firmware as rx_unknown.
omni::firmware::CanFrame ToFw(const omni::can::Frame& f) {
  omni::firmware::CanFrame o;
  if (f.extended || f.rtr) {
    o.id = omni::firmware::can::kForeignFrameId;
    o.dlc = 0;
    return o;
  }
  o.id = static_cast<uint16_t>(f.id & 0x7FF);
  o.dlc = f.dlc;
  for (int i = 0; i < 8; ++i) o.data[i] = f.data[i];
  return o;
}
omni::can::Frame FromFw(const omni::firmware::CanFrame& f) {
  omni::can::Frame o;
  o.id = f.id;
  o.dlc = f.dlc;
  for (int i = 0; i < 8; ++i) o.data[i] = f.data[i];
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace omni::firmware;
  std::string config, can_override, slip_arg, truth_path;
  double duration_s = -1.0;
  std::string param_store;
  omni::ArgReader args(argc, argv, "omni-firmware-sim", Usage);
  while (args.Next()) {
    if (args.Is("--config")) {
      config = args.Value();
    } else if (args.Is("--can")) {
      can_override = args.Value();
    } else if (args.Is("--slip")) {
      slip_arg = args.Value();
    } else if (args.Is("--truth-out")) {
      truth_path = args.Value();
    } else if (args.Is("--duration-s")) {
      duration_s = args.Number(0, 1e9);
    } else if (args.Is("--param-store")) {
      param_store = args.Value();
    } else {
      args.Unknown();
    }
  }
  if (config.empty()) args.Fail("--config FILE is required (e.g. config/firmware_sim.yaml)");
  omni::SetLogProcessName("firmware_sim");
  auto opts = sim::LoadSimOptions(config);
  if (!opts.ok()) {
    LOG_ERROR << opts.error().ToString();
    return 1;
  }
  if (!can_override.empty()) opts->can_url = can_override;
  if (!slip_arg.empty()) {
    std::stringstream ss(slip_arg);
    std::string item;
    for (int w = 0; w < 3; ++w) {
      if (!std::getline(ss, item, ',')) {
        LOG_ERROR << "--slip needs three comma-separated values, got '" << slip_arg << "'";
        return 2;
      }
      char* end = nullptr;
      const double s = std::strtod(item.c_str(), &end);
      if (item.empty() || *end != '\0' || !(s >= 0.0 && s < 1.0)) {
        LOG_ERROR << "--slip values must be in [0, 1), got '" << item << "'";
        return 2;
      }
      opts->plant.slip[w] = s;
    }
  }
  FILE* truth = nullptr;
  if (!truth_path.empty()) {
    truth = std::fopen(truth_path.c_str(), "w");
    if (truth == nullptr) {
      LOG_ERROR << "cannot write " << truth_path;
      return 1;
    }
    std::fprintf(truth, "t_s,x_m,y_m,theta_rad,distance_m,cmd_x_m,cmd_y_m,cmd_theta_rad\n");
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::AlsoStopOnHangup(OnSignal);  // a closed terminal stops it in order too

  sim::Plant plant(opts->plant);
  sim::HostHal hal(&plant);
  hal.tx_mailboxes = 3;  // as the board's bxCAN: frames beyond wait in the firmware's queue
  if (!param_store.empty()) hal.UseParamStoreFile(param_store);
  Firmware fw(&hal, opts->firmware);
  if (fw.Init() != FwStatus::kOk) {
    LOG_ERROR << "firmware parameters rejected";
    return 1;
  }
  static const char* kStore[] = {"empty: compiled defaults", "loaded", "corrupt: compiled defaults",
                                 "none"};
  LOG_INFO << "parameter store: " << kStore[static_cast<int>(fw.param_store_state()) & 3]
           << (fw.param_store_state() == ParamStoreState::kLoaded
                   ? " (" + std::to_string(fw.params_stored()) + " parameters)"
                   : std::string());
  std::unique_ptr<omni::can::CanBus> bus;
  auto last_open = std::chrono::steady_clock::now() - std::chrono::seconds(1);
  auto try_open = [&]() {
    last_open = std::chrono::steady_clock::now();
    auto b = omni::can::OpenCanBus(opts->can_url);
    if (b.ok()) {
      bus = std::move(b).value();
      hal.bus_off = false;
      LOG_INFO << "on CAN " << bus->name() << " as node " << int(opts->firmware.node_id);
    } else {
      hal.bus_off = true;
    }
  };
  try_open();
  if (!bus) {
    LOG_WARN << "CAN " << opts->can_url << " not available yet; retrying";
  }

  const double dt = opts->firmware.control_period_us * 1e-6;
  const auto period = std::chrono::microseconds(opts->firmware.control_period_us);
  auto next = std::chrono::steady_clock::now();
  const auto start = next;
  int64_t steps = 0, late = 0;
  const omni::kinematics::OmniGeometry<double> geom{
      opts->firmware.alpha_rad, opts->firmware.center_to_wheel_m, opts->firmware.wheel_radius_m};
  double cmd_x = 0, cmd_y = 0, cmd_theta = 0;
  while (!g_stop) {
    // Frames that arrived since the last period go to the controller's receive FIFO.
    if (bus) {
      omni::can::Frame f;
      for (int n = 0; n < 64; ++n) {
        auto r = bus->Receive(&f, 0);
        if (!r.ok()) {
          LOG_WARN << r.error().message << ": CAN controller bus-off";
          bus.reset();
          hal.bus_off = true;
          break;
        }
        if (!r.value()) break;
        hal.Deliver(ToFw(f));
      }
    } else if (std::chrono::steady_clock::now() - last_open > std::chrono::milliseconds(100)) {
      try_open();
    }
    fw.Step();
    plant.Advance(dt);
    ++steps;
    {
      omni::kinematics::WheelSpeeds<double> rim;
      for (int w = 0; w < 3; ++w) rim.v_m_s[w] = fw.wheel(w).target_rad_s * geom.wheel_radius_m;
      omni::kinematics::BodyTwist<double> body;
      if (fw.state() == State::kRunning && omni::kinematics::WheelsToBody(geom, rim, &body)) {
        const auto world =
            omni::kinematics::BodyToWorld(cmd_theta + 0.5 * dt * body.omega_rad_s, body);
        cmd_x += dt * world.xdot_m_s;
        cmd_y += dt * world.ydot_m_s;
        cmd_theta += dt * world.thetadot_rad_s;
      }
    }
    while (!hal.tx.empty()) {
      if (bus && !bus->Send(FromFw(hal.tx.front())).ok()) {
        bus.reset();
        hal.bus_off = true;
      }
      hal.tx.pop_front();
    }
    if (truth != nullptr && steps % 10 == 0) {
      std::fprintf(truth, "%.3f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f\n", steps * dt, plant.x_m(),
                   plant.y_m(), plant.theta_rad(), plant.distance_m(), cmd_x, cmd_y, cmd_theta);
      std::fflush(truth);
    }
    if (duration_s > 0 && steps * dt >= duration_s) break;
    next += period;
    const auto now = std::chrono::steady_clock::now();
    if (now < next) {
      std::this_thread::sleep_until(next);
    } else if (now - next > std::chrono::milliseconds(50)) {
      ++late;  // the host stalled: resume from now rather than racing to catch up
      next = now;
    }
  }
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  LOG_INFO << "stopped after " << steps << " steps (" << wall << " s wall, " << late
           << " stalls), state " << int(fw.state()) << ", faults 0x" << std::hex << fw.fault_bits();
  if (truth != nullptr) std::fclose(truth);
  return 0;
}
