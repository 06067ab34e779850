#include "usb_devices.h"

#include <dirent.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace omni::devices {
namespace {

struct Known {
  uint16_t vendor, product;
  DeviceKind kind;
  const char* name;
};

// USB-serial bridges found on RPLidars (CP2102 adapter board) and on serial IMUs (CH340,
// CP2102, FTDI): the id alone cannot tell the two apart.
constexpr Known kKnown[] = {
    {0x10c4, 0xea60, DeviceKind::kSerialBridge, "Silicon Labs CP210x"},
    {0x1a86, 0x7523, DeviceKind::kSerialBridge, "QinHeng CH340"},
    {0x1a86, 0x7522, DeviceKind::kSerialBridge, "QinHeng CH340K"},
    {0x1a86, 0x55d4, DeviceKind::kSerialBridge, "QinHeng CH9102"},
    {0x0403, 0x6001, DeviceKind::kSerialBridge, "FTDI FT232R"},
    {0x0403, 0x6015, DeviceKind::kSerialBridge, "FTDI FT231X"},
    {0x067b, 0x2303, DeviceKind::kSerialBridge, "Prolific PL2303"},
    {kMicrosoftVendor, 0x02ae, DeviceKind::kKinectCamera, "Kinect v1 camera"},
    {kMicrosoftVendor, kKinectMotorProduct, DeviceKind::kKinectMotor,
     "Kinect v1 motor, LED and accelerometer"},
    {kMicrosoftVendor, 0x02ad, DeviceKind::kKinectAudio, "Kinect v1 audio"},
};

constexpr uint8_t kVendorOut = 0x40;  // host-to-device | vendor | device
constexpr uint8_t kVendorIn = 0xc0;   // device-to-host | vendor | device
constexpr uint8_t kSetLed = 0x06;
constexpr uint8_t kSetTilt = 0x31;
constexpr uint8_t kReadState = 0x32;
constexpr uint16_t kStateBytes = 10;

bool StartsWith(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }

std::vector<std::string> List(const std::string& dir) {
  std::vector<std::string> names;
  DIR* d = opendir(dir.c_str());
  if (d == nullptr) return names;
  while (dirent* e = readdir(d)) {
    const std::string n = e->d_name;
    if (n != "." && n != "..") names.push_back(n);
  }
  closedir(d);
  std::sort(names.begin(), names.end());
  return names;
}

bool IsTty(const std::string& n) { return StartsWith(n, "ttyUSB") || StartsWith(n, "ttyACM"); }

}  // namespace

Classification Classify(UsbId id) {
  for (const Known& k : kKnown) {
    if (k.vendor == id.vendor && k.product == id.product) {
      if (k.kind == DeviceKind::kSerialBridge) {
        return {k.kind, std::string("USB-serial bridge (RPLidar or IMU): ") + k.name};
      }
      return {k.kind, k.name};
    }
  }
  return {};
}

const char* DeviceKindName(DeviceKind kind) {
  switch (kind) {
    case DeviceKind::kSerialBridge:
      return "serial-bridge";
    case DeviceKind::kKinectCamera:
      return "kinect-camera";
    case DeviceKind::kKinectMotor:
      return "kinect-motor";
    case DeviceKind::kKinectAudio:
      return "kinect-audio";
    case DeviceKind::kUnknown:
      break;
  }
  return "unknown";
}

std::string SysfsPortName(int bus, const std::vector<int>& ports) {
  std::string name = std::to_string(bus);
  if (ports.empty()) return "usb" + name;  // a root hub
  for (size_t i = 0; i < ports.size(); ++i) {
    name += (i == 0 ? "-" : ".") + std::to_string(ports[i]);
  }
  return name;
}

std::vector<std::string> TtyNodes(const std::string& sysfs_usb_devices,
                                  const std::string& port_name) {
  std::vector<std::string> nodes;
  const std::string prefix = port_name + ":";
  for (const std::string& intf : List(sysfs_usb_devices)) {
    if (!StartsWith(intf, prefix.c_str())) continue;
    const std::string dir = sysfs_usb_devices + "/" + intf;
    for (const std::string& n : List(dir)) {
      if (IsTty(n)) nodes.push_back("/dev/" + n);  // usb-serial drivers (cp210x, ch341, ftdi)
    }
    for (const std::string& n : List(dir + "/tty")) {
      if (IsTty(n)) nodes.push_back("/dev/" + n);  // cdc_acm
    }
  }
  return nodes;
}

Result<ControlRequest> TiltRequest(double degrees) {
  if (!std::isfinite(degrees) || std::fabs(degrees) > kKinectMaxTiltDeg) {
    return MakeError(ErrorCode::kOutOfRange,
                     "tilt must be between -31 and 31 degrees, got " + std::to_string(degrees));
  }
  ControlRequest r;
  r.request_type = kVendorOut;
  r.request = kSetTilt;
  const auto half_degrees = static_cast<int16_t>(std::lround(degrees * 2.0));
  r.value = static_cast<uint16_t>(half_degrees);  // two's complement in wValue
  return r;
}

Result<ControlRequest> LedRequest(int mode) {
  if (mode < 0 || mode > 6) {
    return MakeError(ErrorCode::kOutOfRange,
                     "LED mode must be 0..6 (0 off, 1 green, 2 red, 3 yellow, 4 and 5 blink green, "
                     "6 blink red/yellow), got " +
                         std::to_string(mode));
  }
  ControlRequest r;
  r.request_type = kVendorOut;
  r.request = kSetLed;
  r.value = static_cast<uint16_t>(mode);
  return r;
}

ControlRequest StateRequest() {
  ControlRequest r;
  r.request_type = kVendorIn;
  r.request = kReadState;
  r.length = kStateBytes;
  return r;
}

Result<MotorState> ParseMotorState(const uint8_t* data, size_t size) {
  if (size < kStateBytes) {
    return MakeError(ErrorCode::kParse, "Kinect motor state: " + std::to_string(size) +
                                            " bytes, expected " + std::to_string(kStateBytes));
  }
  MotorState s;
  for (int i = 0; i < 3; ++i) {
    const size_t at = 2 + 2 * static_cast<size_t>(i);
    s.accel_counts[i] = static_cast<int16_t>(static_cast<uint16_t>(data[at] << 8) | data[at + 1]);
    s.accel_m_s2[i] = s.accel_counts[i] / kKinectCountsPerG * 9.80665;
  }
  const auto tilt = static_cast<int8_t>(data[8]);
  s.tilt_known = tilt != -128;
  s.tilt_deg = s.tilt_known ? tilt / 2.0 : 0.0;
  s.status = data[9];
  return s;
}

const char* MotorStatusName(int status) {
  switch (status) {
    case 0:
      return "stopped";
    case 1:
      return "at limit";
    case 4:
      return "moving";
    default:
      return "unknown";
  }
}

const char* LedModeName(int mode) {
  static const char* const kNames[] = {
      "off", "green", "red", "yellow", "blink green", "blink green", "blink red/yellow"};
  return (mode >= 0 && mode <= 6) ? kNames[mode] : "unknown";
}

namespace {
Status Send(const TransferFn& transfer, const ControlRequest& r, const char* what) {
  const int n = transfer(r, nullptr);
  if (n < 0) {
    return MakeError(ErrorCode::kIo, std::string("Kinect motor (045e:02b0): ") + what +
                                         " failed (libusb error " + std::to_string(n) + ")");
  }
  return Status::Ok();
}
}  // namespace

Status SetTilt(const TransferFn& transfer, double degrees) {
  auto r = TiltRequest(degrees);
  if (!r.ok()) return r.error();
  return Send(transfer, *r, "set tilt");
}

Status SetLed(const TransferFn& transfer, int mode) {
  auto r = LedRequest(mode);
  if (!r.ok()) return r.error();
  return Send(transfer, *r, "set LED");
}

Result<MotorState> ReadMotorState(const TransferFn& transfer) {
  uint8_t buf[kStateBytes] = {};
  const int n = transfer(StateRequest(), buf);
  if (n < 0) {
    return MakeError(ErrorCode::kIo, "Kinect motor (045e:02b0): read state failed (libusb error " +
                                         std::to_string(n) + ")");
  }
  return ParseMotorState(buf, static_cast<size_t>(n));
}

}  // namespace omni::devices
