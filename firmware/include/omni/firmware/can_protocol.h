// The CAN protocol between the base controller and the host (docs/firmware.md has the table).
//
// Modelled on ODrive's "CAN Simple": 11-bit id = node_id << 5 | command, every frame carries
// 8 bytes, little-endian. Encoders and decoders are pure functions shared by the firmware
// (float, no heap) and the host base bridge, so both ends cannot disagree.
#pragma once

#include <cstdint>

#include "omni/firmware/hal.h"

namespace omni::firmware::can {

inline constexpr uint8_t kProtocolVersion = 1;
inline constexpr uint8_t kFrameLength = 8;

enum Command : uint8_t {
  kHeartbeat = 0x01,          // fw -> host, every heartbeat_period_ms
  kEstop = 0x02,              // host -> fw
  kClearFaults = 0x03,        // host -> fw
  kSetBodyTwist = 0x04,       // host -> fw
  kSetWheelSpeeds = 0x05,     // host -> fw
  kGetParam = 0x06,           // host -> fw
  kSetParam = 0x07,           // host -> fw
  kParamValue = 0x08,         // fw -> host, reply to get/set
  kEncoderFeedback = 0x09,    // fw -> host, every feedback_period_ms
  kSpeedFeedback = 0x0A,      // fw -> host, every feedback_period_ms
  kCurrentFeedback = 0x0B,    // fw -> host, every feedback_period_ms
  kBodyTwistFeedback = 0x0C,  // fw -> host, every feedback_period_ms
  kSetpointFeedback = 0x0D,   // fw -> host, every heartbeat_period_ms
  kDiagnostics = 0x0E,        // fw -> host, every 10 heartbeats
  kSaveParams = 0x0F,         // host -> fw: store the parameters (or erase the store)
  kParamStoreStatus = 0x10,   // fw -> host, reply to SAVE_PARAMS
  kDiagnostics2 = 0x11,       // fw -> host, every 10 heartbeats (5 after DIAGNOSTICS)
};

inline constexpr uint16_t MakeId(uint8_t node, uint8_t cmd) {
  return static_cast<uint16_t>(((node & 0x3Fu) << 5) | (cmd & 0x1Fu));
}
// What a HAL hands over for a remote (RTR) or extended-id frame: never a command, whatever node
// the firmware is, and counted as unknown (rx_unknown).
inline constexpr uint16_t kForeignFrameId = 0x7FF;
inline constexpr uint8_t NodeOf(uint16_t id) { return static_cast<uint8_t>((id >> 5) & 0x3F); }
inline constexpr uint8_t CommandOf(uint16_t id) { return static_cast<uint8_t>(id & 0x1F); }

// Scalings of the fixed-point fields.
inline constexpr float kLinearScale = 1000.f;   // mm/s per m/s
inline constexpr float kAngularScale = 1000.f;  // mrad/s per rad/s (body yaw rate)
inline constexpr float kWheelScale = 100.f;     // 0.01 rad/s per rad/s (wheel speeds)
inline constexpr float kCurrentScale = 1000.f;  // mA per A
inline constexpr float kVoltageScale = 1000.f;  // mV per V

// A count since boot as a DIAGNOSTICS field: saturates at 65535 instead of wrapping.
inline constexpr uint16_t SaturateCount(uint32_t n) {
  return static_cast<uint16_t>(n > 0xFFFFu ? 0xFFFFu : n);
}

struct Heartbeat {
  uint32_t fault_bits = 0;
  uint8_t state = 0;
  uint8_t counter = 0;        // +1 per heartbeat (wraps)
  float bus_voltage_v = 0.f;  // sent as uint16 mV
};
struct BodyTwist {
  float vx_m_s = 0.f, vy_m_s = 0.f, omega_rad_s = 0.f;  // int16 mm/s, mm/s, mrad/s
  uint16_t seq = 0;
};
struct WheelTriple {  // wheel speeds (int16, 0.01 rad/s) or currents (int16 mA)
  float v[kNumWheels] = {0.f, 0.f, 0.f};
  uint16_t seq = 0;
};
struct EncoderFeedback {
  uint16_t position_low16[kNumWheels] = {0, 0, 0};  // x4 counts mod 2^16
  uint16_t seq = 0;                                 // feedback cycle counter
};

// Feedback cycle numbers run 1, 2, ... 65535 after boot, then wrap to 256, never back into
// 0-255: a number below 256 that does not follow its predecessor is a board that restarted,
// however briefly it was silent and however long it had been up.
inline constexpr uint16_t kFeedbackSeqWrapTo = 256;
inline constexpr uint16_t NextFeedbackSeq(uint16_t s) {
  return s == 0xFFFF ? kFeedbackSeqWrapTo : static_cast<uint16_t>(s + 1);
}
// Cycles from `last` to `seq`: 1 = the next, 0 = the same again, -1 = the board restarted (or the
// number went back more than half the ring).
inline constexpr int32_t FeedbackSeqStep(uint16_t last, uint16_t seq) {
  if (seq == last) return 0;
  if (seq < kFeedbackSeqWrapTo) return last < seq ? seq - last : -1;
  if (last < kFeedbackSeqWrapTo) return seq - last;
  constexpr int32_t kRing = 0x10000 - kFeedbackSeqWrapTo;
  const int32_t d = ((static_cast<int32_t>(seq) - last) % kRing + kRing) % kRing;
  return d >= kRing / 2 ? -1 : d;
}
struct ParamRequest {
  uint16_t id = 0;
  float value = 0.f;  // SET_PARAM only
};
enum ParamResult : uint8_t {
  kParamOk = 0,
  kParamUnknown = 1,
  kParamOutOfRange = 2,
  kParamReadOnly = 3
};
struct ParamReply {
  uint16_t id = 0;
  uint8_t result = kParamOk;
  // 1: the answer to a SET_PARAM, 0: to a GET_PARAM (byte 3). A tool setting a parameter must
  // not take the answer to someone else's GET of the same id (the bridge asks for the geometry
  // every second) as its own: that read "ok, old value" for a refused set.
  uint8_t of_set = 0;
  float value = 0.f;
};
// SAVE_PARAMS: what to do with the non-volatile parameter store (param_store.h). Refused
// unless the motors are off (IDLE, FAULT or ESTOP): writing flash stalls the control loop.
enum ParamStoreAction : uint8_t {
  kStoreSave = 0,   // write every writable parameter; applied at the next boot
  kStoreErase = 1,  // empty the store: the next boot uses the compiled defaults
  kStoreQuery = 2,  // only report (PARAM_STORE_STATUS)
};
enum ParamStoreResult : uint8_t {
  kStoreOk = 0,
  kStoreRefusedMoving = 1,  // the motors are not off
  kStoreWriteFailed = 2,    // the HAL's write failed (or read back differently)
  kStoreUnavailable = 3,    // the board has no parameter store
  kStoreBadAction = 4,
};
struct ParamStoreStatus {
  uint8_t action = kStoreQuery;  // the request answered
  uint8_t result = kStoreOk;
  uint8_t boot_state = 0;  // ParamStoreState found at boot
  uint8_t stored = 0;      // parameters in the store now (0: empty)
  uint32_t crc = 0;        // CRC-32 of the stored record (0: empty)
};

// Counts since boot; each field stops at 65535 (read it as "at least").
struct Diagnostics {
  uint16_t rx_unknown = 0;     // frames for this node with an unknown command
  uint16_t rx_bad_length = 0;  // frames for this node with a wrong DLC
  uint16_t tx_dropped = 0;     // frames not sent (mailboxes full / bus-off)
  uint16_t max_step_us = 0;    // longest control step since boot, microseconds
};
// The second diagnostics frame (DIAGNOSTICS did not have room): counts since boot, each
// stopping at 65535.
struct Diagnostics2 {
  uint16_t watchdog_trips = 0;    // stops because motion commands stopped coming
  uint16_t commands_limited = 0;  // motion commands scaled down to max_wheel_speed
  uint16_t rx_overruns = 0;       // receive-FIFO overruns: frames the controller had to drop
  uint16_t reserved = 0;          // sent as 0
};

// Encoders fill id, dlc = 8 and the payload. Values are saturated to the field range.
CanFrame EncodeHeartbeat(uint8_t node, const Heartbeat& m);
CanFrame EncodeEstop(uint8_t node);
CanFrame EncodeClearFaults(uint8_t node);
CanFrame EncodeSetBodyTwist(uint8_t node, const BodyTwist& m);
CanFrame EncodeSetWheelSpeeds(uint8_t node, const WheelTriple& m);
CanFrame EncodeGetParam(uint8_t node, uint16_t param_id);
CanFrame EncodeSetParam(uint8_t node, const ParamRequest& m);
CanFrame EncodeParamValue(uint8_t node, const ParamReply& m);
CanFrame EncodeEncoderFeedback(uint8_t node, const EncoderFeedback& m);
CanFrame EncodeSpeedFeedback(uint8_t node, const WheelTriple& m);
CanFrame EncodeCurrentFeedback(uint8_t node, const WheelTriple& m);
CanFrame EncodeBodyTwistFeedback(uint8_t node, const BodyTwist& m);
CanFrame EncodeSetpointFeedback(uint8_t node, const WheelTriple& m);
CanFrame EncodeDiagnostics(uint8_t node, const Diagnostics& m);
CanFrame EncodeDiagnostics2(uint8_t node, const Diagnostics2& m);
CanFrame EncodeSaveParams(uint8_t node, uint8_t action);
CanFrame EncodeParamStoreStatus(uint8_t node, const ParamStoreStatus& m);

// Decoders check the DLC (must be 8) and return false on a wrong length; the command must
// already have been matched by the caller from the id.
[[nodiscard]] bool DecodeHeartbeat(const CanFrame& f, Heartbeat* m);
[[nodiscard]] bool DecodeBodyTwist(const CanFrame& f, BodyTwist* m);      // set or feedback
[[nodiscard]] bool DecodeWheelSpeeds(const CanFrame& f, WheelTriple* m);  // 0.01 rad/s fields
[[nodiscard]] bool DecodeCurrents(const CanFrame& f, WheelTriple* m);     // mA fields
[[nodiscard]] bool DecodeEncoderFeedback(const CanFrame& f, EncoderFeedback* m);
[[nodiscard]] bool DecodeParamRequest(const CanFrame& f, ParamRequest* m);  // get or set
[[nodiscard]] bool DecodeParamReply(const CanFrame& f, ParamReply* m);
[[nodiscard]] bool DecodeDiagnostics(const CanFrame& f, Diagnostics* m);
[[nodiscard]] bool DecodeDiagnostics2(const CanFrame& f, Diagnostics2* m);
[[nodiscard]] bool DecodeSaveParams(const CanFrame& f, uint8_t* action);
[[nodiscard]] bool DecodeParamStoreStatus(const CanFrame& f, ParamStoreStatus* m);
[[nodiscard]] bool CheckLength(const CanFrame& f);

}  // namespace omni::firmware::can
