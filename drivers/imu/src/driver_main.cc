// omni-imu-driver: a WitMotion WT901/JY901 on a serial port -> IMU (omni.imu_t) + HEARTBEAT.
//
//   omni-imu-driver --config config/imu_driver.yaml [--port PATH] [--url URL]
//                   [--duration-s S]
//   omni-imu-driver --config config/imu_driver.yaml [--port PATH] --setup
// --setup writes the config's rate_hz and `configure:` settings into the IMU, saves them in its
// flash, checks the stream confirms them and exits (0 when it does), without the bus.
// Exits 1 with a message naming the port when the device is absent or sends no frame at start;
// a device lost later is retried until it comes back.
#include <algorithm>
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "omni/bus/node_loop.h"
#include "omni/common/driver_args.h"

#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/imu/imu_node.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-imu-driver --config FILE [--port PATH] [--url URL] "
               "[--duration-s S]\n"
               "       omni-imu-driver --config FILE [--port PATH] --setup\n"
               "Reads a WitMotion WT901/JY901 IMU (0x55 serial protocol) and publishes one\n"
               "omni.imu_t per output period on IMU (acceleration m/s^2, angular rate rad/s,\n"
               "orientation quaternion), plus HEARTBEAT with its counters.\n"
               "Config: config/imu_driver.yaml. --port and --url override the file.\n"
               "--setup: write rate_hz and the configure: settings (baud, outputs) into the\n"
               "IMU once, save them in its flash, check the stream confirms them, exit.\n");
  return code;
}

// Writes and saves the settings once; 0 when the stream confirmed them.
int Setup(omni::imu::DriverOptions o, const omni::Clock* clock) {
  o.configure.enabled = true;
  o.configure.save = true;
  if (!omni::imu::RateCode(o.rate_hz)) {
    LOG_ERROR << "--setup: rate_hz " << o.rate_hz
              << " is not a WT901 output rate (0.2, 0.5, 1, 2, 5, 10, 20, 50, 100 or 200)";
    return 1;
  }
  if (const std::string why = omni::imu::RateBeyondLine(o); !why.empty()) {
    LOG_ERROR << "--setup: rate_hz " << o.rate_hz << " " << why;
    return 1;
  }
  omni::imu::ImuDriver driver(o, clock);
  omni::Status st = driver.Connect();
  if (!st.ok()) {
    LOG_ERROR << st.error().ToString();
    return 1;
  }
  // Connect() returns once frames flow at the new settings; the frame check and the save come
  // with the first whole cycle.
  std::vector<omni::imu::StampedSample> samples;
  // Three periods at the new rate (at 0.2 Hz a period is 5 s) and a data timeout.
  const double wait_s = std::max(5.0, 3.0 / o.rate_hz + o.data_timeout_s);
  const int64_t end = omni::MonotonicMicros() + omni::SecondsToUtime(wait_s);
  while (omni::MonotonicMicros() < end && driver.counters().configurations == 0 &&
         driver.configuring() && driver.counters().config_failures < o.configure.max_attempts)
    driver.Step(50, &samples);
  if (driver.counters().configurations == 0) {
    LOG_ERROR << "the IMU on " << o.port << " did not take the settings ("
              << driver.counters().config_failures << " failed attempts): " << driver.status_text();
    return 1;
  }
  std::printf("IMU on %s set and saved: %g Hz at %d baud, %zu frame types per period\n",
              o.port.c_str(), o.rate_hz, driver.baud(), driver.cycle().types().size());
  std::printf("run it with baud: %d (configure.enabled can stay false)\n", driver.baud());
  return 0;
}
}  // namespace

int main(int argc, char** argv) {
  // --setup is this driver's own flag; the rest is the drivers' common command line.
  bool setup = false;
  std::vector<char*> rest;
  for (int i = 0; i < argc; ++i) {
    if (i > 0 && std::string(argv[i]) == "--setup") {
      setup = true;
    } else {
      rest.push_back(argv[i]);
    }
  }
  omni::DriverArgs args;
  if (const int code =
          omni::ParseDriverArgs(static_cast<int>(rest.size()), rest.data(), "--port", Usage, &args);
      code >= 0)
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
  if (setup) return Setup(dopt, &clock);
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
  omni::bus::AlsoStopOnHangup(OnSignal);  // and SIGPIPE ignored (node_loop.h)
  omni::FixMallocThresholds();            // large buffers go back to the system when freed
  omni::imu::ImuNode node(bus->get(), &driver, nopt, &clock);
  node.Run(&g_stop, duration_s);
  LOG_INFO << "published " << node.published() << " IMU messages";
  return 0;
}
