#include "omni/imu/driver.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <thread>

#include "omni/common/config.h"
#include "omni/common/log.h"

namespace omni::imu {
namespace {

// The rates a WT901/JY901 can be set to (WitMotion's configuration tool).
constexpr int kWitBauds[] = {2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600};

Rule<int> WitBaud() {
  return [](const int& v) -> std::string {
    if (v == 0) return "";
    for (int b : kWitBauds)
      if (b == v) return "";
    return "must be 0 (auto: 9600 then 115200) or a WitMotion rate (2400 ... 921600)";
  };
}

Rule<std::vector<double>> ThreeVariances() {
  return [](const std::vector<double>& v) -> std::string {
    if (v.size() != 3) return "must be a list of 3 variances (x, y, z)";
    for (double x : v)
      if (!std::isfinite(x) || x < 0) return "variances must be finite and >= 0";
    return "";
  };
}

void GetVariances(ConfigReader* r, const std::string& key, std::array<double, 3>* out) {
  std::vector<double> v(out->begin(), out->end());
  r->Get(key, &v, Optional(), ThreeVariances());
  if (v.size() == 3) std::copy(v.begin(), v.end(), out->begin());
}

std::string Seconds(double s) {
  std::ostringstream o;
  o << s << " s";
  return o.str();
}

}  // namespace

Status LoadImuOptions(const std::string& path, DriverOptions* d, NodeOptions* n) {
  auto reader = ConfigReader::FromFile(path);
  if (!reader.ok()) return reader.error();
  ConfigReader& r = *reader;
  r.Get("port", &d->port, Required(), NonEmpty());
  r.Get("baud", &d->baud, Optional(), WitBaud());
  r.Get("trigger", &d->trigger, Optional(),
        OneOf({"auto", "accel", "gyro", "angle", "mag", "quaternion"}));
  r.Get("rate_hz", &d->rate_hz, Optional(), InRange(0.1, 1000.0));
  r.Get("data_timeout_s", &d->data_timeout_s, Optional(), InRange(0.05, 60.0));
  r.Get("reconnect_interval_s", &d->reconnect_interval_s, Optional(), InRange(0.01, 60.0));
  if (d->data_timeout_s * d->rate_hz < 2.0) {
    // A timeout shorter than two output periods would reconnect a healthy device.
    r.AddError("data_timeout_s", "must be at least two output periods (2 / rate_hz)");
  }
  r.Get("channel", &n->channel, Optional(), NonEmpty());
  r.Get("frame", &n->frame, Optional(), NonEmpty());
  r.Get("bus_url", &n->bus_url, Optional());
  r.Get("mag_tesla_per_lsb", &n->mag_tesla_per_lsb, Optional(), NonNegative<double>());
  ConfigReader cov = r.Section("covariance");
  GetVariances(&cov, "orientation", &n->orientation_var);
  GetVariances(&cov, "angular_velocity", &n->angular_velocity_var);
  GetVariances(&cov, "linear_acceleration", &n->linear_acceleration_var);
  return r.Finish();
}

uint8_t TriggerType(const std::string& name) {
  if (name == "accel") return kTypeAccel;
  if (name == "gyro") return kTypeGyro;
  if (name == "angle") return kTypeAngle;
  if (name == "mag") return kTypeMag;
  if (name == "quaternion") return kTypeQuaternion;
  return 0;
}

// ---------------------------------------------------------------------------------------------
int FrameCycle::IndexOf(uint8_t type) const {
  const auto it = std::find(types_.begin(), types_.end(), type);
  return it == types_.end() ? -1 : static_cast<int>(it - types_.begin());
}

void FrameCycle::Reset() {
  types_.clear();
  learned_ = false;
  prev_ = -1;
}

int FrameCycle::Add(uint8_t type) {
  int idx = IndexOf(type);
  if (idx < 0) {
    // A new type: while learning, part of the first period; later, a type whose frame was lost
    // while learning. Either way it joins the cycle in its ascending place.
    types_.insert(std::upper_bound(types_.begin(), types_.end(), type), type);
    prev_ = IndexOf(type);
    return 0;
  }
  if (!learned_) {
    learned_ = true;  // the first repeat: one whole period has been seen
    prev_ = idx;
    return 0;
  }
  const int n = static_cast<int>(types_.size());
  const int expected = prev_ < 0 ? idx : (prev_ + 1) % n;
  prev_ = idx;
  return (idx - expected + n) % n;
}

Utime SampleStamper::Stamp(Utime read_utime, size_t i, size_t n) {
  // The samples of one read were sent after the previous stamp: never spread them wider than
  // the time since then (rate_hz set lower than the device's real rate).
  if (i == 0) {
    step_ = period_us_;
    if (last_ > 0 && read_utime > last_) {
      step_ = std::min<Utime>(step_, (read_utime - last_) / static_cast<Utime>(n));
    }
  }
  Utime t = read_utime - static_cast<Utime>(n - 1 - i) * step_;
  if (t <= last_) t = last_ + 1;
  last_ = t;
  return t;
}

// ---------------------------------------------------------------------------------------------
ImuDriver::ImuDriver(DriverOptions options, const Clock* clock)
    : options_(std::move(options)), clock_(clock), stamper_(options_.rate_hz) {}

ImuDriver::~ImuDriver() { Shutdown(); }

std::vector<int> ImuDriver::Bauds() const {
  if (options_.baud > 0) return {options_.baud};
  return {9600, 115200};
}

FrameCounters ImuDriver::frame_counters() const {
  FrameCounters c = past_;
  const FrameCounters& now = parser_.counters();
  c.frames += now.frames;
  c.checksum_errors += now.checksum_errors;
  c.resyncs += now.resyncs;
  c.bytes_skipped += now.bytes_skipped;
  return c;
}

Status ImuDriver::Open() {
  port_.reset();
  const auto bauds = Bauds();
  baud_index_ %= bauds.size();
  auto port = serial::SerialPort::Open(options_.port, bauds[baud_index_]);
  if (!port.ok()) {
    ++counters_.connect_failures;
    state_ = DriverState::kDisconnected;
    status_ = "IMU on " + options_.port + ": " + port.error().message;
    next_attempt_us_ = MonotonicMicros() + SecondsToUtime(options_.reconnect_interval_s);
    return MakeError(port.error().code, "IMU: " + port.error().message);
  }
  port_ = std::move(*port);
  // A fresh parser, cycle and assembler per connection: the device may have been reset or
  // replaced by one set up differently.
  past_ = frame_counters();
  parser_ = FrameParser();
  cycle_.Reset();
  if (assembler_) past_incomplete_ += assembler_->incomplete();
  assembler_.reset();
  trigger_ = 0;
  state_ = DriverState::kOpening;
  status_ =
      "waiting for frames on " + options_.port + " at " + std::to_string(port_->baud()) + " baud";
  opened_us_ = MonotonicMicros();
  bytes_since_open_ = 0;
  return Status::Ok();
}

void ImuDriver::FailOpening(const std::string& why) {
  LOG_DEBUG << "IMU on " << options_.port << ": " << why;
  port_.reset();
  ++counters_.connect_failures;
  state_ = DriverState::kDisconnected;
  status_ = why;
  ++baud_index_;  // with baud 0, the next attempt tries the other rate
  next_attempt_us_ = MonotonicMicros() + SecondsToUtime(options_.reconnect_interval_s);
}

void ImuDriver::Lose(const std::string& why) {
  LOG_WARN << "IMU on " << options_.port << ": " << why << "; reconnecting every "
           << options_.reconnect_interval_s << " s";
  port_.reset();
  state_ = DriverState::kDisconnected;
  status_ = why;
  next_attempt_us_ = MonotonicMicros() + SecondsToUtime(options_.reconnect_interval_s);
}

Status ImuDriver::Connect() {
  const size_t n = Bauds().size();
  std::string why;
  int64_t bytes = 0;
  for (size_t k = 0; k < n; ++k) {
    baud_index_ = k;
    Status st = Open();
    if (!st.ok()) return st;
    std::vector<StampedSample> first;
    while (state_ == DriverState::kOpening) Step(50, &first);
    pending_.insert(pending_.end(), first.begin(), first.end());
    if (state_ == DriverState::kStreaming) return Status::Ok();
    why += (k ? "; " : "") + status_;
    bytes += bytes_since_open_;
  }
  status_ =
      "IMU: " + why +
      (bytes > 0 ? "; bytes but no frame: wrong baud rate?" : "; is the IMU powered and wired?");
  return MakeError(ErrorCode::kUnavailable, status_);
}

void ImuDriver::Feed(const uint8_t* data, size_t size, std::vector<StampedSample>* out) {
  frames_.clear();
  parser_.Feed(data, size, &frames_);
  if (frames_.empty()) return;
  last_data_us_ = MonotonicMicros();
  if (state_ == DriverState::kOpening) {
    if (ever_connected_) ++counters_.reconnects;
    ever_connected_ = true;
    state_ = DriverState::kStreaming;
    status_ = "streaming on " + options_.port + " at " + std::to_string(port_->baud()) + " baud";
    LOG_INFO << "IMU " << status_;
  }
  const Utime read_utime = clock_->NowUtime();
  const uint8_t fixed = TriggerType(options_.trigger);
  std::vector<ImuSample> done;
  for (const Frame& f : frames_) {
    counters_.dropped_frames += cycle_.Add(f.type);
    if (!cycle_.learned()) continue;  // one period at most, after each (re)connection
    const uint8_t want = fixed ? fixed : cycle_.last_type();
    if (want != trigger_) {
      // First period learned, or a type beyond the old last one showed up (its frame was lost
      // while learning): start over at the next period with the right closing frame.
      if (assembler_) past_incomplete_ += assembler_->incomplete();
      assembler_ = std::make_unique<SampleAssembler>(want);
      trigger_ = want;
      aligned_ = false;
    }
    if (!aligned_) {
      if (f.type != cycle_.types().front()) continue;
      aligned_ = true;
    }
    ImuSample s;
    if (assembler_->Add(f, &s)) done.push_back(s);
  }
  counters_.incomplete_samples = past_incomplete_ + (assembler_ ? assembler_->incomplete() : 0);
  for (size_t i = 0; i < done.size(); ++i) {
    out->push_back({stamper_.Stamp(read_utime, i, done.size()), done[i]});
    ++counters_.samples;
  }
}

void ImuDriver::Step(int timeout_ms, std::vector<StampedSample>* out) {
  if (!pending_.empty()) {
    out->insert(out->end(), pending_.begin(), pending_.end());
    pending_.clear();
  }
  if (state_ == DriverState::kDisconnected) {
    const int64_t wait_us = next_attempt_us_ - MonotonicMicros();
    if (wait_us > 0) {
      std::this_thread::sleep_for(
          std::chrono::microseconds(std::min<int64_t>(wait_us, int64_t{timeout_ms} * 1000)));
      return;
    }
    Status st = Open();
    if (!st.ok()) {
      LOG_DEBUG << st.message();
    }
    return;
  }
  uint8_t chunk[2048];
  auto n = port_->Read(chunk, sizeof(chunk), timeout_ms);
  if (!n.ok()) {
    if (state_ == DriverState::kOpening) {
      FailOpening(n.error().message);
    } else {
      Lose(n.error().message);
    }
    return;
  }
  if (*n > 0) {
    bytes_since_open_ += static_cast<int64_t>(*n);
    Feed(chunk, *n, out);
  }
  const int64_t now = MonotonicMicros();
  const int64_t limit = SecondsToUtime(options_.data_timeout_s);
  if (state_ == DriverState::kOpening && now - opened_us_ > limit) {
    FailOpening("no WitMotion frame on " + options_.port + " within " +
                Seconds(options_.data_timeout_s) + " at " + std::to_string(port_->baud()) +
                " baud (" + std::to_string(bytes_since_open_) + " bytes received)");
  } else if (state_ == DriverState::kStreaming && now - last_data_us_ > limit) {
    ++counters_.timeouts;
    Lose("no frame for " + Seconds(options_.data_timeout_s));
  }
}

void ImuDriver::Shutdown() {
  port_.reset();
  state_ = DriverState::kDisconnected;
}

}  // namespace omni::imu
