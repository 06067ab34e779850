#include "omni/rplidar/protocol.h"

#include <cmath>
#include <cstdio>

namespace omni::rplidar {
namespace {

uint16_t U16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }
void PutU16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v & 0xFF);
  p[1] = static_cast<uint8_t>(v >> 8);
}
int Clamp(long v, int lo, int hi) { return static_cast<int>(v < lo ? lo : (v > hi ? hi : v)); }

}  // namespace

std::string DeviceInfo::SerialHex() const {
  std::string s;
  char buf[3];
  for (uint8_t b : serial_number) {
    std::snprintf(buf, sizeof(buf), "%02X", b);
    s += buf;
  }
  return s;
}

std::vector<uint8_t> MakeRequest(uint8_t cmd) { return {kSyncByte, cmd}; }

std::vector<uint8_t> MakeRequest(uint8_t cmd, const std::vector<uint8_t>& payload) {
  std::vector<uint8_t> r{kSyncByte, cmd, static_cast<uint8_t>(payload.size())};
  uint8_t checksum = 0;
  for (uint8_t b : r) checksum ^= b;
  for (uint8_t b : payload) {
    r.push_back(b);
    checksum ^= b;
  }
  r.push_back(checksum);
  return r;
}

std::vector<uint8_t> MakeMotorPwmRequest(uint16_t pwm) {
  return MakeRequest(kCmdSetMotorPwm,
                     {static_cast<uint8_t>(pwm & 0xFF), static_cast<uint8_t>(pwm >> 8)});
}

std::vector<uint8_t> MakeExpressScanRequest() {
  return MakeRequest(kCmdExpressScan, {0, 0, 0, 0, 0});
}

std::array<uint8_t, kDescriptorSize> EncodeDescriptor(const Descriptor& d) {
  const uint32_t v = (d.size & 0x3FFFFFFFu) | (static_cast<uint32_t>(d.mode & 0x3) << 30);
  return {kSyncByte,
          kSyncByte2,
          static_cast<uint8_t>(v),
          static_cast<uint8_t>(v >> 8),
          static_cast<uint8_t>(v >> 16),
          static_cast<uint8_t>(v >> 24),
          d.type};
}

bool DecodeDescriptor(const uint8_t* p, Descriptor* d) {
  if (p[0] != kSyncByte || p[1] != kSyncByte2) return false;
  const uint32_t v = static_cast<uint32_t>(p[2]) | (static_cast<uint32_t>(p[3]) << 8) |
                     (static_cast<uint32_t>(p[4]) << 16) | (static_cast<uint32_t>(p[5]) << 24);
  d->size = v & 0x3FFFFFFFu;
  d->mode = static_cast<uint8_t>(v >> 30);
  d->type = p[6];
  return true;
}

std::vector<uint8_t> EncodeDeviceInfo(const DeviceInfo& info) {
  std::vector<uint8_t> b(kDevInfoSize);
  b[0] = info.model;
  PutU16(&b[1], info.firmware_version);
  b[3] = info.hardware_version;
  for (size_t i = 0; i < 16; ++i) b[4 + i] = info.serial_number[i];
  return b;
}

DeviceInfo DecodeDeviceInfo(const uint8_t* p) {
  DeviceInfo info;
  info.model = p[0];
  info.firmware_version = U16(p + 1);
  info.hardware_version = p[3];
  for (size_t i = 0; i < 16; ++i) info.serial_number[i] = p[4 + i];
  return info;
}

std::vector<uint8_t> EncodeHealth(const Health& h) {
  std::vector<uint8_t> b(kHealthSize);
  b[0] = h.status;
  PutU16(&b[1], h.error_code);
  return b;
}

Health DecodeHealth(const uint8_t* p) { return Health{p[0], U16(p + 1)}; }

std::vector<uint8_t> EncodeSampleRate(const SampleRate& r) {
  std::vector<uint8_t> b(kSampleRateSize);
  PutU16(&b[0], r.standard_us);
  PutU16(&b[2], r.express_us);
  return b;
}

SampleRate DecodeSampleRate(const uint8_t* p) { return SampleRate{U16(p), U16(p + 2)}; }

bool StandardSampleChecksPass(const uint8_t* p) {
  const bool s = (p[0] & 0x1) != 0;
  const bool not_s = (p[0] & 0x2) != 0;
  const bool c = (p[1] & 0x1) != 0;
  return s != not_s && c;
}

Sample DecodeStandardSample(const uint8_t* p) {
  Sample s;
  s.start = (p[0] & 0x1) != 0;
  s.quality = static_cast<uint8_t>(p[0] >> 2);
  const unsigned angle_q6 = (static_cast<unsigned>(p[2]) << 7) | (static_cast<unsigned>(p[1]) >> 1);
  const unsigned dist_q2 = (static_cast<unsigned>(p[4]) << 8) | p[3];
  s.angle_deg = angle_q6 / 64.0;
  s.distance_mm = dist_q2 / 4.0;
  return s;
}

std::array<uint8_t, kSampleSize> EncodeStandardSample(double angle_deg, double distance_mm,
                                                      uint8_t quality, bool start) {
  double a = std::fmod(angle_deg, 360.0);
  if (a < 0) a += 360.0;
  const int angle_q6 = Clamp(std::lround(a * 64.0), 0, 360 * 64 - 1);
  const int dist_q2 = Clamp(std::lround(distance_mm * 4.0), 0, 0xFFFF);
  std::array<uint8_t, kSampleSize> b;
  b[0] = static_cast<uint8_t>(((quality & 0x3F) << 2) | (start ? 0x1 : 0x2));
  b[1] = static_cast<uint8_t>(((angle_q6 & 0x7F) << 1) | 0x1);
  b[2] = static_cast<uint8_t>(angle_q6 >> 7);
  b[3] = static_cast<uint8_t>(dist_q2 & 0xFF);
  b[4] = static_cast<uint8_t>(dist_q2 >> 8);
  return b;
}

bool CapsuleSyncMatches(const uint8_t* p) { return (p[0] >> 4) == 0xA && (p[1] >> 4) == 0x5; }

bool CapsuleChecksumMatches(const uint8_t* p) {
  const uint8_t expected = static_cast<uint8_t>((p[0] & 0xF) | ((p[1] & 0xF) << 4));
  uint8_t sum = 0;
  for (size_t i = 2; i < kCapsuleSize; ++i) sum ^= p[i];
  return sum == expected;
}

Capsule DecodeCapsule(const uint8_t* p) {
  Capsule c;
  const uint16_t a = U16(p + 2);
  c.start = (a & 0x8000) != 0;
  c.start_angle_q6 = a & 0x7FFF;
  for (size_t i = 0; i < 16; ++i) {
    const uint8_t* q = p + 4 + 5 * i;
    c.cabins[i].distance_angle_1 = U16(q);
    c.cabins[i].distance_angle_2 = U16(q + 2);
    c.cabins[i].offset_angles_q3 = q[4];
  }
  return c;
}

std::array<uint8_t, kCapsuleSize> EncodeCapsule(const Capsule& c) {
  std::array<uint8_t, kCapsuleSize> b{};
  PutU16(&b[2], static_cast<uint16_t>((c.start_angle_q6 & 0x7FFF) | (c.start ? 0x8000 : 0)));
  for (size_t i = 0; i < 16; ++i) {
    uint8_t* q = &b[4 + 5 * i];
    PutU16(q, c.cabins[i].distance_angle_1);
    PutU16(q + 2, c.cabins[i].distance_angle_2);
    q[4] = c.cabins[i].offset_angles_q3;
  }
  uint8_t sum = 0;
  for (size_t i = 2; i < kCapsuleSize; ++i) sum ^= b[i];
  b[0] = static_cast<uint8_t>(0xA0 | (sum & 0xF));
  b[1] = static_cast<uint8_t>(0x50 | (sum >> 4));
  return b;
}

void CapsuleToSamples(const Capsule& prev, const Capsule& next, int64_t utime,
                      std::vector<Sample>* out) {
  const int32_t prev_start_q8 = static_cast<int32_t>(prev.start_angle_q6) << 2;
  const int32_t cur_start_q8 = static_cast<int32_t>(next.start_angle_q6) << 2;
  int32_t diff_q8 = cur_start_q8 - prev_start_q8;
  if (prev_start_q8 > cur_start_q8) diff_q8 += (360 << 8);
  const int32_t inc_q16 = diff_q8 << 3;  // 32 samples per capsule: << 8 >> 5
  int32_t angle_q16 = prev_start_q8 << 8;
  constexpr int32_t kFull = 360 << 16;
  for (const Cabin& cabin : prev.cabins) {
    const int32_t dist_q2[2] = {cabin.distance_angle_1 & 0xFFFC, cabin.distance_angle_2 & 0xFFFC};
    const int32_t offset_q3[2] = {
        (cabin.offset_angles_q3 & 0xF) | ((cabin.distance_angle_1 & 0x3) << 4),
        (cabin.offset_angles_q3 >> 4) | ((cabin.distance_angle_2 & 0x3) << 4)};
    for (int k = 0; k < 2; ++k) {
      int32_t angle_q6 = (angle_q16 - (offset_q3[k] << 13)) >> 10;
      const bool sync = ((angle_q16 + inc_q16) % kFull) < inc_q16;
      angle_q16 += inc_q16;
      if (angle_q6 < 0) angle_q6 += (360 << 6);
      if (angle_q6 >= (360 << 6)) angle_q6 -= (360 << 6);
      Sample s;
      s.angle_deg = angle_q6 / 64.0;
      s.distance_mm = dist_q2[k] / 4.0;
      s.quality = dist_q2[k] != 0 ? 0x2F : 0;
      s.start = sync;
      s.utime = utime;
      out->push_back(s);
    }
  }
}

}  // namespace omni::rplidar
