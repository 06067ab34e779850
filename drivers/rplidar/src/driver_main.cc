// omni-rplidar-driver: an RPLidar on a serial port -> LIDAR_SCAN (omni.laser_scan_t) + HEARTBEAT.
//
//   omni-rplidar-driver --config config/rplidar_driver.yaml [--port PATH] [--url URL]
//                       [--duration-s S]
// Exits 1 with a message naming the port when the device is absent or does not answer at start;
// a device lost later is retried until it comes back.
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/bus/node_loop.h"
#include "omni/common/driver_args.h"

#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/rplidar/rplidar_node.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-rplidar-driver --config FILE [--port PATH] [--url URL] "
               "[--duration-s S]\n"
               "Reads an RPLidar (A1/A2/A3) and publishes one omni.laser_scan_t per revolution\n"
               "on LIDAR_SCAN, plus HEARTBEAT with its counters. Config: "
               "config/rplidar_driver.yaml.\n");
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
  omni::SetLogProcessName("rplidar_driver");
  omni::rplidar::DriverOptions dopt;
  omni::rplidar::NodeOptions nopt;
  omni::Status st = omni::rplidar::LoadRplidarOptions(config, &dopt, &nopt);
  if (!st.ok()) {
    LOG_ERROR << st.error().ToString();
    return 1;
  }
  if (!port.empty()) dopt.port = port;
  if (have_url) nopt.bus_url = lcm_url;
  omni::SystemClock clock;
  omni::rplidar::RplidarDriver driver(dopt, &clock);
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
  omni::bus::AlsoStopOnHangup(OnSignal);  // and SIGPIPE ignored (node_loop.h)
  omni::FixMallocThresholds();            // large buffers go back to the system when freed
  omni::rplidar::RplidarNode node(bus->get(), &driver, nopt, &clock);
  node.Run(&g_stop, duration_s);
  return 0;
}
