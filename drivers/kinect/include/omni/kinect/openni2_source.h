// DepthSource over OpenNI2 (libOpenNI2, Debian package libopenni2-dev). OpenNI.h stays in the
// .cc file. OpenNI2 loads its device drivers from the `Repository` of the [Drivers] section of
// OpenNI.ini (Debian: /etc/openni2/OpenNI.ini, default OpenNI2/Drivers next to libOpenNI2.so,
// i.e. /usr/lib/x86_64-linux-gnu/OpenNI2/Drivers). OpenNI2's built-in test device has the URI
// "Dummy": it is not listed by enumerateDevices but opens by name and streams 320x240 depth.
#pragma once

#include <memory>
#include <string>

#include "omni/kinect/depth_source.h"

namespace omni::kinect {

struct OpenNI2Options {
  std::string uri;  // "" = the first device OpenNI2 finds; "Dummy" = OpenNI2's test device
  bool color = true;
  bool register_depth_to_color = true;  // when the device supports it
  // Used when the stream reports no field of view (0); radians. Kinect v1: 58.5 x 45.6 deg.
  double fallback_hfov_rad = 1.0210;
  double fallback_vfov_rad = 0.7959;
};

class OpenNI2DepthSource final : public DepthSource {
 public:
  explicit OpenNI2DepthSource(OpenNI2Options options);
  ~OpenNI2DepthSource() override;
  Status Open() override;
  std::string Warning() const override;
  Status Read(int timeout_ms, SourceFrames* out) override;
  void Close() override;
  std::string Describe() const override;
  bool color_open() const;
  bool registered() const;

 private:
  struct Impl;
  OpenNI2Options options_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace omni::kinect
