// omni-imu-driver: a WitMotion WT901/JY901 on a serial port -> IMU (omni.imu_t) + HEARTBEAT.
//
//   omni-imu-driver --config config/imu_driver.yaml [--port PATH] [--url URL]
//                   [--duration-s S]
// Exits 1 with a message naming the port when the device is absent or sends no frame at start;
// a device lost later is retried until it comes back.
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/common/driver_args.h"

#include "omni/common/log.h"
#include "omni/imu/imu_node.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-imu-driver --config FILE [--port PATH] [--url URL] "
               "[--duration-s S]\n"
               "Reads a WitMotion WT901/JY901 IMU (0x55 serial protocol) and publishes one\n"
               "omni.imu_t per output period on IMU (acceleration m/s^2, angular rate rad/s,\n"
               "orientation quaternion), plus HEARTBEAT with its counters.\n"
               "Config: config/imu_driver.yaml. --port and --url override the file.\n");
  return code;
}
}  // namespace

int main(int argc, char** argv) {
  omni::DriverArgs args;
  if (const int code = omni::ParseDriverArgs(argc, argv, "--port", Usage, &args); code >= 0)
    return code;
  const std::string& config = args.config;
  const std::string& port = args.device;
  const std::string& lcm_url = args.lcm_url;
  const bool have_url = args.have_url;
  const double duration_s = args.duration_s;
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
