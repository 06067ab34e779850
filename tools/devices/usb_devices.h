// omni-devices without libusb: which USB ids are ours (lidar / IMU bridges, Kinect v1 parts),
// the tty node a USB-serial bridge got (from sysfs), and the Kinect v1 motor protocol (vendor
// control requests on 045e:02b0) behind a transfer function, so all of it is tested without a
// device.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "omni/common/result.h"

namespace omni::devices {

enum class DeviceKind {
  kUnknown,
  kSerialBridge,  // RPLidar or serial IMU: the same bridge chips serve both
  kKinectCamera,
  kKinectMotor,
  kKinectAudio,
};

struct UsbId {
  uint16_t vendor = 0;
  uint16_t product = 0;
};

struct Classification {
  DeviceKind kind = DeviceKind::kUnknown;
  std::string what;  // "USB-serial bridge (RPLidar or IMU): Silicon Labs CP210x", ...
};

Classification Classify(UsbId id);
const char* DeviceKindName(DeviceKind kind);  // "serial-bridge", "kinect-camera", ...

// The tty nodes (e.g. "/dev/ttyUSB0") of the USB device whose sysfs name is `port_name`
// ("1-1.2"): looks in <sysfs_usb_devices>/<port_name>:*/ for ttyUSB*/ttyACM* entries (directly
// or under tty/). Empty when none (not a serial device, or sysfs absent).
std::vector<std::string> TtyNodes(const std::string& sysfs_usb_devices,
                                  const std::string& port_name);

// sysfs name of a device from its bus and port chain: bus 1, ports {1, 2} -> "1-1.2".
std::string SysfsPortName(int bus, const std::vector<int>& ports);

// ---------------------------------------------------------------------------------------------
// Kinect v1 motor/LED/accelerometer (USB 045e:02b0). Vendor requests on the default control
// pipe: set tilt (0x31, wValue = 2 * degrees, signed, -31..31 deg), set LED (0x06, wValue =
// LED mode 0..6), read state (0x32, 10 bytes IN: three big-endian signed accelerometer counts
// at bytes 2..7, 819 counts per g; tilt angle in half degrees as int8 at byte 8, -128 while
// unknown; motor status at byte 9: 0 stopped, 1 at a limit, 4 moving).
constexpr uint16_t kMicrosoftVendor = 0x045e;
constexpr uint16_t kKinectMotorProduct = 0x02b0;
constexpr double kKinectMaxTiltDeg = 31.0;
constexpr double kKinectCountsPerG = 819.0;

struct ControlRequest {
  uint8_t request_type = 0;  // bmRequestType
  uint8_t request = 0;       // bRequest
  uint16_t value = 0;        // wValue
  uint16_t index = 0;        // wIndex
  uint16_t length = 0;       // wLength (IN data expected, or OUT data sent)
};

Result<ControlRequest> TiltRequest(double degrees);
Result<ControlRequest> LedRequest(int mode);
ControlRequest StateRequest();

struct MotorState {
  int16_t accel_counts[3] = {0, 0, 0};
  double accel_m_s2[3] = {0, 0, 0};
  bool tilt_known = false;
  double tilt_deg = 0;
  int status = 0;  // 0 stopped, 1 at limit, 4 moving
};

Result<MotorState> ParseMotorState(const uint8_t* data, size_t size);
const char* MotorStatusName(int status);
const char* LedModeName(int mode);

// Performs one control transfer; returns the bytes transferred or a negative error.
using TransferFn = std::function<int(const ControlRequest& req, uint8_t* data)>;

Status SetTilt(const TransferFn& transfer, double degrees);
Status SetLed(const TransferFn& transfer, int mode);
Result<MotorState> ReadMotorState(const TransferFn& transfer);

}  // namespace omni::devices
