// omni-devices: the robot's USB devices (libusb) and the Kinect v1 motor.
//
//   omni-devices [--json]          list lidar/IMU serial bridges and Kinect v1 parts
//   omni-devices kinect-tilt DEG   tilt the Kinect v1 (-31..31 degrees)
//   omni-devices kinect-led N      set the Kinect v1 LED (0 off .. 6)
//   omni-devices kinect-accel      read the Kinect v1 accelerometer and tilt state
#include <libusb.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <vector>

#include "omni/common/json.h"
#include "usb_devices.h"

namespace {

using omni::JsonEscape;
using omni::devices::Classification;
using omni::devices::DeviceKind;

constexpr char kSysfsUsb[] = "/sys/bus/usb/devices";
constexpr unsigned kTimeoutMs = 1000;

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-devices [--json]\n"
               "       omni-devices kinect-tilt DEG | kinect-led N | kinect-accel\n"
               "Lists connected USB devices the robot uses: USB-serial bridges (RPLidar or\n"
               "serial IMU: CP210x 10c4:ea60, CH340 1a86:7523, FTDI 0403:6001, ...) with their\n"
               "/dev/tty node, and Kinect v1 parts (045e:02ae camera, 02b0 motor, 02ad audio).\n"
               "kinect-tilt sets the tilt motor (-31..31 degrees), kinect-led the LED (0 off,\n"
               "1 green, 2 red, 3 yellow, 4/5 blink green, 6 blink red/yellow), kinect-accel\n"
               "reads the accelerometer (m/s^2) and the tilt state. Needs USB access (udev\n"
               "rule or root) for the Kinect commands.\n");
  return code;
}

struct Found {
  int bus = 0;
  int address = 0;
  std::string port;
  uint16_t vendor = 0, product = 0;
  Classification what;
  std::vector<std::string> ttys;
};

int List(bool json) {
  libusb_context* ctx = nullptr;
  std::vector<Found> found;
  const bool usb = libusb_init(&ctx) == 0;
  if (usb) {
    libusb_device** list = nullptr;
    const ssize_t n = libusb_get_device_list(ctx, &list);
    for (ssize_t i = 0; i < n; ++i) {
      libusb_device_descriptor desc;
      if (libusb_get_device_descriptor(list[i], &desc) != 0) continue;
      Found f;
      f.vendor = desc.idVendor;
      f.product = desc.idProduct;
      f.what = omni::devices::Classify({f.vendor, f.product});
      if (f.what.kind == DeviceKind::kUnknown) continue;
      f.bus = libusb_get_bus_number(list[i]);
      f.address = libusb_get_device_address(list[i]);
      uint8_t ports[8];
      const int np = libusb_get_port_numbers(list[i], ports, 8);
      std::vector<int> chain;
      for (int k = 0; k < np; ++k) chain.push_back(ports[k]);
      f.port = omni::devices::SysfsPortName(f.bus, chain);
      if (f.what.kind == DeviceKind::kSerialBridge) {
        f.ttys = omni::devices::TtyNodes(kSysfsUsb, f.port);
      }
      found.push_back(f);
    }
    if (n >= 0) libusb_free_device_list(list, 1);
    libusb_exit(ctx);
  } else {
    // Said in both forms, and exit 1: "no devices" would be a false answer.
    std::fprintf(stderr, "omni-devices: libusb could not start: no USB access on this machine\n");
  }
  if (json) {
    std::printf("[");
    for (size_t i = 0; i < found.size(); ++i) {
      const Found& f = found[i];
      std::printf(
          "%s\n  {\"bus\": %d, \"address\": %d, \"port\": \"%s\", \"id\": \"%04x:%04x\", "
          "\"kind\": \"%s\", \"what\": \"%s\", \"tty\": [",
          i ? "," : "", f.bus, f.address, f.port.c_str(), f.vendor, f.product,
          omni::devices::DeviceKindName(f.what.kind), JsonEscape(f.what.what).c_str());
      for (size_t k = 0; k < f.ttys.size(); ++k) {
        std::printf("%s\"%s\"", k ? ", " : "", f.ttys[k].c_str());
      }
      std::printf("]}");
    }
    std::printf("%s]\n", found.empty() ? "" : "\n");
    return usb ? 0 : 1;
  }
  if (!usb) return 1;
  if (found.empty()) {
    std::printf("no known devices (USB-serial bridges for RPLidar/IMU, Kinect v1 parts)\n");
    return 0;
  }
  std::printf("%-10s %-9s %-14s %s\n", "port", "id", "tty", "what");
  for (const Found& f : found) {
    std::string tty;
    for (const std::string& t : f.ttys) tty += (tty.empty() ? "" : ",") + t;
    if (tty.empty()) tty = "-";
    char id[16];
    std::snprintf(id, sizeof(id), "%04x:%04x", f.vendor, f.product);
    std::printf("%-10s %-9s %-14s %s\n", f.port.c_str(), id, tty.c_str(), f.what.what.c_str());
  }
  return 0;
}

// Opens the first Kinect v1 motor and runs `body` with a libusb control-transfer function.
int WithMotor(const std::function<int(const omni::devices::TransferFn&)>& body) {
  libusb_context* ctx = nullptr;
  if (libusb_init(&ctx) != 0) {
    std::fprintf(stderr, "no Kinect motor (045e:02b0) found: libusb could not start\n");
    return 1;
  }
  // Find it first, then open: "absent" and "present but not ours to open" need different fixes.
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx, &list);
  libusb_device* motor = nullptr;
  for (ssize_t i = 0; i < n && motor == nullptr; ++i) {
    libusb_device_descriptor desc;
    if (libusb_get_device_descriptor(list[i], &desc) == 0 &&
        desc.idVendor == omni::devices::kMicrosoftVendor &&
        desc.idProduct == omni::devices::kKinectMotorProduct) {
      motor = list[i];
    }
  }
  libusb_device_handle* h = nullptr;
  int open_rc = 0;
  if (motor != nullptr) open_rc = libusb_open(motor, &h);
  const int bus = motor ? libusb_get_bus_number(motor) : 0;
  const int address = motor ? libusb_get_device_address(motor) : 0;
  if (n >= 0) libusb_free_device_list(list, 1);
  if (motor == nullptr) {
    std::fprintf(stderr, "no Kinect motor (045e:02b0) found\n");
    libusb_exit(ctx);
    return 1;
  }
  if (open_rc != 0 || h == nullptr) {
    std::fprintf(stderr,
                 "Kinect motor (045e:02b0) on bus %d address %d: cannot open it: %s (needs a "
                 "udev rule giving access to 045e:02b0, or root)\n",
                 bus, address, libusb_error_name(open_rc));
    libusb_exit(ctx);
    return 1;
  }
  const omni::devices::TransferFn transfer = [h](const omni::devices::ControlRequest& r,
                                                 uint8_t* data) {
    static uint8_t none[1];
    return libusb_control_transfer(h, r.request_type, r.request, r.value, r.index,
                                   data ? data : none, r.length, kTimeoutMs);
  };
  const int rc = body(transfer);
  libusb_close(h);
  libusb_exit(ctx);
  return rc;
}

bool ParseNumber(const char* s, double* out) {
  char* end = nullptr;
  *out = std::strtod(s, &end);
  return end != s && *end == '\0';
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  if (args.empty()) return List(false);
  const std::string cmd = args[0];
  if (cmd == "--help" || cmd == "-h") return Usage(0);
  if (cmd == "--json" && args.size() == 1) return List(true);
  if (cmd == "kinect-tilt" || cmd == "kinect-led") {
    double v = 0;
    if (args.size() != 2 || !ParseNumber(args[1].c_str(), &v)) {
      std::fprintf(stderr, "%s needs one number\n", cmd.c_str());
      return Usage(2);
    }
    // Check the value before looking for the device, so a typo is reported as such.
    if (cmd == "kinect-tilt") {
      auto r = omni::devices::TiltRequest(v);
      if (!r.ok()) {
        std::fprintf(stderr, "%s\n", r.error().message.c_str());
        return 2;
      }
    } else {
      // The range first: casting NaN or 1e300 to int is undefined.
      if (!(v >= 0 && v <= 6) || v != std::floor(v)) {
        std::fprintf(stderr, "LED mode must be an integer 0..6\n");
        return 2;
      }
      auto r = omni::devices::LedRequest(static_cast<int>(v));
      if (!r.ok()) {
        std::fprintf(stderr, "%s\n", r.error().message.c_str());
        return 2;
      }
    }
    return WithMotor([&](const omni::devices::TransferFn& t) {
      const omni::Status st = cmd == "kinect-tilt" ? omni::devices::SetTilt(t, v)
                                                   : omni::devices::SetLed(t, static_cast<int>(v));
      if (!st.ok()) {
        std::fprintf(stderr, "%s\n", st.error().message.c_str());
        return 1;
      }
      if (cmd == "kinect-tilt") {
        std::printf("tilt set to %.1f degrees\n", v);
      } else {
        std::printf("LED set to %d (%s)\n", static_cast<int>(v),
                    omni::devices::LedModeName(static_cast<int>(v)));
      }
      return 0;
    });
  }
  if (cmd == "kinect-accel" && args.size() == 1) {
    return WithMotor([](const omni::devices::TransferFn& t) {
      auto s = omni::devices::ReadMotorState(t);
      if (!s.ok()) {
        std::fprintf(stderr, "%s\n", s.error().message.c_str());
        return 1;
      }
      std::printf("accel m/s^2: %.3f %.3f %.3f (counts %d %d %d)\n", s->accel_m_s2[0],
                  s->accel_m_s2[1], s->accel_m_s2[2], s->accel_counts[0], s->accel_counts[1],
                  s->accel_counts[2]);
      if (s->tilt_known) {
        std::printf("tilt: %.1f degrees, motor %s\n", s->tilt_deg,
                    omni::devices::MotorStatusName(s->status));
      } else {
        std::printf("tilt: unknown, motor %s\n", omni::devices::MotorStatusName(s->status));
      }
      return 0;
    });
  }
  std::fprintf(stderr, "unknown command: %s\n", cmd.c_str());
  return Usage(2);
}
