// Quadrature decoding, x4.
//
// On the board the timers count x4 in hardware (encoder mode, 16 bits) and the firmware
// extends the count: the difference of two 16-bit readings taken as int16 is correct as long
// as fewer than 32768 counts pass between two reads (at 1 kHz that is 32.7 M counts/s), so
// the accumulated 32-bit position is overflow-safe across counter wrap.
//
// QuadratureDecoderX4 decodes raw A/B levels in software (Gray-code state table), for boards
// or tests that sample the pins directly; illegal transitions (both lines changed, i.e. a
// missed state) are counted.
#pragma once

#include <cstdint>

namespace omni::firmware {

// The signed counts from position `from` to position `to` of a wrapping 32-bit position, right as
// long as fewer than 2^31 counts lie between them.
inline int32_t CountsBetween(int32_t from, int32_t to) {
  return static_cast<int32_t>(static_cast<uint32_t>(to) - static_cast<uint32_t>(from));
}

class EncoderCounter {
 public:
  // Takes the first reading as the origin.
  void Reset(uint16_t raw) {
    last_raw_ = raw;
    position_ = 0;
  }
  // Consumes a new raw reading; returns the signed counts since the previous one.
  int32_t Update(uint16_t raw) {
    const int16_t delta = static_cast<int16_t>(static_cast<uint16_t>(raw - last_raw_));
    last_raw_ = raw;
    // Modulo 2^32, so that the position wraps instead of overflowing (undefined behaviour) after
    // 2^31 counts: 74 h of one direction at the reference base's top wheel speed.
    position_ = static_cast<int32_t>(static_cast<uint32_t>(position_) +
                                     static_cast<uint32_t>(static_cast<int32_t>(delta)));
    return delta;
  }
  // Accumulated counts since Reset, modulo 2^32: compare positions with CountsBetween.
  int32_t position() const { return position_; }

 private:
  uint16_t last_raw_ = 0;
  int32_t position_ = 0;
};

class QuadratureDecoderX4 {
 public:
  void Reset(bool a, bool b) {
    state_ = static_cast<uint8_t>((a ? 2 : 0) | (b ? 1 : 0));
    count_ = 0;
    errors_ = 0;
  }
  // Feeds one sample of the A and B lines.
  void Sample(bool a, bool b) {
    const uint8_t next = static_cast<uint8_t>((a ? 2 : 0) | (b ? 1 : 0));
    // Index = previous state << 2 | new state; +1 forward (A leads B), -1 backward, 2 illegal.
    static constexpr int8_t kTable[16] = {0, -1, 1, 2, 1, 0, 2, -1, -1, 2, 0, 1, 2, 1, -1, 0};
    const int8_t step = kTable[(state_ << 2) | next];
    if (step == 2) {
      ++errors_;
    } else {
      count_ += step;
    }
    state_ = next;
  }
  int32_t count() const { return count_; }
  uint32_t errors() const { return errors_; }
  // The counter as a 16-bit timer register would hold it.
  uint16_t raw16() const { return static_cast<uint16_t>(count_); }

 private:
  uint8_t state_ = 0;
  int32_t count_ = 0;
  uint32_t errors_ = 0;
};

}  // namespace omni::firmware
