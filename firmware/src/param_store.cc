#include "omni/firmware/param_store.h"

#include <cstring>

namespace omni::firmware {
namespace {

// Writable parameter ids: 1 .. kParamHeartbeatPeriodMs (the rest are read-only).
constexpr uint16_t kFirstId = kParamKp;
constexpr uint16_t kLastId = kParamHeartbeatPeriodMs;
constexpr size_t kHeader = 8, kRecord = 6, kCrc = 4;

void Put16(uint8_t* b, uint16_t v) {
  b[0] = static_cast<uint8_t>(v);
  b[1] = static_cast<uint8_t>(v >> 8);
}
void Put32(uint8_t* b, uint32_t v) {
  for (int i = 0; i < 4; ++i) b[i] = static_cast<uint8_t>(v >> (8 * i));
}
uint16_t Get16(const uint8_t* b) { return static_cast<uint16_t>(b[0] | (b[1] << 8)); }
uint32_t Get32(const uint8_t* b) {
  return static_cast<uint32_t>(b[0]) | (static_cast<uint32_t>(b[1]) << 8) |
         (static_cast<uint32_t>(b[2]) << 16) | (static_cast<uint32_t>(b[3]) << 24);
}

}  // namespace

uint32_t Crc32(const uint8_t* data, size_t len) {
  // Bitwise (no table: 1 KiB of flash is worth more than speed for a few hundred bytes).
  uint32_t crc = 0xFFFFFFFFu;
  for (size_t i = 0; i < len; ++i) {
    crc ^= data[i];
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

size_t EncodeParamStore(const Params& p, uint8_t* buf, size_t cap) {
  const size_t count = kLastId - kFirstId + 1;
  const size_t len = kHeader + count * kRecord + kCrc;
  if (cap < len) return 0;
  Put32(buf, kParamStoreMagic);
  Put16(buf + 4, kParamStoreFormat);
  Put16(buf + 6, static_cast<uint16_t>(count));
  uint8_t* r = buf + kHeader;
  for (uint16_t id = kFirstId; id <= kLastId; ++id, r += kRecord) {
    float v = 0.f;
    if (GetParam(p, id, &v) != FwStatus::kOk) v = 0.f;  // every id in range is known
    uint32_t bits = 0;
    std::memcpy(&bits, &v, sizeof(bits));
    Put16(r, id);
    Put32(r + 2, bits);
  }
  Put32(buf + len - kCrc, Crc32(buf, len - kCrc));
  return len;
}

FwStatus DecodeParamStore(const uint8_t* buf, size_t len, Params* p, int* applied) {
  if (applied != nullptr) *applied = 0;
  if (len == 0) return FwStatus::kUnknown;
  if (len < kHeader + kCrc || Get32(buf) != kParamStoreMagic || Get16(buf + 4) != kParamStoreFormat)
    return FwStatus::kInvalid;
  const size_t count = Get16(buf + 6);
  const size_t need = kHeader + count * kRecord + kCrc;
  if (len < need || Crc32(buf, need - kCrc) != Get32(buf + need - kCrc)) return FwStatus::kInvalid;
  Params out = *p;
  int n = 0;
  for (size_t i = 0; i < count; ++i) {
    const uint8_t* r = buf + kHeader + i * kRecord;
    const uint16_t id = Get16(r);
    const uint32_t bits = Get32(r + 2);
    float v = 0.f;
    std::memcpy(&v, &bits, sizeof(v));
    const FwStatus s = SetParam(&out, id, v);
    if (s == FwStatus::kUnknown || s == FwStatus::kReadOnly) continue;  // a newer firmware's
    if (s != FwStatus::kOk) return FwStatus::kInvalid;
    ++n;
  }
  uint16_t bad = 0;
  if (ValidateParams(out, &bad) != FwStatus::kOk) return FwStatus::kInvalid;
  *p = out;
  if (applied != nullptr) *applied = n;
  return FwStatus::kOk;
}

}  // namespace omni::firmware
