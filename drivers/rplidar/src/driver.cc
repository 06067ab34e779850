#include "omni/rplidar/driver.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <thread>

#include "omni/common/config.h"
#include "omni/common/log.h"

namespace omni::rplidar {

Status LoadRplidarOptions(const std::string& path, DriverOptions* d, NodeOptions* n) {
  auto reader = ConfigReader::FromFile(path);
  if (!reader.ok()) return reader.error();
  return LoadRplidarOptions(*reader, d, n);
}

Status LoadRplidarOptions(ConfigReader& r, DriverOptions* d, NodeOptions* n) {
  r.Get("port", &d->port, Required(), NonEmpty());
  r.Get("baud", &d->baud, Optional(), InRange(0, 4000000));
  r.Get("model", &d->model, Optional(), OneOf({"auto", "a1", "a2", "a3"}));
  r.Get("scan_mode", &d->scan_mode, Optional(), OneOf({"standard", "express", "force"}));
  r.Get("motor_pwm", &d->motor_pwm, Optional(), InRange(0, 1023));
  r.Get("data_timeout_s", &d->data_timeout_s, Optional(), InRange(0.05, 60.0));
  r.Get("reconnect_interval_s", &d->reconnect_interval_s, Optional(), InRange(0.01, 60.0));
  r.Get("response_timeout_s", &d->response_timeout_s, Optional(), InRange(0.01, 10.0));
  r.Get("reset_wait_s", &d->reset_wait_s, Optional(), InRange(0.0, 10.0));
  r.Get("resync_lookahead", &d->resync_lookahead, Optional(), InRange(1, 16));
  ConfigReader scan = r.Section("scan");
  scan.Get("beams", &d->scan.beams, Optional(), InRange(16, 16384));
  scan.Get("range_min_m", &d->scan.range_min_m, Optional(), NonNegative<double>());
  scan.Get("range_max_m", &d->scan.range_max_m, Optional(), InRange(0.1, 1000.0));
  scan.Get("angle_offset_rad", &d->scan.angle_offset_rad, Optional(), InRange(-7.0, 7.0));
  if (d->scan.range_min_m >= d->scan.range_max_m) {
    r.AddError("scan.range_min_m", "must be < scan.range_max_m");
  }
  r.Get("channel", &n->channel, Optional(), NonEmpty());
  r.Get("frame", &n->frame, Optional(), NonEmpty());
  r.Get("bus_url", &n->bus_url, Optional());
  ConfigReader mount = r.Section("mount");
  mount.Get("x_m", &n->mount_x_m, Optional(), InRange(-10.0, 10.0));
  mount.Get("y_m", &n->mount_y_m, Optional(), InRange(-10.0, 10.0));
  mount.Get("yaw_rad", &n->mount_yaw_rad, Optional(), InRange(-7.0, 7.0));
  return r.Finish();
}

RplidarDriver::RplidarDriver(DriverOptions options, const Clock* clock)
    : options_(std::move(options)),
      clock_(clock),
      parser_(StreamMode::kStandard, options_.resync_lookahead) {}

RplidarDriver::~RplidarDriver() { Shutdown(); }

void RplidarDriver::SleepMs(int ms) { std::this_thread::sleep_for(std::chrono::milliseconds(ms)); }

Status RplidarDriver::Transact(const std::vector<uint8_t>& request, uint8_t type,
                               std::vector<uint8_t>* payload, std::vector<uint8_t>* leftover) {
  Status st = port_->Write(request.data(), request.size());
  if (!st.ok()) return st;
  std::vector<uint8_t> buf;
  const int64_t deadline = MonotonicMicros() + SecondsToUtime(options_.response_timeout_s);
  uint8_t chunk[512];
  while (true) {
    // Look for A5 5A .. type; anything before it (old scan data, a reset banner) is skipped.
    for (size_t i = 0; i + kDescriptorSize <= buf.size(); ++i) {
      Descriptor d;
      if (!DecodeDescriptor(&buf[i], &d) || d.type != type) continue;
      const size_t body = i + kDescriptorSize;
      if (d.mode == kModeSingle) {
        // Never trust a length: single answers of this protocol are at most a few dozen bytes.
        if (d.size > 256) continue;
        if (buf.size() < body + d.size) break;  // wait for the rest
        if (payload)
          payload->assign(buf.begin() + static_cast<long>(body),
                          buf.begin() + static_cast<long>(body + d.size));
        return Status::Ok();
      }
      if (leftover) leftover->assign(buf.begin() + static_cast<long>(body), buf.end());
      return Status::Ok();
    }
    const int64_t left = deadline - MonotonicMicros();
    if (left <= 0) {
      char hex[8];
      std::snprintf(hex, sizeof(hex), "0x%02X", request.size() > 1 ? request[1] : 0);
      return MakeError(ErrorCode::kUnavailable,
                       "RPLidar on " + options_.port + ": no answer to command " + hex +
                           " within " + std::to_string(options_.response_timeout_s) + " s at " +
                           std::to_string(port_->baud()) + " baud");
    }
    auto n = port_->Read(chunk, sizeof(chunk), static_cast<int>(left / 1000) + 1);
    if (!n.ok()) return n.error();
    buf.insert(buf.end(), chunk, chunk + *n);
    if (buf.size() > 65536) buf.erase(buf.begin(), buf.end() - 64);
  }
}

Status RplidarDriver::StartMotor(int major_model) {
  const bool dtr_model = options_.model == "a1" || (options_.model == "auto" && major_model == 1);
  if (dtr_model) {
    // A1: the motor runs while DTR is low (rplidar_sdk startMotor: clearDTR).
    Status st = port_->SetDtr(false);
    if (!st.ok()) {
      ++counters_.dtr_failures;
      LOG_WARN << st.message() << " (motor control by DTR skipped; not fatal)";
    }
    return Status::Ok();
  }
  const auto req = MakeMotorPwmRequest(static_cast<uint16_t>(options_.motor_pwm));
  return port_->Write(req.data(), req.size());
}

Status RplidarDriver::Handshake() {
  // Stop whatever the device was doing and drop what it already sent.
  const auto stop = MakeRequest(kCmdStop);
  Status st = port_->Write(stop.data(), stop.size());
  if (!st.ok()) return st;
  SleepMs(20);
  port_->FlushInput();
  std::vector<uint8_t> payload;
  st = Transact(MakeRequest(kCmdGetInfo), kAnsDevInfo, &payload, nullptr);
  if (!st.ok()) return st;
  if (payload.size() < kDevInfoSize) {
    return MakeError(ErrorCode::kParse, "RPLidar on " + options_.port + ": GET_INFO answer has " +
                                            std::to_string(payload.size()) + " bytes, expected 20");
  }
  info_ = DecodeDeviceInfo(payload.data());
  for (int attempt = 0; attempt < 2; ++attempt) {
    st = Transact(MakeRequest(kCmdGetHealth), kAnsDevHealth, &payload, nullptr);
    if (!st.ok()) return st;
    if (payload.size() < kHealthSize) {
      return MakeError(ErrorCode::kParse, "RPLidar on " + options_.port + ": short GET_HEALTH");
    }
    health_ = DecodeHealth(payload.data());
    if (health_.status != kHealthError) break;
    LOG_WARN << "RPLidar on " << options_.port << ": health error code " << health_.error_code
             << ", sending RESET";
    ++counters_.health_resets;
    const auto reset = MakeRequest(kCmdReset);
    st = port_->Write(reset.data(), reset.size());
    if (!st.ok()) return st;
    SleepMs(static_cast<int>(options_.reset_wait_s * 1000));
    port_->FlushInput();
  }
  if (health_.status == kHealthError) {
    return MakeError(ErrorCode::kUnavailable,
                     "RPLidar on " + options_.port + ": health is error (code " +
                         std::to_string(health_.error_code) + ") after RESET");
  }
  st = StartMotor(info_.MajorModel());
  if (!st.ok()) return st;
  std::vector<uint8_t> leftover;
  StreamMode mode = StreamMode::kStandard;
  if (options_.scan_mode == "express") {
    mode = StreamMode::kExpressLegacy;
    st = Transact(MakeExpressScanRequest(), kAnsMeasurementCapsuled, nullptr, &leftover);
  } else {
    st = Transact(MakeRequest(options_.scan_mode == "force" ? kCmdForceScan : kCmdScan),
                  kAnsMeasurement, nullptr, &leftover);
  }
  if (!st.ok()) return st;
  parser_.Reset(mode);
  assembler_.Reset();
  samples_.clear();
  if (!leftover.empty())
    parser_.Feed(leftover.data(), leftover.size(), clock_->NowUtime(), &samples_);
  return Status::Ok();
}

Status RplidarDriver::Connect() {
  port_.reset();
  std::vector<int> bauds;
  if (options_.baud > 0) {
    bauds = {options_.baud};
  } else if (options_.model == "a3") {
    bauds = {256000};
  } else if (options_.model == "a1" || options_.model == "a2") {
    bauds = {115200};
  } else {
    bauds = {256000, 115200};
  }
  Status last;
  for (int baud : bauds) {
    auto port = serial::SerialPort::Open(options_.port, baud);
    if (!port.ok()) {
      last = port.error();
      if (port.error().code == ErrorCode::kNotFound) break;  // no point trying other rates
      continue;
    }
    port_ = std::move(*port);
    last = Handshake();
    if (last.ok()) break;
    port_.reset();
  }
  if (!last.ok()) {
    ++counters_.connect_failures;
    status_ = last.error().message;
    state_ = DriverState::kDisconnected;
    next_attempt_us_ = MonotonicMicros() + SecondsToUtime(options_.reconnect_interval_s);
    return last;
  }
  if (ever_connected_) ++counters_.reconnects;
  ever_connected_ = true;
  state_ = DriverState::kStreaming;
  last_data_us_ = MonotonicMicros();
  char fw[32];
  std::snprintf(fw, sizeof(fw), "%d.%02d", info_.firmware_version >> 8,
                info_.firmware_version & 0xFF);
  status_ = "scanning (" + options_.scan_mode + ") on " + options_.port + " at " +
            std::to_string(port_->baud()) + " baud, model " + std::to_string(info_.model) + " fw " +
            fw + " serial " + info_.SerialHex();
  LOG_INFO << "RPLidar " << status_;
  return Status::Ok();
}

void RplidarDriver::Lose(const std::string& why) {
  LOG_WARN << "RPLidar on " << options_.port << ": " << why << "; reconnecting every "
           << options_.reconnect_interval_s << " s";
  port_.reset();
  state_ = DriverState::kDisconnected;
  status_ = why;
  counters_.dropped_samples += static_cast<int64_t>(assembler_.pending());
  samples_.clear();
  assembler_.Reset();
  // The next connection's samples are timed afresh (the handshake's leftovers would skew it).
  sample_period_us_ = 0;
  last_read_utime_ = -1;
  next_attempt_us_ = MonotonicMicros() + SecondsToUtime(options_.reconnect_interval_s);
}

void RplidarDriver::Step(int timeout_ms, std::vector<std::vector<Sample>>* out) {
  if (state_ == DriverState::kDisconnected) {
    const int64_t wait_us = next_attempt_us_ - MonotonicMicros();
    if (wait_us > 0) {
      SleepMs(static_cast<int>(std::min<int64_t>(wait_us / 1000 + 1, timeout_ms)));
      return;
    }
    Status st = Connect();
    if (!st.ok()) {
      LOG_DEBUG << st.message();
    }
    return;
  }
  uint8_t chunk[4096];
  auto n = port_->Read(chunk, sizeof(chunk), timeout_ms);
  if (!n.ok()) {
    Lose(n.error().message);
    return;
  }
  const int64_t now_mono = MonotonicMicros();
  if (*n == 0) {
    if (now_mono - last_data_us_ > SecondsToUtime(options_.data_timeout_s)) {
      ++counters_.timeouts;
      Lose("no data for " + std::to_string(options_.data_timeout_s) + " s");
    }
    return;
  }
  last_data_us_ = now_mono;
  // samples_ may still hold what came in with the scan's descriptor (Handshake): keep it.
  const int64_t now = clock_->NowUtime();
  parser_.Feed(chunk, *n, now, &samples_);
  // A full chunk: more is waiting (the process was held up). All of it came by now, so it is
  // read before the samples are stamped back from now (at most 64 chunks, 256 KB).
  for (int more = 0; *n == sizeof(chunk) && more < 64; ++more) {
    n = port_->Read(chunk, sizeof(chunk), 0);
    if (!n.ok()) {
      Lose(n.error().message);
      return;
    }
    if (*n == 0) break;
    parser_.Feed(chunk, *n, now, &samples_);
  }
  // The wall clock set back by more than a second: followed, not hidden behind stamps 1 us
  // apart (the mappers re-base on such a step; their other inputs show it too).
  if (last_stamp_ >= 0 && now < last_stamp_ - 1000000) last_stamp_ = -1;
  if (!samples_.empty()) {
    const double count = static_cast<double>(samples_.size());
    if (last_read_utime_ >= 0 && now > last_read_utime_ && now - last_read_utime_ < 500000) {
      // Samples stream without pause: the time since the last read is what these took.
      const double period = static_cast<double>(now - last_read_utime_) / count;
      if (period >= 20 && period <= 10000)
        sample_period_us_ = sample_period_us_ > 0 ? 0.9 * sample_period_us_ + 0.1 * period : period;
    }
    last_read_utime_ = now;
    for (size_t i = 0; i < samples_.size(); ++i) {
      int64_t t = now;
      if (sample_period_us_ > 0)
        t -= std::llround((count - 1 - static_cast<double>(i)) * sample_period_us_);
      t = std::max(t, last_stamp_ + 1);
      samples_[i].utime = t;
      last_stamp_ = t;
    }
  }
  std::vector<Sample> done;
  for (const Sample& s : samples_) {
    if (assembler_.Add(s, &done)) {
      ++counters_.revolutions;
      out->push_back(std::move(done));
      done.clear();
    }
  }
  samples_.clear();
}

void RplidarDriver::Shutdown() {
  if (!port_) return;
  const auto stop = MakeRequest(kCmdStop);
  (void)port_->Write(stop.data(), stop.size(), 100);
  if (options_.model != "a1" && info_.MajorModel() != 1) {
    const auto pwm0 = MakeMotorPwmRequest(0);
    (void)port_->Write(pwm0.data(), pwm0.size(), 100);
  } else {
    (void)port_->SetDtr(true);
  }
  port_.reset();
  state_ = DriverState::kDisconnected;
}

}  // namespace omni::rplidar
