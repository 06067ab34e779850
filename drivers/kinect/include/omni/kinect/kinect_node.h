// Bus side of the Kinect driver: each depth frame becomes omni.depth_image_t on DEPTH (encoded
// with the depth codec: RAW, ZLIB or DELTA_ZLIB), each colour frame omni.color_image_t (RGB8)
// on RGB, and HEARTBEAT carries the state (STARTING / ERROR until the first depth frame, OK
// while streaming, DEGRADED when streaming with a warning such as colour off) and the counters
// (depth/colour frames, messages, dropped and bad frames, encode errors, reconnects, connect
// failures, device errors).
#pragma once

#include <atomic>
#include <cstdint>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/color_image_t.hpp"
#include "omni/depth_image_t.hpp"
#include "omni/kinect/kinect_driver.h"

namespace omni::kinect {

// Messages for one frame (pure functions, for tests). `utime` is the host receive time.
Status MakeDepthMessage(const DepthFrame& f, Utime utime, int64_t seq, const std::string& frame,
                        DepthEncoding encoding, const DepthEncodeOptions& codec,
                        omni::depth_image_t* msg);
omni::color_image_t MakeColorMessage(const ColorFrame& f, Utime utime, int64_t seq,
                                     const std::string& frame);

class KinectNode {
 public:
  // `clock` (the wall clock in the field) stamps the messages and the heartbeat; the driver
  // times its timeouts on its own monotonic clock.
  KinectNode(bus::Bus* bus, KinectDriver* driver, KinectNodeOptions options, const Clock* clock);
  KinectNode(const KinectNode&) = delete;  // the heartbeat's counters point into this object
  KinectNode& operator=(const KinectNode&) = delete;
  void RunOnce(int timeout_ms);
  // Until *stop (or `max_s` seconds when > 0).
  void Run(const std::atomic<bool>* stop, double max_s = -1);
  int64_t depth_published() const { return depth_seq_; }
  int64_t color_published() const { return color_seq_; }
  int64_t encode_errors() const { return encode_errors_; }

 private:
  bus::Bus* bus_;
  KinectDriver* driver_;
  KinectNodeOptions options_;
  const Clock* clock_;
  DepthEncoding encoding_ = DepthEncoding::kDeltaZlib;
  DepthEncodeOptions codec_;
  bus::Heartbeat heartbeat_;
  int64_t depth_seq_ = 0;
  int64_t color_seq_ = 0;
  int64_t encode_errors_ = 0;
};

}  // namespace omni::kinect
