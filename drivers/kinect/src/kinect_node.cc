#include "omni/kinect/kinect_node.h"

#include <chrono>
#include <thread>
#include <utility>

#include "omni/common/log.h"
#include "omni/heartbeat_t.hpp"
#include "omni/kinect/depth_message.h"

namespace omni::kinect {

Status MakeDepthMessage(const DepthFrame& f, Utime utime, int64_t seq, const std::string& frame,
                        DepthEncoding encoding, const DepthEncodeOptions& codec,
                        omni::depth_image_t* msg) {
  if (f.width <= 0 || f.height <= 0 ||
      f.depth_mm.size() != static_cast<size_t>(f.width) * static_cast<size_t>(f.height)) {
    return MakeError(ErrorCode::kInvalidArgument,
                     "depth frame " + std::to_string(seq) + ": " + std::to_string(f.width) + "x" +
                         std::to_string(f.height) + " does not match its " +
                         std::to_string(f.depth_mm.size()) + " pixels");
  }
  msg->utime = utime;
  msg->seq = seq;
  msg->frame = frame;
  msg->fx = f.intrinsics.fx;
  msg->fy = f.intrinsics.fy;
  msg->cx = f.intrinsics.cx;
  msg->cy = f.intrinsics.cy;
  msg->depth_scale = 1000.0;  // millimetres
  msg->registered_to_color = f.registered_to_color;
  return FillDepthMessage(f.depth_mm.data(), f.width, f.height, encoding, codec, msg);
}

omni::color_image_t MakeColorMessage(const ColorFrame& f, Utime utime, int64_t seq,
                                     const std::string& frame) {
  omni::color_image_t m;
  m.utime = utime;
  m.seq = seq;
  m.frame = frame;
  m.width = f.width;
  m.height = f.height;
  m.fx = f.intrinsics.fx;
  m.fy = f.intrinsics.fy;
  m.cx = f.intrinsics.cx;
  m.cy = f.intrinsics.cy;
  m.encoding = omni::color_image_t::ENCODING_RGB8;
  m.data = f.rgb;
  m.size = static_cast<int32_t>(m.data.size());
  return m;
}

KinectNode::KinectNode(bus::Bus* bus, KinectDriver* driver, KinectNodeOptions options,
                       const Clock* clock)
    : bus_(bus),
      driver_(driver),
      options_(std::move(options)),
      clock_(clock),
      heartbeat_(bus, "kinect_driver", clock) {
  if (!ParseDepthEncoding(options_.encoding, &encoding_)) encoding_ = DepthEncoding::kDeltaZlib;
  codec_.zlib_level = options_.zlib_level;
  const KinectDriver* d = driver_;
  heartbeat_.AddCounter("depth_messages", [this] { return depth_seq_; });
  heartbeat_.AddCounter("color_messages", [this] { return color_seq_; });
  heartbeat_.AddCounter("frames", [d] { return d->counters().depth_frames; });
  heartbeat_.AddCounter("color_frames", [d] { return d->counters().color_frames; });
  heartbeat_.AddCounter("dropped_frames", [d] { return d->counters().dropped_frames; });
  heartbeat_.AddCounter("bad_frames", [d] { return d->counters().bad_frames; });
  heartbeat_.AddCounter("encode_errors", [this] { return encode_errors_; });
  heartbeat_.AddCounter("reconnects", [d] { return d->counters().reconnects; });
  heartbeat_.AddCounter("connect_failures", [d] { return d->counters().connect_failures; });
  heartbeat_.AddCounter("device_errors", [d] { return d->counters().device_errors; });
  heartbeat_.AddCounter("color_stalls", [d] { return d->counters().color_stalls; });
}

void KinectNode::RunOnce(int timeout_ms) {
  SourceFrames frames;
  driver_->Step(timeout_ms, &frames);
  const Utime now = clock_->NowUtime();
  if (frames.has_depth) {
    omni::depth_image_t msg;
    Status st = MakeDepthMessage(frames.depth, now, depth_seq_, options_.depth_frame, encoding_,
                                 codec_, &msg);
    if (st.ok()) {
      bus_->Publish(options_.depth_channel, msg);
      ++depth_seq_;
    } else {
      ++encode_errors_;
      LOG_WARN << "depth frame not published: " << st.error().ToString();
    }
  }
  if (frames.has_color && driver_->options().color) {
    bus_->Publish(options_.color_channel,
                  MakeColorMessage(frames.color, now, color_seq_, options_.color_frame));
    ++color_seq_;
  }
  switch (driver_->state()) {
    case KinectState::kStreaming: {
      // A warning (colour off although configured) or colour that stopped is a degraded stream,
      // not a healthy one.
      const std::string colour = driver_->ColorProblem();
      heartbeat_.SetState(
          driver_->warning().empty() && colour.empty() ? omni::heartbeat_t::STATE_OK
                                                       : omni::heartbeat_t::STATE_DEGRADED,
          colour.empty() ? driver_->status_text() : driver_->status_text() + "; " + colour);
      break;
    }
    case KinectState::kOpening:
      // Starting while the first open since start-up waits for its first frame; once an
      // opening has failed or the device has streamed before, this is a device not streaming.
      heartbeat_.SetState(driver_->ever_streamed() || driver_->counters().connect_failures > 0
                              ? omni::heartbeat_t::STATE_ERROR
                              : omni::heartbeat_t::STATE_STARTING,
                          driver_->status_text());
      break;
    case KinectState::kDisconnected:
      heartbeat_.SetState(omni::heartbeat_t::STATE_ERROR, "retrying: " + driver_->status_text());
      break;
  }
  heartbeat_.Tick();
}

void KinectNode::Run(const std::atomic<bool>* stop, double max_s) {
  const int64_t start = MonotonicMicros();
  while (!stop->load()) {
    if (max_s > 0 && MonotonicMicros() - start > SecondsToUtime(max_s)) break;
    RunOnce(100);
    if (driver_->state() == KinectState::kDisconnected) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));  // between reopen attempts
    }
  }
  heartbeat_.SetState(omni::heartbeat_t::STATE_STOPPING, "stopping");
  heartbeat_.Tick(true);
  driver_->Shutdown();
}

}  // namespace omni::kinect
