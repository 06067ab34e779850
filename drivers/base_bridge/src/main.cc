// omni-base-bridge: BASE_CMD -> CAN -> base firmware; wheel feedback -> WHEEL_ODOM, BASE_STATUS.
//
//   omni-base-bridge --config config/base_bridge.yaml [--can URL] [--url URL] [--duration-s S]
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/base_bridge/base_bridge_node.h"
#include "omni/bus/node_loop.h"
#include "omni/can/can_bus.h"
#include "omni/common/cli.h"
#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-base-bridge --config FILE [--can URL] [--url URL] [--duration-s S]\n"
      "Bridges BASE_CMD to the base firmware over CAN (URL: can0, socketcan:IF or shm:NAME)\n"
      "and publishes WHEEL_ODOM, WHEEL_ENCODERS, BASE_STATUS and HEARTBEAT.\n");
}
}  // namespace

int main(int argc, char** argv) {
  std::string config, can_url, lcm_url;
  double duration_s = -1;
  omni::ArgReader args(argc, argv, "omni-base-bridge", Usage);
  while (args.Next()) {
    if (args.Is("--config")) {
      config = args.Value();
    } else if (args.Is("--can")) {
      can_url = args.Value();
    } else if (args.IsUrl()) {
      lcm_url = args.Value();
    } else if (args.Is("--duration-s")) {
      duration_s = args.Number(0, 1e9);
    } else {
      args.Unknown();
    }
  }
  if (config.empty()) args.Fail("--config FILE is required (e.g. config/base_bridge.yaml)");
  omni::SetLogProcessName("base_bridge");
  auto opts = omni::base_bridge::LoadBaseBridgeOptions(config);
  if (!opts.ok()) {
    LOG_ERROR << opts.error().ToString();
    return 1;
  }
  if (!can_url.empty()) opts->can_url = can_url;
  // A URL that can never open is a mistake to fix, not a device to wait for.
  if (auto u = omni::can::ParseCanUrl(opts->can_url); !u.ok()) {
    LOG_ERROR << u.error().message;
    return 1;
  }
  auto bus = omni::bus::Bus::Create(lcm_url);
  if (!bus.ok()) {
    LOG_ERROR << bus.error().ToString();
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::bus::AlsoStopOnHangup(OnSignal);  // and SIGPIPE ignored (node_loop.h)
  omni::FixMallocThresholds();            // large buffers go back to the system when freed
  omni::SystemClock clock;
  omni::base_bridge::BaseBridgeNode node(*opts, bus->get(), &clock);
  node.Run(&g_stop, duration_s);
  return 0;
}
