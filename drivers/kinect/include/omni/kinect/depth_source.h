// The camera behind the Kinect driver, as an interface: the driver and its node only see
// frames (16-bit depth in millimetres, optional RGB8 colour, intrinsics, device timestamps),
// so they are tested with a scripted source and run on OpenNI2 (openni2_source.h) in the field.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "omni/common/result.h"

namespace omni::kinect {

// Pinhole intrinsics in pixels (u right, v down).
struct Intrinsics {
  double fx = 0, fy = 0, cx = 0, cy = 0;
};

// fx = width / (2 tan(hfov / 2)), fy likewise from vfov, principal point at the image centre
// ((w - 1) / 2, (h - 1) / 2). A field of view <= 0 or >= pi (unknown) gives fx = fy = 0.
Intrinsics IntrinsicsFromFov(int width, int height, double hfov_rad, double vfov_rad);

struct DepthFrame {
  int width = 0;
  int height = 0;
  std::vector<uint16_t> depth_mm;  // width*height, row-major, 0 = no measurement
  Intrinsics intrinsics;
  int64_t device_timestamp_us = 0;  // the device's own clock (not the epoch)
  int64_t frame_index = -1;         // the device's frame counter, -1 when it has none
  bool registered_to_color = false;
};

struct ColorFrame {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> rgb;  // width*height*3, R G B
  Intrinsics intrinsics;
  int64_t device_timestamp_us = 0;
  int64_t frame_index = -1;
};

// What one Read() produced: a depth frame, a colour frame, both or nothing (timeout).
struct SourceFrames {
  bool has_depth = false;
  bool has_color = false;
  DepthFrame depth;
  ColorFrame color;
};

class DepthSource {
 public:
  virtual ~DepthSource() = default;
  // Opens the device and starts its streams. The error names the device (URI).
  virtual Status Open() = 0;
  // After a successful Open(): what could not be set up as configured although depth works
  // (e.g. colour left off because the device will not give RGB888); empty when nothing.
  virtual std::string Warning() const { return {}; }
  // Waits at most `timeout_ms` for frames. Nothing ready is not an error (out has neither).
  // ErrorCode::kParse means one frame could not be used (short, wrong pixel format): it is
  // skipped and the device stays open. Any other error means the device is gone or broken:
  // the caller closes and reopens it later.
  virtual Status Read(int timeout_ms, SourceFrames* out) = 0;
  virtual void Close() = 0;
  // The device's name for messages ("Dummy", "freenect2://0", "first OpenNI2 device").
  virtual std::string Describe() const = 0;
};

}  // namespace omni::kinect
