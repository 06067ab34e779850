#include "omni/kinect/kinect_driver.h"

#include <cmath>
#include <sstream>
#include <utility>

#include "omni/common/config.h"
#include "omni/common/log.h"

namespace omni::kinect {
namespace {

std::string Seconds(double s) {
  std::ostringstream o;
  o << s << " s";
  return o.str();
}

}  // namespace

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
                           MonotonicNow now_us)
    : options_(std::move(options)),
      source_(std::move(source)),
      now_us_(std::move(now_us)),
      gaps_(options_.fps) {}

KinectDriver::~KinectDriver() { Shutdown(); }

Status KinectDriver::Connect() {
  Status st = source_->Open();
  if (!st.ok()) {
    ++counters_.connect_failures;
    state_ = KinectState::kDisconnected;
    status_ = st.error().message;
    next_attempt_us_ = now_us_() + SecondsToUtime(options_.reconnect_interval_s);
    return st;
  }
  warning_ = source_->Warning();
  if (!warning_.empty()) {
    LOG_WARN << source_->Describe() << ": " << warning_;
  }
  // Not streaming yet: a device can open and then send nothing (see KinectState).
  state_ = KinectState::kOpening;
  status_ = "opened " + source_->Describe() + ", no depth frame yet";
  opened_us_ = now_us_();
  last_bad_frame_.clear();
  gaps_.Reset();
  return Status::Ok();
}

void KinectDriver::Retry(const std::string& why) {
  source_->Close();
  state_ = KinectState::kDisconnected;
  status_ = why;
  next_attempt_us_ = now_us_() + SecondsToUtime(options_.reconnect_interval_s);
  LOG_WARN << why << "; retrying every " << Seconds(options_.reconnect_interval_s);
}

void KinectDriver::Lose(const std::string& why) {
  ++counters_.device_errors;
  Retry(why);
}

void KinectDriver::FailOpening(const std::string& why) {
  ++counters_.connect_failures;
  Retry(why);
}

void KinectDriver::Step(int timeout_ms, SourceFrames* out) {
  out->has_depth = false;
  out->has_color = false;
  if (state_ == KinectState::kDisconnected) {
    if (now_us_() < next_attempt_us_) return;
    Status st = Connect();
    if (!st.ok()) return;
    LOG_INFO << status_;
  }
  Status st = source_->Read(timeout_ms, out);
  if (!st.ok()) {
    out->has_depth = out->has_color = false;
    if (st.error().code != ErrorCode::kParse) {
      if (state_ == KinectState::kOpening) {
        FailOpening("lost before its first depth frame: " + st.error().message);
      } else {
        Lose("device lost: " + st.error().message);
      }
      return;
    }
    // One unusable frame (short, wrong pixel format) says nothing about the device: skip it.
    // A device sending only such frames still runs into the data timeout below.
    ++counters_.bad_frames;
    last_bad_frame_ = st.error().message;
    if ((counters_.bad_frames & (counters_.bad_frames - 1)) == 0) {  // 1, 2, 4, 8, ...
      LOG_WARN << "frame skipped (" << counters_.bad_frames << " so far): " << last_bad_frame_;
    }
  }
  const int64_t now = now_us_();
  const int64_t limit = SecondsToUtime(options_.data_timeout_s);
  const auto silent_for = [this] {
    return Seconds(options_.data_timeout_s) +
           (last_bad_frame_.empty() ? "" : " (last frame skipped: " + last_bad_frame_ + ")");
  };
  if (out->has_color) {
    ++counters_.color_frames;
    color_since_us_ = now;
    if (color_stalled_) {
      LOG_INFO << "colour frames from " << source_->Describe() << " again";
    }
    color_stalled_ = false;
  }
  if (out->has_depth) {
    ++counters_.depth_frames;
    counters_.dropped_frames += gaps_.Add(out->depth.frame_index, out->depth.device_timestamp_us);
    last_data_us_ = now;
    last_bad_frame_.clear();
    if (state_ == KinectState::kOpening) {
      if (ever_streamed_) ++counters_.reconnects;
      ever_streamed_ = true;
      state_ = KinectState::kStreaming;
      color_since_us_ = now;
      color_stalled_ = false;
      status_ = "streaming from " + source_->Describe();
      if (!warning_.empty()) status_ += "; " + warning_;
      LOG_INFO << status_;
    }
  } else if (state_ == KinectState::kOpening && now - opened_us_ > limit) {
    FailOpening("opened " + source_->Describe() + " but no depth frame within " + silent_for());
  } else if (state_ == KinectState::kStreaming && now - last_data_us_ > limit) {
    Lose("no depth frame from " + source_->Describe() + " for " + silent_for());
  }
  if (state_ == KinectState::kStreaming && options_.color && warning_.empty() && !color_stalled_ &&
      now - color_since_us_ > limit) {
    color_stalled_ = true;
    ++counters_.color_stalls;
    LOG_WARN << ColorProblem();
  }
}

std::string KinectDriver::ColorProblem() const {
  if (!color_stalled_ || state_ != KinectState::kStreaming) return "";
  return "no colour frame from " + source_->Describe() + " for over " +
         Seconds(options_.data_timeout_s) +
         " while depth streams: the 3D map goes on without colour";
}

void KinectDriver::Shutdown() {
  if (source_) source_->Close();
  state_ = KinectState::kDisconnected;
}

}  // namespace omni::kinect
