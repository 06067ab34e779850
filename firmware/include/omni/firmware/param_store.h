// Parameters kept across power cycles. SAVE_PARAMS (over CAN, motors off) writes every writable
// parameter to one small non-volatile area the HAL provides (a flash sector on the STM32, a
// file or memory on the host); Init() reads it back, so tuned gains and the geometry survive a
// reboot. The record:
//
//   magic u32 "OMP1" | format u16 (1) | count u16 | count x (id u16, value f32) | CRC-32 u32
//
// little-endian; the CRC (IEEE 802.3, as zlib's crc32) covers everything before it. A record
// whose magic, format, length or CRC is wrong, or that holds a value SetParam refuses, is not
// applied: the firmware boots with its compiled defaults and says so (ParamStoreState).
#pragma once

#include <cstdint>
#include <cstring>  // size_t (the MCU build has no <cstddef>)

#include "omni/firmware/params.h"
#include "omni/firmware/status.h"

namespace omni::firmware {

inline constexpr uint32_t kParamStoreMagic = 0x31504D4Fu;  // "OMP1" in memory order
inline constexpr uint16_t kParamStoreFormat = 1;
inline constexpr size_t kParamStoreMaxBytes = 256;

// What Init() found in the store (sent in PARAM_STORE_STATUS).
enum class ParamStoreState : uint8_t {
  kEmpty = 0,    // nothing stored (or erased): compiled defaults
  kLoaded = 1,   // a valid record was applied
  kCorrupt = 2,  // a record was there but is not valid: compiled defaults
  kNoStore = 3,  // the board has no parameter store
};

uint32_t Crc32(const uint8_t* data, size_t len);

// Writes `p`'s writable parameters as a record into buf; returns its length (0 if cap is too
// small).
size_t EncodeParamStore(const Params& p, uint8_t* buf, size_t cap);

// Applies a record to *p (every value through SetParam, then ValidateParams on the result);
// on any error *p is unchanged. Ids this firmware does not know are skipped (a record written
// by a newer firmware still loads); kInvalid for a bad record, kUnknown when len is 0.
[[nodiscard]] FwStatus DecodeParamStore(const uint8_t* buf, size_t len, Params* p,
                                        int* applied = nullptr);

}  // namespace omni::firmware
