#include "omni/imu/witmotion.h"

#include <cmath>

namespace omni::imu {

std::array<uint8_t, kFrameSize> EncodeFrame(uint8_t type, const std::array<int16_t, 4>& v) {
  std::array<uint8_t, kFrameSize> b{};
  b[0] = kHeader;
  b[1] = type;
  for (size_t i = 0; i < 4; ++i) {
    const uint16_t u = static_cast<uint16_t>(v[i]);
    b[2 + 2 * i] = static_cast<uint8_t>(u & 0xFF);
    b[3 + 2 * i] = static_cast<uint8_t>(u >> 8);
  }
  unsigned sum = 0;
  for (size_t i = 0; i < 10; ++i) sum += b[i];
  b[10] = static_cast<uint8_t>(sum & 0xFF);
  return b;
}

bool IsKnownType(uint8_t type) { return type >= 0x50 && type <= 0x5A; }

std::array<uint8_t, kWriteSize> EncodeWrite(uint8_t reg, uint16_t value) {
  return {0xFF, 0xAA, reg, static_cast<uint8_t>(value & 0xFF), static_cast<uint8_t>(value >> 8)};
}

namespace {
// RRATE codes 0x01..0x0B (0x0A, 125 Hz, exists on the WT931 only and is left out).
constexpr struct {
  uint8_t code;
  double hz;
} kRates[] = {{0x01, 0.2}, {0x02, 0.5}, {0x03, 1},  {0x04, 2},   {0x05, 5},
              {0x06, 10},  {0x07, 20},  {0x08, 50}, {0x09, 100}, {0x0B, 200}};
// BAUD codes 1..9.
constexpr int kBaudOfCode[] = {0, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600};
}  // namespace

uint8_t RateCode(double hz) {
  for (const auto& r : kRates)
    if (std::abs(hz - r.hz) < 1e-9) return r.code;
  return 0;
}

double RateOfCode(uint8_t code) {
  for (const auto& r : kRates)
    if (r.code == code) return r.hz;
  return 0;
}

uint8_t BaudCode(int baud) {
  for (uint8_t c = 1; c < sizeof(kBaudOfCode) / sizeof(kBaudOfCode[0]); ++c)
    if (kBaudOfCode[c] == baud) return c;
  return 0;
}

int BaudOfCode(uint8_t code) {
  return code >= 1 && code < sizeof(kBaudOfCode) / sizeof(kBaudOfCode[0]) ? kBaudOfCode[code] : 0;
}

uint16_t OutputBit(uint8_t type) {
  return IsKnownType(type) ? static_cast<uint16_t>(1u << (type - 0x50)) : 0;
}

void WriteParser::Feed(const uint8_t* data, size_t size, std::vector<RegisterWrite>* out) {
  buf_.insert(buf_.end(), data, data + size);
  size_t at = 0;
  while (buf_.size() - at >= 2) {
    if (buf_[at] != 0xFF || buf_[at + 1] != 0xAA) {
      ++at;
      ++bytes_skipped_;
      continue;
    }
    if (buf_.size() - at < kWriteSize) break;
    out->push_back({buf_[at + 2], static_cast<uint16_t>(buf_[at + 3] | (buf_[at + 4] << 8))});
    at += kWriteSize;
  }
  buf_.erase(buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(at));
}

void FrameParser::Reset() {
  buf_.clear();
  pos_ = 0;
  in_sync_ = false;
  ever_synced_ = false;
}

bool FrameParser::FrameAt(size_t at) const {
  if (buf_.size() < at + kFrameSize) return false;
  const uint8_t* p = &buf_[at];
  if (p[0] != kHeader || !IsKnownType(p[1])) return false;
  unsigned sum = 0;
  for (size_t i = 0; i < 10; ++i) sum += p[i];
  return (sum & 0xFF) == p[10];
}

FrameParser::Check FrameParser::Confirm(size_t at) const {
  // The window at `at` checks out. A frame that lost one byte in transit leaves a window of its
  // other 10 bytes and the next frame's 0x55, which passes the additive checksum about once in
  // 256 (a gyro z of -937.5 deg/s instead of 5.6 was seen so): only the bytes after the window
  // tell. Real frames follow each other, so the next two bytes must be a header and a type.
  if (buf_.size() < at + kFrameSize + 2) return Check::kWait;
  if (buf_[at + kFrameSize] == kHeader && IsKnownType(buf_[at + kFrameSize + 1])) {
    return Check::kYes;
  }
  // Not followed by a frame. Out of sync, a window that checks out is as likely a chance match
  // in noise: dropped. In sync, it may be a whole frame with line noise after it; it is kept
  // unless a frame that checks out starts inside it, which is what a lost byte leaves (the
  // next frame, intact, starts at byte 10 of the window).
  if (!in_sync_) return Check::kNo;
  if (buf_.size() < at + 2 * kFrameSize - 1) return Check::kWait;
  for (size_t o = 1; o < kFrameSize; ++o) {
    if (FrameAt(at + o)) return Check::kNo;
  }
  return Check::kYes;
}

void FrameParser::Feed(const uint8_t* data, size_t size, std::vector<Frame>* out) {
  // Frames whose bytes were all here before this call were held back for confirmation.
  const size_t before = buf_.size();
  buf_.insert(buf_.end(), data, data + size);
  while (buf_.size() - pos_ >= kFrameSize) {
    const uint8_t* p = &buf_[pos_];
    bool ok = p[0] == kHeader && IsKnownType(p[1]);
    if (ok) {
      unsigned sum = 0;
      for (size_t i = 0; i < 10; ++i) sum += p[i];
      if ((sum & 0xFF) != p[10]) {
        // Out of sync, wait for the next frame to tell a damaged frame from a chance match.
        if (!in_sync_ && buf_.size() < pos_ + 2 * kFrameSize) break;
        // A damaged frame: in a stream we were following, or followed by a good frame.
        if (in_sync_ || FrameAt(pos_ + kFrameSize)) ++counters_.checksum_errors;
        ok = false;
      } else {
        const Check c = Confirm(pos_);
        if (c == Check::kWait) break;  // held until the next read brings the bytes after it
        if (c == Check::kNo) {
          ++counters_.unconfirmed;
          ok = false;
        }
      }
    }
    if (!ok) {
      in_sync_ = false;
      ++pos_;
      ++counters_.bytes_skipped;
      continue;
    }
    if (!in_sync_) {
      if (ever_synced_) ++counters_.resyncs;
      in_sync_ = ever_synced_ = true;
    }
    Frame f;
    f.type = p[1];
    for (size_t i = 0; i < 8; ++i) f.raw[i] = p[2 + i];
    for (size_t i = 0; i < 4; ++i) {
      f.v[i] = static_cast<int16_t>(static_cast<uint16_t>(p[2 + 2 * i] | (p[3 + 2 * i] << 8)));
    }
    f.held = pos_ + kFrameSize <= before;
    out->push_back(f);
    ++counters_.frames;
    pos_ += kFrameSize;
  }
  if (pos_ > 4096 || pos_ == buf_.size()) {
    buf_.erase(buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(pos_));
    pos_ = 0;
  }
}

uint8_t FrameParser::held_type() const {
  return buf_.size() - pos_ >= kFrameSize && FrameAt(pos_) ? buf_[pos_ + 1] : 0;
}

double AccelToMs2(int16_t v) { return v / 32768.0 * 16.0 * kGravity; }
double GyroToRadS(int16_t v) { return v / 32768.0 * 2000.0 * M_PI / 180.0; }
double AngleToRad(int16_t v) { return v / 32768.0 * M_PI; }

namespace {
int16_t ToI16(double x) {
  const long r = std::lround(x);
  return static_cast<int16_t>(r > 32767 ? 32767 : (r < -32768 ? -32768 : r));
}
}  // namespace

int16_t Ms2ToAccel(double a) { return ToI16(a / (16.0 * kGravity) * 32768.0); }
int16_t RadSToGyro(double w) { return ToI16(w * 180.0 / M_PI / 2000.0 * 32768.0); }
int16_t RadToAngle(double a) { return ToI16(a / M_PI * 32768.0); }

std::array<double, 4> EulerToQuaternion(double roll, double pitch, double yaw) {
  const double cr = std::cos(roll / 2), sr = std::sin(roll / 2);
  const double cp = std::cos(pitch / 2), sp = std::sin(pitch / 2);
  const double cy = std::cos(yaw / 2), sy = std::sin(yaw / 2);
  return {cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
          cr * cp * sy - sr * sp * cy};
}

bool SampleAssembler::Add(const Frame& f, ImuSample* out) {
  switch (f.type) {
    case kTypeAccel:
      for (size_t i = 0; i < 3; ++i) cur_.accel_m_s2[i] = AccelToMs2(f.v[i]);
      cur_.temperature_c = f.v[3] / 100.0;
      cur_.has_temperature = true;
      have_accel_ = true;
      break;
    case kTypeGyro:
      for (size_t i = 0; i < 3; ++i) cur_.gyro_rad_s[i] = GyroToRadS(f.v[i]);
      have_gyro_ = true;
      break;
    case kTypeAngle:
      for (size_t i = 0; i < 3; ++i) cur_.euler_rad[i] = AngleToRad(f.v[i]);
      if (!have_quat_) {
        cur_.orientation_wxyz =
            EulerToQuaternion(cur_.euler_rad[0], cur_.euler_rad[1], cur_.euler_rad[2]);
      }
      cur_.has_orientation = true;
      break;
    case kTypeMag:
      for (size_t i = 0; i < 3; ++i) cur_.mag_raw[i] = f.v[i];
      cur_.has_mag = true;
      break;
    case kTypeQuaternion: {
      double n = 0;
      std::array<double, 4> q;
      for (size_t i = 0; i < 4; ++i) {
        q[i] = f.v[i] / 32768.0;
        n += q[i] * q[i];
      }
      n = std::sqrt(n);
      if (n > 0.5) {
        for (size_t i = 0; i < 4; ++i) cur_.orientation_wxyz[i] = q[i] / n;
        cur_.has_orientation = true;
        have_quat_ = true;
      }
      break;
    }
    default:
      break;
  }
  if (f.type != trigger_) return false;
  if (!have_accel_ || !have_gyro_) {
    ++incomplete_;
    return false;
  }
  *out = cur_;
  have_accel_ = have_gyro_ = have_quat_ = false;
  // What a period did not bring is missing from its sample, not the period before's: an angle
  // frame lost to a bad checksum would otherwise pass on an orientation one period old.
  cur_.has_mag = cur_.has_orientation = cur_.has_temperature = false;
  return true;
}

}  // namespace omni::imu
