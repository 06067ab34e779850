#include "omni/kinect/kinect_driver.h"

#include <cmath>
#include <utility>

#include "omni/common/config.h"
#include "omni/common/log.h"

namespace omni::kinect {

bool ParseDepthEncoding(const std::string& name, DepthEncoding* out) {
  if (name == "RAW") {
    *out = DepthEncoding::kRaw;
  } else if (name == "ZLIB") {
    *out = DepthEncoding::kZlib;
  } else if (name == "DELTA_ZLIB") {
    *out = DepthEncoding::kDeltaZlib;
  } else {
    return false;
  }
  return true;
}

Status LoadKinectOptions(const std::string& path, KinectDriverOptions* d, KinectNodeOptions* n) {
  auto reader = ConfigReader::FromFile(path);
  if (!reader.ok()) return reader.error();
  return LoadKinectOptions(*reader, d, n);
}

Status LoadKinectOptions(ConfigReader& r, KinectDriverOptions* d, KinectNodeOptions* n) {
  r.Get("uri", &d->uri, Optional());
  r.Get("color", &d->color, Optional());
  r.Get("register_depth_to_color", &d->register_depth_to_color, Optional());
  r.Get("fps", &d->fps, Optional(), InRange(1.0, 120.0));
  r.Get("data_timeout_s", &d->data_timeout_s, Optional(), InRange(0.1, 60.0));
  r.Get("reconnect_interval_s", &d->reconnect_interval_s, Optional(), InRange(0.01, 60.0));
  r.Get("fallback_hfov_deg", &d->fallback_hfov_deg, Optional(), InRange(1.0, 179.0));
  r.Get("fallback_vfov_deg", &d->fallback_vfov_deg, Optional(), InRange(1.0, 179.0));
  r.Get("depth_channel", &n->depth_channel, Optional(), NonEmpty());
  r.Get("color_channel", &n->color_channel, Optional(), NonEmpty());
  r.Get("depth_frame", &n->depth_frame, Optional(), NonEmpty());
  r.Get("color_frame", &n->color_frame, Optional(), NonEmpty());
  r.Get("encoding", &n->encoding, Optional(), OneOf({"RAW", "ZLIB", "DELTA_ZLIB"}));
  r.Get("zlib_level", &n->zlib_level, Optional(), InRange(0, 9));
  r.Get("bus_url", &n->bus_url, Optional());
  return r.Finish();
}

int64_t GapCounter::Add(int64_t frame_index, int64_t timestamp_us) {
  int64_t missed = 0;
  if (have_) {
    if (frame_index >= 0 && last_index_ >= 0) {
      if (frame_index > last_index_ + 1) missed = frame_index - last_index_ - 1;
    } else if (period_us_ > 0 && timestamp_us > last_ts_) {
      const double gap = static_cast<double>(timestamp_us - last_ts_);
      if (gap > 1.5 * period_us_) missed = std::llround(gap / period_us_) - 1;
    }
  }
  have_ = true;
  last_index_ = frame_index;
  last_ts_ = timestamp_us;
  return missed;
}

KinectDriver::KinectDriver(KinectDriverOptions options, std::unique_ptr<DepthSource> source,
                           const Clock* clock)
    : options_(std::move(options)),
      source_(std::move(source)),
      clock_(clock),
      gaps_(options_.fps) {}

KinectDriver::~KinectDriver() { Shutdown(); }

Status KinectDriver::Connect() {
  Status st = source_->Open();
  if (!st.ok()) {
    ++counters_.connect_failures;
    status_ = st.error().message;
    next_attempt_ = clock_->NowUtime() + SecondsToUtime(options_.reconnect_interval_s);
    return st;
  }
  if (ever_connected_) ++counters_.reconnects;
  ever_connected_ = true;
  state_ = KinectState::kStreaming;
  status_ = "streaming from " + source_->Describe();
  last_data_ = clock_->NowUtime();
  gaps_.Reset();
  return Status::Ok();
}

void KinectDriver::Lose(const std::string& why) {
  ++counters_.device_errors;
  source_->Close();
  state_ = KinectState::kDisconnected;
  status_ = why;
  next_attempt_ = clock_->NowUtime() + SecondsToUtime(options_.reconnect_interval_s);
  LOG_WARN << why << "; retrying every " << options_.reconnect_interval_s << " s";
}

void KinectDriver::Step(int timeout_ms, SourceFrames* out) {
  out->has_depth = false;
  out->has_color = false;
  if (state_ == KinectState::kDisconnected) {
    const Utime now = clock_->NowUtime();
    // A wait longer than the whole interval means the clock was set back: wait one from now.
    const Utime interval = SecondsToUtime(options_.reconnect_interval_s);
    if (next_attempt_ - now > interval) next_attempt_ = now + interval;
    if (now < next_attempt_) return;
    Status st = Connect();
    if (!st.ok()) return;
    LOG_INFO << "reconnected: " << status_;
  }
  Status st = source_->Read(timeout_ms, out);
  if (!st.ok()) {
    out->has_depth = out->has_color = false;
    Lose("device lost: " + st.error().message);
    return;
  }
  const Utime now = clock_->NowUtime();
  if (out->has_color) ++counters_.color_frames;
  if (out->has_depth) {
    ++counters_.depth_frames;
    counters_.dropped_frames += gaps_.Add(out->depth.frame_index, out->depth.device_timestamp_us);
    last_data_ = now;
  } else if (now < last_data_) {
    last_data_ = now;  // the clock set back: the silence is counted from now
  } else if (now - last_data_ > SecondsToUtime(options_.data_timeout_s)) {
    Lose("no depth frame from " + source_->Describe() + " for " +
         std::to_string(options_.data_timeout_s) + " s");
  }
}

void KinectDriver::Shutdown() {
  if (source_) source_->Close();
  state_ = KinectState::kDisconnected;
}

}  // namespace omni::kinect
