// omni-base-bridge: BASE_CMD -> CAN -> base firmware; wheel feedback -> WHEEL_ODOM, BASE_STATUS.
//
//   omni-base-bridge --config config/base_bridge.yaml [--can URL] [--lcm-url URL] [--duration-s S]
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/base_bridge/base_bridge_node.h"
#include "omni/common/log.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(
      code == 0 ? stdout : stderr,
      "usage: omni-base-bridge --config FILE [--can URL] [--lcm-url URL] [--duration-s S]\n"
      "Bridges BASE_CMD to the base firmware over CAN (URL socketcan:IF or shm:NAME)\n"
      "and publishes WHEEL_ODOM, WHEEL_ENCODERS, BASE_STATUS and HEARTBEAT.\n");
  return code;
}
}  // namespace

int main(int argc, char** argv) {
  std::string config, can_url, lcm_url;
  double duration_s = -1;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(Usage(2));
      }
      return argv[++i];
    };
    if (a == "--help" || a == "-h") return Usage(0);
    if (a == "--config")
      config = next();
    else if (a == "--can")
      can_url = next();
    else if (a == "--lcm-url")
      lcm_url = next();
    else if (a == "--duration-s")
      duration_s = std::atof(next().c_str());
    else {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      return Usage(2);
    }
  }
  if (config.empty()) return Usage(2);
  omni::SetLogProcessName("base_bridge");
  auto opts = omni::base_bridge::LoadBaseBridgeOptions(config);
  if (!opts.ok()) {
    LOG_ERROR << opts.error().ToString();
    return 1;
  }
  if (!can_url.empty()) opts->can_url = can_url;
  auto bus = omni::bus::Bus::Create(lcm_url);
  if (!bus.ok()) {
    LOG_ERROR << bus.error().ToString();
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::SystemClock clock;
  omni::base_bridge::BaseBridgeNode node(*opts, bus->get(), &clock);
  node.Run(&g_stop, duration_s);
  return 0;
}
