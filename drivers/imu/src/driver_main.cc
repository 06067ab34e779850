// omni-imu-driver: a WitMotion WT901/JY901 on a serial port -> IMU (omni.imu_t) + HEARTBEAT.
//
//   omni-imu-driver --config config/imu_driver.yaml [--port PATH] [--lcm-url URL]
//                   [--duration-s S]
// Exits 1 with a message naming the port when the device is absent or sends no frame at start;
// a device lost later is retried until it comes back.
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/common/log.h"
#include "omni/imu/imu_node.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-imu-driver --config FILE [--port PATH] [--lcm-url URL] "
               "[--duration-s S]\n"
               "Reads a WitMotion WT901/JY901 IMU (0x55 serial protocol) and publishes one\n"
               "omni.imu_t per output period on IMU (acceleration m/s^2, angular rate rad/s,\n"
               "orientation quaternion), plus HEARTBEAT with its counters.\n"
               "Config: config/imu_driver.yaml. --port and --lcm-url override the file.\n");
  return code;
}
}  // namespace

int main(int argc, char** argv) {
  std::string config, port, lcm_url;
  bool have_url = false;
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
    if (a == "--config") {
      config = next();
    } else if (a == "--port") {
      port = next();
    } else if (a == "--lcm-url") {
      lcm_url = next();
      have_url = true;
    } else if (a == "--duration-s") {
      char* end = nullptr;
      const std::string v = next();
      duration_s = std::strtod(v.c_str(), &end);
      if (end == v.c_str() || *end != '\0') {
        std::fprintf(stderr, "--duration-s: '%s' is not a number\n", v.c_str());
        return Usage(2);
      }
    } else {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      return Usage(2);
    }
  }
  if (config.empty()) {
    std::fprintf(stderr, "--config is required\n");
    return Usage(2);
  }
  omni::SetLogProcessName("imu_driver");
  omni::imu::DriverOptions dopt;
  omni::imu::NodeOptions nopt;
  omni::Status st = omni::imu::LoadImuOptions(config, &dopt, &nopt);
  if (!st.ok()) {
    LOG_ERROR << st.error().ToString();
    return 1;
  }
  if (!port.empty()) dopt.port = port;
  if (have_url) nopt.bus_url = lcm_url;
  omni::SystemClock clock;
  omni::imu::ImuDriver driver(dopt, &clock);
  st = driver.Connect();
  if (!st.ok()) {
    LOG_ERROR << st.error().ToString();
    return 1;
  }
  auto bus = omni::bus::Bus::Create(nopt.bus_url);
  if (!bus.ok()) {
    LOG_ERROR << bus.error().ToString();
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::imu::ImuNode node(bus->get(), &driver, nopt, &clock);
  node.Run(&g_stop, duration_s);
  LOG_INFO << "published " << node.published() << " IMU messages";
  return 0;
}
