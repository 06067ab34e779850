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

constexpr const char* kOutputNames = "time, accel, gyro, angle, mag, quaternion";

std::string Seconds(double s) {
  std::ostringstream o;
  o << s << " s";
  return o.str();
}

}  // namespace

Status LoadImuOptions(const std::string& path, DriverOptions* d, NodeOptions* n) {
  auto reader = ConfigReader::FromFile(path);
  if (!reader.ok()) return reader.error();
  return LoadImuOptions(*reader, d, n);
}

Status LoadImuOptions(ConfigReader& r, DriverOptions* d, NodeOptions* n) {
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
  ConfigReader cfg = r.Section("configure");
  ConfigureOptions& c = d->configure;
  cfg.Get("enabled", &c.enabled, Optional());
  cfg.Get("baud", &c.baud, Optional(), Rule<int>([](const int& v) -> std::string {
            return v == 0 || BaudCode(v) ? "" : "must be 0 (leave it) or 4800 ... 921600";
          }));
  std::vector<std::string> outputs;
  cfg.Get("outputs", &outputs, Optional(),
          Rule<std::vector<std::string>>([](const std::vector<std::string>& v) -> std::string {
            for (const std::string& o : v)
              if (!OutputType(o)) return "unknown output '" + o + "' (" + kOutputNames + ")";
            return "";
          }));
  c.outputs.clear();
  for (const std::string& o : outputs) c.outputs.push_back(OutputType(o));
  std::sort(c.outputs.begin(), c.outputs.end());
  c.outputs.erase(std::unique(c.outputs.begin(), c.outputs.end()), c.outputs.end());
  if (!c.outputs.empty() && !(std::count(c.outputs.begin(), c.outputs.end(), kTypeAccel) &&
                              std::count(c.outputs.begin(), c.outputs.end(), kTypeGyro))) {
    cfg.AddError("outputs", "must include accel and gyro (each sample needs both)");
  }
  cfg.Get("save", &c.save, Optional());
  cfg.Get("command_gap_ms", &c.command_gap_ms, Optional(), InRange(10, 1000));
  if (!c.outputs.empty() && d->trigger != "auto" &&
      !std::count(c.outputs.begin(), c.outputs.end(), TriggerType(d->trigger))) {
    r.AddError("trigger",
               "'" + d->trigger + "' is not among configure.outputs: no sample would ever close");
  }
  cfg.Get("max_attempts", &c.max_attempts, Optional(), InRange(1, 100));
  if (c.enabled) {
    const std::string why = RateBeyondLine(*d);
    if (!why.empty()) r.AddError("rate_hz", why);
  }
  if (c.enabled && !RateCode(d->rate_hz)) {
    r.AddError("rate_hz",
               "must be a WT901 output rate (0.2, 0.5, 1, 2, 5, 10, 20, 50, 100 or 200) when "
               "configure.enabled is true (it is written into the device)");
  }
  ConfigReader cov = r.Section("covariance");
  GetVariances(&cov, "orientation", &n->orientation_var);
  GetVariances(&cov, "angular_velocity", &n->angular_velocity_var);
  GetVariances(&cov, "linear_acceleration", &n->linear_acceleration_var);
  return r.Finish();
}

std::string RateBeyondLine(const DriverOptions& d) {
  const ConfigureOptions& c = d.configure;
  const int line_baud = c.baud > 0 ? c.baud : d.baud;
  if (line_baud <= 0) return "";
  // 10 bits per byte on the line, 11 bytes per frame; without outputs the device sends at
  // least acceleration, rate and angles.
  const size_t frames = c.outputs.empty() ? 3 : c.outputs.size();
  const double max_hz = line_baud / 10.0 / (11.0 * static_cast<double>(frames));
  if (d.rate_hz <= max_hz) return "";
  std::ostringstream why;
  why << "is more than " << line_baud << " baud carries with " << frames << " frames per period ("
      << static_cast<int>(max_hz) << " Hz): set configure.baud higher or send fewer frames";
  return why.str();
}

uint8_t OutputType(const std::string& name) {
  if (name == "time") return kTypeTime;
  return TriggerType(name);
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
  period_ = 0;
  candidates_.clear();
}

int FrameCycle::Add(uint8_t type) {
  int idx = IndexOf(type);
  if (idx < 0 && !learned_) {
    // A new type while learning: part of the first period, in its ascending place.
    types_.insert(std::upper_bound(types_.begin(), types_.end(), type), type);
    prev_ = IndexOf(type);
    return 0;
  }
  if (idx < 0) {
    // A type the learned cycle lacks: its frame was lost while learning, or a stray frame that
    // passed the parser. Only the first comes back every period; it joins when seen in two
    // consecutive ones. Until then it neither counts as a drop nor moves the position.
    const auto it = candidates_.find(type);
    if (it == candidates_.end() || it->second < period_ - 1) {
      candidates_[type] = period_;
      return 0;
    }
    if (it->second == period_) return 0;  // twice in one period: not the device's cycle
    candidates_.erase(it);
    types_.insert(std::upper_bound(types_.begin(), types_.end(), type), type);
    prev_ = IndexOf(type);
    return 0;
  }
  if (!learned_) {
    learned_ = true;  // the first repeat: one whole period has been seen
    prev_ = idx;
    return 0;
  }
  if (prev_ >= 0 && idx <= prev_) {
    ++period_;  // back to a lower type: a new period
    // Candidates not seen in the period that just ended are forgotten.
    for (auto it = candidates_.begin(); it != candidates_.end();) {
      it = it->second < period_ - 1 ? candidates_.erase(it) : std::next(it);
    }
  }
  const int n = static_cast<int>(types_.size());
  const int expected = prev_ < 0 ? idx : (prev_ + 1) % n;
  prev_ = idx;
  return (idx - expected + n) % n;
}

bool SampleBuilder::Learn(const Frame& f) {
  dropped_ += cycle_.Add(f.type);
  return cycle_.learned();
}

bool SampleBuilder::Assemble(const Frame& f, ImuSample* out) {
  const uint8_t want = fixed_ ? fixed_ : cycle_.last_type();
  if (want != trigger_) {
    // First period learned, or a type beyond the old last one joined the cycle (its frame was
    // lost while learning): start over at the next period with the right closing frame.
    past_incomplete_ += assembler_.incomplete();
    assembler_ = SampleAssembler(want);
    trigger_ = want;
    aligned_ = false;
  }
  if (!aligned_) {
    if (f.type != cycle_.types().front()) return false;
    aligned_ = true;
  }
  return assembler_.Add(f, out);
}

void SampleBuilder::Reset() {
  cycle_.Reset();
  past_incomplete_ += assembler_.incomplete();
  assembler_ = SampleAssembler();
  trigger_ = 0;
  aligned_ = false;
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
  if (t <= last_) {
    if (last_ - t > kClockStepBackUs) {
      ++steps_back_;  // the clock was set back: follow it (see the class comment)
    } else {
      t = last_ + 1;  // jitter or a small step: keep the stamps increasing
    }
  }
  last_ = t;
  return t;
}

// ---------------------------------------------------------------------------------------------
ImuDriver::ImuDriver(DriverOptions options, const Clock* clock)
    : options_(std::move(options)),
      clock_(clock),
      builder_(TriggerType(options_.trigger)),
      stamper_(options_.rate_hz),
      config_pending_(options_.configure.enabled) {}

ImuDriver::~ImuDriver() { Shutdown(); }

std::vector<int> ImuDriver::Bauds() const {
  std::vector<int> b =
      options_.baud > 0 ? std::vector<int>{options_.baud} : std::vector<int>{9600, 115200};
  const int target = options_.configure.enabled ? options_.configure.baud : 0;
  if (target > 0) {
    // Try the rate the device is being set to first: after a configuration it is there. And
    // the factory rate too: a device that lost unsaved settings in a power cycle is there.
    b.erase(std::remove(b.begin(), b.end(), target), b.end());
    b.insert(b.begin(), target);
    if (std::find(b.begin(), b.end(), 9600) == b.end()) b.push_back(9600);
  }
  return b;
}

FrameCounters ImuDriver::frame_counters() const {
  FrameCounters c = past_;
  const FrameCounters& now = parser_.counters();
  c.frames += now.frames;
  c.checksum_errors += now.checksum_errors;
  c.resyncs += now.resyncs;
  c.bytes_skipped += now.bytes_skipped;
  c.unconfirmed += now.unconfirmed;
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
  ResetStream();
  state_ = DriverState::kOpening;
  status_ =
      "waiting for frames on " + options_.port + " at " + std::to_string(port_->baud()) + " baud";
  opened_us_ = MonotonicMicros();
  bytes_since_open_ = 0;
  return Status::Ok();
}

void ImuDriver::ResetStream() {
  past_ = frame_counters();
  // A frame the old parser still held back cannot be confirmed any more: it is dropped.
  parser_ = FrameParser();
  builder_.Reset();
  held_group_ = 0;
}

void ImuDriver::Relearn(int64_t now_us) {
  std::ostringstream why;
  why << "frames but no complete sample for " << static_cast<double>(now_us - last_sample_us_) / 1e6
      << " s (cycle";
  for (uint8_t t : builder_.cycle().types()) why << " 0x" << std::hex << int{t} << std::dec;
  why << ", closing frame 0x" << std::hex << int{builder_.trigger()} << std::dec
      << "); learning the frame cycle again";
  relearn_reason_ = why.str();
  LOG_WARN << "IMU on " << options_.port << ": " << relearn_reason_;
  builder_.Reset();
  held_group_ = 0;
  ++counters_.cycle_relearns;
  degraded_ = true;
  last_sample_us_ = now_us;
  // Learning and one whole period take up to about three periods, and a period is shorter than
  // data_timeout_s while frames keep coming: doubling up to 8 x data_timeout_s always leaves a
  // re-learn the time it needs, however the two compare.
  no_sample_limit_us_ =
      std::min(2 * no_sample_limit_us_, 8 * SecondsToUtime(options_.data_timeout_s));
}

void ImuDriver::FailOpening(const std::string& why) {
  LOG_DEBUG << "IMU on " << options_.port << ": " << why;
  if (config_verifying_) {
    // The device was written to and sends nothing readable at the new settings.
    config_verifying_ = false;
    ++counters_.config_failures;
    config_pending_ = config_attempts_ < options_.configure.max_attempts;
    LOG_WARN << "IMU on " << options_.port << ": no frames after writing its settings (" << why
             << ")"
             << (config_pending_ ? "; trying the other baud rates and writing them again"
                                 : "; giving up on writing settings");
  }
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
  // A device that comes back may have lost unsaved settings (power cycle) or be another one.
  config_pending_ = options_.configure.enabled;
  config_verifying_ = false;
  save_after_verify_ = false;
  config_attempts_ = 0;
  reopened_by_config_ = false;
  measured_rate_hz_ = 0;  // no stream, no rate
  state_ = DriverState::kDisconnected;
  status_ = why;
  next_attempt_us_ = MonotonicMicros() + SecondsToUtime(options_.reconnect_interval_s);
}

Status ImuDriver::Connect() {
  // Each baud rate once, and again after each configuration that did not take.
  const size_t n =
      Bauds().size() * (options_.configure.enabled ? 1 + options_.configure.max_attempts : 1);
  std::string why;
  int64_t bytes = 0;
  baud_index_ = 0;
  for (size_t k = 0; k < n; ++k) {
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
  const bool was_holding = parser_.held_type() != 0;
  parser_.Feed(data, size, &frames_);
  if (frames_.empty()) {
    // No frame confirmed, but this read may have completed the one now held back (bytes that
    // trickle in at 9600 baud): its sample's time is this read's.
    if (!was_holding && parser_.held_type() != 0) {
      held_read_utime_ = clock_->NowUtime();
      held_group_ = builder_.trigger() != 0 && parser_.held_type() == builder_.trigger() ? 1 : 0;
    }
    return;
  }
  last_data_us_ = MonotonicMicros();
  if (state_ == DriverState::kOpening) {
    if (ever_connected_ && !reopened_by_config_) ++counters_.reconnects;
    reopened_by_config_ = false;
    ever_connected_ = true;
    state_ = DriverState::kStreaming;
    status_ = "streaming on " + options_.port + " at " + std::to_string(port_->baud()) + " baud";
    LOG_INFO << "IMU " << status_;
    rate_window_start_us_ = 0;
    rate_checked_ = false;
    last_sample_us_ = last_data_us_;
    no_sample_limit_us_ = SecondsToUtime(options_.data_timeout_s);
    if (config_pending_) {
      Configure();
      return;
    }
  }
  const Utime read_utime = clock_->NowUtime();
  struct Done {
    ImuSample sample;
    bool held;  // closed by a frame that came with an earlier read
  };
  std::vector<Done> done;
  for (const Frame& f : frames_) {
    const bool learned = builder_.Learn(f);
    counters_.dropped_frames = builder_.dropped_frames();
    if (!learned) continue;  // one period at most, after each (re)connection
    if (config_verifying_ && !VerifyConfiguration()) return;  // written again
    ImuSample s;
    if (builder_.Assemble(f, &s)) done.push_back({s, f.held});
  }
  counters_.incomplete_samples = builder_.incomplete();
  // Stamps: a sample closed by a frame that was held back since the previous read gets that
  // read's time, as one of the group it arrived with; the others are this read's, and the
  // closing frame the parser now holds back counts in this read's group.
  const bool closing_held = builder_.trigger() != 0 && parser_.held_type() == builder_.trigger();
  size_t group = closing_held ? 1 : 0;
  for (const Done& d : done) group += d.held ? 0 : 1;
  // The sample was taken before its period's frames went down the line; the closing frame's
  // arrival is that much later.
  const int64_t line_delay_us = SerialLineDelayUs(builder_.cycle().types().size(), baud());
  size_t i = 0;
  for (const Done& d : done) {
    Utime t;
    if (!d.held) {
      t = stamper_.Stamp(read_utime, i++, group);
    } else if (held_group_ > 0) {
      t = stamper_.Stamp(held_read_utime_, held_group_ - 1, held_group_);
    } else {
      t = stamper_.Stamp(held_read_utime_ > 0 ? held_read_utime_ : read_utime, 0, 1);
    }
    out->push_back({t - line_delay_us, d.sample});
    ++counters_.samples;
  }
  held_read_utime_ = read_utime;  // the time of the frame held now, if any
  held_group_ = closing_held ? group : 0;
  counters_.clock_steps_back = stamper_.steps_back();
  if (!done.empty()) {
    last_sample_us_ = last_data_us_;
    no_sample_limit_us_ = SecondsToUtime(options_.data_timeout_s);
    degraded_ = false;
  }
  MeasureRate(done.size());
}

bool ImuDriver::Write(uint8_t reg, uint16_t value) {
  const auto bytes = EncodeWrite(reg, value);
  const Status st = port_->Write(bytes.data(), bytes.size(), 500);
  if (!st.ok()) {
    if (st.error().code == ErrorCode::kUnavailable) {
      Lose("writing its settings: " + st.message());
    } else {
      // Reads work but writes do not (a receive-only cable?): stream as the device is set.
      ++counters_.config_failures;
      config_pending_ = false;
      config_verifying_ = false;
      save_after_verify_ = false;
      LOG_WARN << "IMU on " << options_.port << ": cannot write its settings (" << st.message()
               << "); streaming as it is set";
    }
    return false;
  }
  // On the wire before the gap (and before a baud change). A port that cannot send them is
  // treated as gone and reopened.
  if (const Status drained = port_->Drain(); !drained.ok()) {
    Lose("sending its settings: " + drained.message());
    return false;
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(options_.configure.command_gap_ms));
  // The device was busy with the writes, not silent: the data timeout starts again, and so
  // does the wait for a sample.
  last_data_us_ = MonotonicMicros();
  last_sample_us_ = last_data_us_;
  return true;
}

void ImuDriver::Configure() {
  const ConfigureOptions& c = options_.configure;
  config_pending_ = false;
  ++config_attempts_;
  // With no baud configured (baud: 0 tries 9600 and 115200) the line's limit is known only
  // now, at the baud the device answered at: a rate beyond it is refused before any write.
  if (c.baud <= 0 && options_.baud <= 0) {
    DriverOptions found = options_;
    found.baud = port_->baud();
    if (const std::string why = RateBeyondLine(found); !why.empty()) {
      ++counters_.config_failures;
      std::ostringstream msg;
      msg << "rate_hz " << options_.rate_hz << " " << why << " (the IMU on " << options_.port
          << " answered at " << port_->baud() << " baud); nothing saved or written, streaming "
          << "as it is set";
      status_ = msg.str();
      LOG_ERROR << status_;
      return;
    }
  }
  uint16_t bits = 0;
  for (uint8_t t : c.outputs) bits = static_cast<uint16_t>(bits | OutputBit(t));
  const bool new_baud = c.baud > 0 && c.baud != port_->baud();
  std::ostringstream what;
  what << "rate " << options_.rate_hz << " Hz";
  if (bits) what << ", outputs 0x" << std::hex << bits << std::dec;
  if (new_baud) what << ", baud " << port_->baud() << " -> " << c.baud;
  const bool save = c.save && !saved_;
  if (save) what << ", saved once confirmed";
  LOG_INFO << "IMU on " << options_.port << ": writing " << what.str() << " (attempt "
           << config_attempts_ << " of " << c.max_attempts << ")";
  // The baud rate last: the device switches at once and understands nothing more at the old
  // rate. The save comes only after the stream has confirmed the settings, and once per
  // process: each SAVE is a flash write, and a loose cable must not wear the flash out.
  if (!Write(kRegKey, kUnlockKey)) return;
  if (bits && !Write(kRegOutputs, bits)) return;
  if (!Write(kRegRate, RateCode(options_.rate_hz))) return;
  if (new_baud) {
    if (!Write(kRegBaud, BaudCode(c.baud))) return;
    const Status st = port_->SetBaud(c.baud);
    if (!st.ok()) {
      Lose(st.message());
      return;
    }
    baud_index_ = 0;  // Bauds() puts the configured rate first
  }
  save_after_verify_ = save;
  port_->FlushInput();
  ResetStream();
  state_ = DriverState::kOpening;
  opened_us_ = MonotonicMicros();
  bytes_since_open_ = 0;
  reopened_by_config_ = true;
  config_verifying_ = true;
  status_ = "wrote the IMU's settings (" + what.str() + "); waiting for frames at " +
            std::to_string(port_->baud()) + " baud";
}

bool ImuDriver::VerifyConfiguration() {
  config_verifying_ = false;
  const std::vector<uint8_t>& want = options_.configure.outputs;
  const FrameCycle& cycle = builder_.cycle();
  if (!want.empty() && cycle.types() != want) {
    auto names = [](const std::vector<uint8_t>& v) {
      std::ostringstream o;
      for (size_t i = 0; i < v.size(); ++i) o << (i ? " " : "") << "0x" << std::hex << int{v[i]};
      return o.str();
    };
    ++counters_.config_failures;
    const bool again = config_attempts_ < options_.configure.max_attempts;
    LOG_WARN << "IMU on " << options_.port << ": asked for frames " << names(want)
             << ", the device sends " << names(cycle.types())
             << (again ? "; writing the settings again" : "; giving up, streaming as it is set");
    if (again) {
      Configure();
      return false;
    }
    return true;
  }
  if (save_after_verify_) {
    save_after_verify_ = false;
    if (!Write(kRegKey, kUnlockKey) || !Write(kRegSave, 0)) return port_ != nullptr;
    saved_ = true;
  }
  config_attempts_ = 0;
  ++counters_.configurations;
  LOG_INFO << "IMU on " << options_.port << ": settings confirmed by the stream at "
           << port_->baud() << " baud";
  return true;
}

void ImuDriver::MeasureRate(size_t samples) {
  if (state_ != DriverState::kStreaming) return;
  const int64_t now = MonotonicMicros();
  if (rate_window_start_us_ == 0) {
    // Count from the next read on: the samples of this one arrived before the window.
    rate_window_start_us_ = now;
    rate_window_samples_ = 0;
    return;
  }
  rate_window_samples_ += static_cast<int64_t>(samples);
  const int64_t span = now - rate_window_start_us_;
  if (span < 2'000'000) return;
  measured_rate_hz_ = static_cast<double>(rate_window_samples_) * 1e6 / static_cast<double>(span);
  rate_window_start_us_ = now;
  rate_window_samples_ = 0;
  if (rate_checked_) return;
  rate_checked_ = true;
  if (std::abs(measured_rate_hz_ - options_.rate_hz) > 0.2 * options_.rate_hz) {
    ++counters_.rate_mismatches;
    LOG_WARN << "IMU on " << options_.port << " sends " << measured_rate_hz_
             << " samples/s but rate_hz is " << options_.rate_hz
             << ": the stamps are spaced by rate_hz; set it to the device's rate (or set "
                "configure.enabled to write it into the device)";
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
    // Gone while its new settings were awaited (unplugged mid-configuration): a loss, so the
    // device that comes back is configured afresh.
    const bool gone_while_verifying =
        config_verifying_ && n.error().code == ErrorCode::kUnavailable;
    if (state_ == DriverState::kOpening && !gone_while_verifying) {
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
  } else if (state_ == DriverState::kStreaming && now - last_sample_us_ > no_sample_limit_us_) {
    // Frames keep the data timeout away, yet no sample closes: with trigger auto, a stray type
    // learned into the cycle above its last type would close no sample ever again.
    Relearn(now);
  }
}

void ImuDriver::Shutdown() {
  port_.reset();
  state_ = DriverState::kDisconnected;
}

}  // namespace omni::imu
