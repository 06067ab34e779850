#include "omni/firmware/can_protocol.h"

#include <cstring>

namespace omni::firmware::can {
namespace {

void PutU16(uint8_t* d, uint16_t v) {
  d[0] = static_cast<uint8_t>(v & 0xFF);
  d[1] = static_cast<uint8_t>(v >> 8);
}
void PutU32(uint8_t* d, uint32_t v) {
  for (int i = 0; i < 4; ++i) d[i] = static_cast<uint8_t>((v >> (8 * i)) & 0xFF);
}
void PutF32(uint8_t* d, float v) {
  uint32_t u;
  std::memcpy(&u, &v, sizeof(u));
  PutU32(d, u);
}
uint16_t GetU16(const uint8_t* d) { return static_cast<uint16_t>(d[0] | (d[1] << 8)); }
int16_t GetI16(const uint8_t* d) { return static_cast<int16_t>(GetU16(d)); }
uint32_t GetU32(const uint8_t* d) {
  return static_cast<uint32_t>(d[0]) | (static_cast<uint32_t>(d[1]) << 8) |
         (static_cast<uint32_t>(d[2]) << 16) | (static_cast<uint32_t>(d[3]) << 24);
}
float GetF32(const uint8_t* d) {
  const uint32_t u = GetU32(d);
  float v;
  std::memcpy(&v, &u, sizeof(v));
  return v;
}

// Rounds to the nearest integer and saturates to int16; NaN becomes 0.
int16_t SatI16(float v) {
  if (!(v == v)) return 0;
  if (v >= 32767.f) return 32767;
  if (v <= -32768.f) return -32768;
  return static_cast<int16_t>(v >= 0.f ? v + 0.5f : v - 0.5f);
}
uint16_t SatU16(float v) {
  if (!(v == v) || v <= 0.f) return 0;
  if (v >= 65535.f) return 65535;
  return static_cast<uint16_t>(v + 0.5f);
}

CanFrame Make(uint8_t node, uint8_t cmd) {
  CanFrame f;
  f.id = MakeId(node, cmd);
  f.dlc = kFrameLength;
  return f;
}

CanFrame EncodeTriple(uint8_t node, uint8_t cmd, const WheelTriple& m, float scale) {
  CanFrame f = Make(node, cmd);
  for (int i = 0; i < kNumWheels; ++i)
    PutU16(&f.data[2 * i], static_cast<uint16_t>(SatI16(m.v[i] * scale)));
  PutU16(&f.data[6], m.seq);
  return f;
}
bool DecodeTriple(const CanFrame& f, WheelTriple* m, float scale) {
  if (!CheckLength(f)) return false;
  for (int i = 0; i < kNumWheels; ++i) m->v[i] = static_cast<float>(GetI16(&f.data[2 * i])) / scale;
  m->seq = GetU16(&f.data[6]);
  return true;
}

CanFrame EncodeTwist(uint8_t node, uint8_t cmd, const BodyTwist& m) {
  CanFrame f = Make(node, cmd);
  PutU16(&f.data[0], static_cast<uint16_t>(SatI16(m.vx_m_s * kLinearScale)));
  PutU16(&f.data[2], static_cast<uint16_t>(SatI16(m.vy_m_s * kLinearScale)));
  PutU16(&f.data[4], static_cast<uint16_t>(SatI16(m.omega_rad_s * kAngularScale)));
  PutU16(&f.data[6], m.seq);
  return f;
}

}  // namespace

bool CheckLength(const CanFrame& f) { return f.dlc == kFrameLength; }

CanFrame EncodeHeartbeat(uint8_t node, const Heartbeat& m) {
  CanFrame f = Make(node, kHeartbeat);
  PutU32(&f.data[0], m.fault_bits);
  f.data[4] = m.state;
  f.data[5] = m.counter;
  PutU16(&f.data[6], SatU16(m.bus_voltage_v * kVoltageScale));
  return f;
}
CanFrame EncodeEstop(uint8_t node) { return Make(node, kEstop); }
CanFrame EncodeClearFaults(uint8_t node) { return Make(node, kClearFaults); }
CanFrame EncodeSetBodyTwist(uint8_t node, const BodyTwist& m) {
  return EncodeTwist(node, kSetBodyTwist, m);
}
CanFrame EncodeSetWheelSpeeds(uint8_t node, const WheelTriple& m) {
  return EncodeTriple(node, kSetWheelSpeeds, m, kWheelScale);
}
CanFrame EncodeGetParam(uint8_t node, uint16_t param_id) {
  CanFrame f = Make(node, kGetParam);
  PutU16(&f.data[0], param_id);
  return f;
}
CanFrame EncodeSetParam(uint8_t node, const ParamRequest& m) {
  CanFrame f = Make(node, kSetParam);
  PutU16(&f.data[0], m.id);
  PutF32(&f.data[4], m.value);
  return f;
}
CanFrame EncodeParamValue(uint8_t node, const ParamReply& m) {
  CanFrame f = Make(node, kParamValue);
  PutU16(&f.data[0], m.id);
  f.data[2] = m.result;
  f.data[3] = m.of_set;
  PutF32(&f.data[4], m.value);
  return f;
}
CanFrame EncodeEncoderFeedback(uint8_t node, const EncoderFeedback& m) {
  CanFrame f = Make(node, kEncoderFeedback);
  for (int i = 0; i < kNumWheels; ++i) PutU16(&f.data[2 * i], m.position_low16[i]);
  PutU16(&f.data[6], m.seq);
  return f;
}
CanFrame EncodeSpeedFeedback(uint8_t node, const WheelTriple& m) {
  return EncodeTriple(node, kSpeedFeedback, m, kWheelScale);
}
CanFrame EncodeCurrentFeedback(uint8_t node, const WheelTriple& m) {
  return EncodeTriple(node, kCurrentFeedback, m, kCurrentScale);
}
CanFrame EncodeBodyTwistFeedback(uint8_t node, const BodyTwist& m) {
  return EncodeTwist(node, kBodyTwistFeedback, m);
}
CanFrame EncodeSetpointFeedback(uint8_t node, const WheelTriple& m) {
  return EncodeTriple(node, kSetpointFeedback, m, kWheelScale);
}
CanFrame EncodeDiagnostics(uint8_t node, const Diagnostics& m) {
  CanFrame f = Make(node, kDiagnostics);
  PutU16(&f.data[0], m.rx_unknown);
  PutU16(&f.data[2], m.rx_bad_length);
  PutU16(&f.data[4], m.tx_dropped);
  PutU16(&f.data[6], m.max_step_us);
  return f;
}
CanFrame EncodeDiagnostics2(uint8_t node, const Diagnostics2& m) {
  CanFrame f = Make(node, kDiagnostics2);
  PutU16(&f.data[0], m.watchdog_trips);
  PutU16(&f.data[2], m.commands_limited);
  PutU16(&f.data[4], m.rx_overruns);
  PutU16(&f.data[6], m.reserved);
  return f;
}

bool DecodeHeartbeat(const CanFrame& f, Heartbeat* m) {
  if (!CheckLength(f)) return false;
  m->fault_bits = GetU32(&f.data[0]);
  m->state = f.data[4];
  m->counter = f.data[5];
  m->bus_voltage_v = static_cast<float>(GetU16(&f.data[6])) / kVoltageScale;
  return true;
}
bool DecodeBodyTwist(const CanFrame& f, BodyTwist* m) {
  if (!CheckLength(f)) return false;
  m->vx_m_s = static_cast<float>(GetI16(&f.data[0])) / kLinearScale;
  m->vy_m_s = static_cast<float>(GetI16(&f.data[2])) / kLinearScale;
  m->omega_rad_s = static_cast<float>(GetI16(&f.data[4])) / kAngularScale;
  m->seq = GetU16(&f.data[6]);
  return true;
}
bool DecodeWheelSpeeds(const CanFrame& f, WheelTriple* m) {
  return DecodeTriple(f, m, kWheelScale);
}
bool DecodeCurrents(const CanFrame& f, WheelTriple* m) { return DecodeTriple(f, m, kCurrentScale); }
bool DecodeEncoderFeedback(const CanFrame& f, EncoderFeedback* m) {
  if (!CheckLength(f)) return false;
  for (int i = 0; i < kNumWheels; ++i) m->position_low16[i] = GetU16(&f.data[2 * i]);
  m->seq = GetU16(&f.data[6]);
  return true;
}
bool DecodeParamRequest(const CanFrame& f, ParamRequest* m) {
  if (!CheckLength(f)) return false;
  m->id = GetU16(&f.data[0]);
  m->value = GetF32(&f.data[4]);
  return true;
}
bool DecodeParamReply(const CanFrame& f, ParamReply* m) {
  if (!CheckLength(f)) return false;
  m->id = GetU16(&f.data[0]);
  m->result = f.data[2];
  m->of_set = f.data[3] != 0 ? 1 : 0;
  m->value = GetF32(&f.data[4]);
  return true;
}
CanFrame EncodeSaveParams(uint8_t node, uint8_t action) {
  CanFrame f = Make(node, kSaveParams);
  f.data[0] = action;
  return f;
}
CanFrame EncodeParamStoreStatus(uint8_t node, const ParamStoreStatus& m) {
  CanFrame f = Make(node, kParamStoreStatus);
  f.data[0] = m.action;
  f.data[1] = m.result;
  f.data[2] = m.boot_state;
  f.data[3] = m.stored;
  PutU32(&f.data[4], m.crc);
  return f;
}
bool DecodeSaveParams(const CanFrame& f, uint8_t* action) {
  if (!CheckLength(f)) return false;
  *action = f.data[0];
  return true;
}
bool DecodeParamStoreStatus(const CanFrame& f, ParamStoreStatus* m) {
  if (!CheckLength(f)) return false;
  m->action = f.data[0];
  m->result = f.data[1];
  m->boot_state = f.data[2];
  m->stored = f.data[3];
  m->crc = GetU32(&f.data[4]);
  return true;
}
bool DecodeDiagnostics2(const CanFrame& f, Diagnostics2* m) {
  if (!CheckLength(f)) return false;
  m->watchdog_trips = GetU16(&f.data[0]);
  m->commands_limited = GetU16(&f.data[2]);
  m->rx_overruns = GetU16(&f.data[4]);
  m->reserved = GetU16(&f.data[6]);
  return true;
}
bool DecodeDiagnostics(const CanFrame& f, Diagnostics* m) {
  if (!CheckLength(f)) return false;
  m->rx_unknown = GetU16(&f.data[0]);
  m->rx_bad_length = GetU16(&f.data[2]);
  m->tx_dropped = GetU16(&f.data[4]);
  m->max_step_us = GetU16(&f.data[6]);
  return true;
}

}  // namespace omni::firmware::can
