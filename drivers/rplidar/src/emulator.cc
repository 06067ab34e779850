#include "omni/rplidar/emulator.h"

#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <random>

namespace omni::rplidar {

double RoomRangeMm(double angle_cw_deg) {
  const double a = -angle_cw_deg * M_PI / 180.0;  // CCW in the lidar frame
  const double dx = std::cos(a), dy = std::sin(a);
  const double x0 = 0.7, y0 = 0.4, hx = 3.0, hy = 2.0;
  double t = 1e9;
  if (dx > 1e-9) t = std::min(t, (hx - x0) / dx);
  if (dx < -1e-9) t = std::min(t, (-hx - x0) / dx);
  if (dy > 1e-9) t = std::min(t, (hy - y0) / dy);
  if (dy < -1e-9) t = std::min(t, (-hy - y0) / dy);
  // A pillar (0.3 m radius) at (-1.5, -0.5): some structure for scan matchers.
  const double px = -1.5 - x0, py = -0.5 - y0, r = 0.3;
  const double b = px * dx + py * dy, c = px * px + py * py - r * r;
  const double disc = b * b - c;
  if (disc >= 0 && b - std::sqrt(disc) > 0) t = std::min(t, b - std::sqrt(disc));
  return t * 1000.0;
}

Result<std::unique_ptr<RplidarEmulator>> RplidarEmulator::Create(EmulatorOptions options) {
  if (!options.range_mm) options.range_mm = RoomRangeMm;
  if (options.scan_hz <= 0 || options.standard_sample_us <= 0 || options.express_sample_us <= 0) {
    return MakeError(ErrorCode::kInvalidArgument, "RPLidar emulator: rates must be > 0");
  }
  if (!options.capture.empty() && options.capture.size() < kSampleSize) {
    return MakeError(ErrorCode::kInvalidArgument, "RPLidar emulator: capture shorter than a node");
  }
  std::unique_ptr<RplidarEmulator> e(new RplidarEmulator(std::move(options)));
  Status st = e->Restore();
  if (!st.ok()) return st.error();
  return e;
}

void RplidarEmulator::Vanish() {
  pty_.reset();
  scanning_ = false;
  in_.clear();
}

Status RplidarEmulator::Restore() {
  auto pty = serial::Pty::Create(options_.link_path);
  if (!pty.ok()) return pty.error();
  pty_ = std::move(*pty);
  if (options_.link_path.empty()) options_.link_path = pty_->slave_path();
  scanning_ = false;
  in_.clear();
  return Status::Ok();
}

void RplidarEmulator::Send(const uint8_t* data, size_t size) {
  if (!pty_) return;
  size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(pty_->master_fd(), data + done, size - done);
    if (n <= 0) break;  // buffer full (nobody reading): the bytes are lost, as on a real UART
    done += static_cast<size_t>(n);
  }
  counters_.bytes_streamed += static_cast<int64_t>(done);
  counters_.bytes_dropped += static_cast<int64_t>(size - done);
}

void RplidarEmulator::InjectGarbage(size_t bytes, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> g(bytes);
  for (auto& b : g) b = static_cast<uint8_t>(rng());
  Send(g);
}

void RplidarEmulator::HandleInput() {
  if (!pty_) return;
  uint8_t buf[256];
  while (true) {
    const ssize_t n = ::read(pty_->master_fd(), buf, sizeof(buf));
    if (n <= 0) break;
    in_.insert(in_.end(), buf, buf + n);
  }
  size_t i = 0;
  while (i + 2 <= in_.size()) {
    if (in_[i] != kSyncByte) {
      ++i;
      continue;
    }
    const uint8_t cmd = in_[i + 1];
    std::vector<uint8_t> payload;
    size_t used = 2;
    if (cmd & 0x80) {  // RPLIDAR_CMDFLAG_HAS_PAYLOAD
      if (i + 3 > in_.size()) break;
      const size_t len = in_[i + 2];
      if (i + 3 + len + 1 > in_.size()) break;
      uint8_t sum = 0;
      for (size_t k = 0; k < 3 + len; ++k) sum ^= in_[i + k];
      if (sum != in_[i + 3 + len]) {
        ++counters_.bad_requests;
        ++i;
        continue;
      }
      payload.assign(in_.begin() + static_cast<long>(i + 3),
                     in_.begin() + static_cast<long>(i + 3 + len));
      used = 3 + len + 1;
    }
    HandleCommand(cmd, payload);
    i += used;
  }
  in_.erase(in_.begin(), in_.begin() + static_cast<long>(i));
}

void RplidarEmulator::HandleCommand(uint8_t cmd, const std::vector<uint8_t>& payload) {
  ++counters_.commands;
  auto descriptor = [&](uint32_t size, uint8_t mode, uint8_t type) {
    const auto d = EncodeDescriptor({size, mode, type});
    Send(d.data(), d.size());
  };
  switch (cmd) {
    case kCmdStop:
      scanning_ = false;
      break;
    case kCmdReset: {
      scanning_ = false;
      health_ = Health{};
      ++counters_.resets;
      const std::string banner =
          "RP LIDAR System.\r\nFirmware Ver 1.29 - rc0\r\nHardware Rev 6\r\n";
      Send(reinterpret_cast<const uint8_t*>(banner.data()), banner.size());
      break;
    }
    case kCmdGetInfo: {
      DeviceInfo info;
      info.model = static_cast<uint8_t>(options_.model);
      info.firmware_version = 0x011D;
      info.hardware_version = 6;
      for (size_t k = 0; k < 16; ++k) info.serial_number[k] = static_cast<uint8_t>(0xE0 + k);
      descriptor(kDevInfoSize, kModeSingle, kAnsDevInfo);
      Send(EncodeDeviceInfo(info));
      break;
    }
    case kCmdGetHealth:
      descriptor(kHealthSize, kModeSingle, kAnsDevHealth);
      Send(EncodeHealth(health_));
      break;
    case kCmdGetSampleRate:
      descriptor(kSampleRateSize, kModeSingle, kAnsSampleRate);
      Send(EncodeSampleRate({static_cast<uint16_t>(options_.standard_sample_us),
                             static_cast<uint16_t>(options_.express_sample_us)}));
      break;
    case kCmdGetAccBoardFlag: {
      descriptor(4, kModeSingle, kAnsAccBoardFlag);
      const uint8_t flag = (options_.model >> 4) >= 2 ? 1 : 0;  // A2+: motor by PWM
      Send(std::vector<uint8_t>{flag, 0, 0, 0});
      break;
    }
    case kCmdSetMotorPwm:
      if (payload.size() >= 2) motor_pwm_ = static_cast<uint16_t>(payload[0] | (payload[1] << 8));
      break;
    case kCmdScan:
    case kCmdForceScan:
    case kCmdExpressScan:
      if (health_.status == kHealthError) break;  // a device in protection stop does not scan
      express_ = cmd == kCmdExpressScan;
      if (express_) {
        descriptor(kCapsuleSize, kModeMulti, kAnsMeasurementCapsuled);
      } else {
        descriptor(kSampleSize, kModeMulti, kAnsMeasurement);
      }
      scanning_ = true;
      first_capsule_ = true;
      scan_start_us_ = now_us_;
      emitted_ = 0;
      capture_pos_ = 0;
      ++counters_.scans_started;
      break;
    default:
      break;  // unknown commands are ignored, as by the device
  }
}

void RplidarEmulator::StreamDue(int64_t now_us) {
  if (!scanning_ || !pty_) return;
  const double elapsed_us = static_cast<double>(now_us - scan_start_us_);
  std::vector<uint8_t> out;
  if (!express_) {
    const int64_t due = static_cast<int64_t>(elapsed_us / options_.standard_sample_us);
    const int per_rev = std::max(
        1, static_cast<int>(std::lround(1e6 / options_.scan_hz / options_.standard_sample_us)));
    for (; emitted_ < due; ++emitted_) {
      if (!options_.capture.empty()) {
        if (capture_pos_ + kSampleSize > options_.capture.size()) capture_pos_ = 0;
        out.insert(out.end(), options_.capture.begin() + static_cast<long>(capture_pos_),
                   options_.capture.begin() + static_cast<long>(capture_pos_ + kSampleSize));
        capture_pos_ += kSampleSize;
        continue;
      }
      const int k = static_cast<int>(emitted_ % per_rev);
      const double angle = 360.0 * k / per_rev;
      const double r = options_.range_mm(angle);
      const bool valid = r > 0 && r < 16000;
      const auto b = EncodeStandardSample(angle, valid ? r : 0, valid ? 47 : 0, k == 0);
      out.insert(out.end(), b.begin(), b.end());
    }
  } else {
    const int64_t due = static_cast<int64_t>(elapsed_us / (32.0 * options_.express_sample_us));
    const double deg_per_sample = 360.0 * options_.scan_hz * options_.express_sample_us * 1e-6;
    for (; emitted_ < due; ++emitted_) {
      Capsule c;
      const double start = std::fmod(emitted_ * 32 * deg_per_sample, 360.0);
      c.start_angle_q6 = static_cast<uint16_t>(std::lround(start * 64.0) % (360 * 64));
      c.start = first_capsule_;
      first_capsule_ = false;
      for (int i = 0; i < 16; ++i) {
        for (int k = 0; k < 2; ++k) {
          const double a = std::fmod(start + (2 * i + k) * deg_per_sample, 360.0);
          const double r = options_.range_mm(a);
          const int q2 = (r > 0 && r < 16000) ? static_cast<int>(std::lround(r * 4.0)) & 0xFFFC : 0;
          auto& cabin = c.cabins[static_cast<size_t>(i)];
          (k == 0 ? cabin.distance_angle_1 : cabin.distance_angle_2) = static_cast<uint16_t>(q2);
        }
      }
      const auto b = EncodeCapsule(c);
      out.insert(out.end(), b.begin(), b.end());
    }
  }
  if (!out.empty()) Send(out);
}

void RplidarEmulator::Step(int64_t now_us) {
  now_us_ = now_us;
  HandleInput();
  StreamDue(now_us);
}

}  // namespace omni::rplidar
