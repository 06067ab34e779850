// omni-kinect-driver: a Kinect-class RGB-D camera over OpenNI2 -> DEPTH (omni.depth_image_t),
// RGB (omni.color_image_t) and HEARTBEAT.
//
//   omni-kinect-driver --config config/kinect_driver.yaml [--uri URI] [--url URL]
//                      [--duration-s S]
// Exits 1 with a message naming the URI when the device cannot be opened at start; a device
// lost later is reopened every reconnect_interval_s until it comes back.
#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

#include "omni/bus/node_loop.h"
#include "omni/common/driver_args.h"

#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/kinect/kinect_node.h"
#include "omni/kinect/openni2_source.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-kinect-driver --config FILE [--uri URI] [--url URL] "
               "[--duration-s S]\n"
               "Streams a Kinect-class RGB-D camera through OpenNI2 and publishes\n"
               "omni.depth_image_t on DEPTH (16-bit mm, RAW/ZLIB/DELTA_ZLIB) and\n"
               "omni.color_image_t on RGB (RGB8), with intrinsics in every message, plus\n"
               "HEARTBEAT with its counters. --uri \"\" takes the first device; --uri Dummy opens\n"
               "OpenNI2's built-in test device. OpenNI2 loads its drivers from the [Drivers]\n"
               "Repository of /etc/openni2/OpenNI.ini (default: OpenNI2/Drivers next to\n"
               "libOpenNI2.so). Config: config/kinect_driver.yaml; options override it.\n");
  return code;
}
}  // namespace

int main(int argc, char** argv) {
  omni::DriverArgs args;
  if (const int code = omni::ParseDriverArgs(argc, argv, "--uri", Usage, &args); code >= 0)
    return code;
  const std::string& config = args.config;
  const std::string& uri = args.device;
  const std::string& lcm_url = args.lcm_url;
  const bool have_url = args.have_url;
  const double duration_s = args.duration_s;
  const bool have_uri = args.have_device;
  omni::SetLogProcessName("kinect_driver");
  omni::kinect::KinectDriverOptions dopt;
  omni::kinect::KinectNodeOptions nopt;
  omni::Status st = omni::kinect::LoadKinectOptions(config, &dopt, &nopt);
  if (!st.ok()) {
    LOG_ERROR << st.error().ToString();
    return 1;
  }
  if (have_uri) dopt.uri = uri;
  if (have_url) nopt.bus_url = lcm_url;
  omni::kinect::OpenNI2Options oopt;
  oopt.uri = dopt.uri;
  oopt.color = dopt.color;
  oopt.register_depth_to_color = dopt.register_depth_to_color;
  const double kDeg = 3.14159265358979323846 / 180.0;
  oopt.fallback_hfov_rad = dopt.fallback_hfov_deg * kDeg;
  oopt.fallback_vfov_rad = dopt.fallback_vfov_deg * kDeg;
  // The driver times its data timeout and retries on the monotonic clock (its default), so an
  // NTP step neither fakes a silent device nor hides one; the wall clock stamps the messages.
  omni::SystemClock clock;
  omni::kinect::KinectDriver driver(dopt, std::make_unique<omni::kinect::OpenNI2DepthSource>(oopt));
  st = driver.Connect();
  if (!st.ok()) {
    LOG_ERROR << st.error().ToString() << " (uri: '" << dopt.uri << "')";
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
  omni::kinect::KinectNode node(bus->get(), &driver, nopt, &clock);
  node.Run(&g_stop, duration_s);
  LOG_INFO << "published " << node.depth_published() << " depth and " << node.color_published()
           << " colour messages";
  return 0;
}
