// The RPLidar serial protocol, after Slamtec's rplidar_sdk (sdk/include/sl_lidar_cmd.h and
// sl_lidar_protocol.h): requests `A5 cmd [size payload checksum]`, 7-byte response descriptors
// `A5 5A len(30 bits)|mode(2 bits) type`, 5-byte standard measurement nodes and 84-byte legacy
// express capsules. Angles on the wire are clockwise seen from above, 0 = the sensor's forward.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace omni::rplidar {

inline constexpr uint8_t kSyncByte = 0xA5;
inline constexpr uint8_t kSyncByte2 = 0x5A;

// Commands (sl_lidar_cmd.h).
inline constexpr uint8_t kCmdStop = 0x25;
inline constexpr uint8_t kCmdScan = 0x20;
inline constexpr uint8_t kCmdForceScan = 0x21;
inline constexpr uint8_t kCmdReset = 0x40;
inline constexpr uint8_t kCmdGetInfo = 0x50;
inline constexpr uint8_t kCmdGetHealth = 0x52;
inline constexpr uint8_t kCmdGetSampleRate = 0x59;
inline constexpr uint8_t kCmdExpressScan = 0x82;
inline constexpr uint8_t kCmdSetMotorPwm = 0xF0;
inline constexpr uint8_t kCmdGetAccBoardFlag = 0xFF;

// Answer types of the response descriptor.
inline constexpr uint8_t kAnsDevInfo = 0x04;
inline constexpr uint8_t kAnsDevHealth = 0x06;
inline constexpr uint8_t kAnsMeasurement = 0x81;
inline constexpr uint8_t kAnsMeasurementCapsuled = 0x82;
inline constexpr uint8_t kAnsSampleRate = 0x15;
inline constexpr uint8_t kAnsAccBoardFlag = 0xFF;

inline constexpr uint8_t kModeSingle = 0x0;
inline constexpr uint8_t kModeMulti = 0x1;

inline constexpr uint8_t kHealthGood = 0;
inline constexpr uint8_t kHealthWarning = 1;
inline constexpr uint8_t kHealthError = 2;

inline constexpr size_t kDescriptorSize = 7;
inline constexpr size_t kSampleSize = 5;
inline constexpr size_t kCapsuleSize = 84;
inline constexpr size_t kDevInfoSize = 20;
inline constexpr size_t kHealthSize = 3;
inline constexpr size_t kSampleRateSize = 4;

inline constexpr uint16_t kDefaultMotorPwm = 660;  // DEFAULT_MOTOR_PWM in the SDK

struct Descriptor {
  uint32_t size = 0;  // bytes per answer (per node for multi-answer modes)
  uint8_t mode = 0;   // kModeSingle or kModeMulti
  uint8_t type = 0;   // kAns*
};

struct DeviceInfo {
  uint8_t model = 0;  // major model id in the high nibble: 1 = A1, 2 = A2, 3 = A3, 6 = S1
  uint16_t firmware_version = 0;  // major << 8 | minor
  uint8_t hardware_version = 0;
  std::array<uint8_t, 16> serial_number{};
  int MajorModel() const { return model >> 4; }
  std::string SerialHex() const;
};

struct Health {
  uint8_t status = kHealthGood;
  uint16_t error_code = 0;
};

struct SampleRate {
  uint16_t standard_us = 0;  // time per sample in SCAN mode, microseconds
  uint16_t express_us = 0;   // time per sample in EXPRESS_SCAN mode, microseconds
};

// One decoded measurement. Angles as the lidar reports them: degrees, clockwise.
struct Sample {
  double angle_deg = 0;    // [0, 360)
  double distance_mm = 0;  // 0 = no valid return
  uint8_t quality = 0;     // 0..63
  bool start = false;      // first sample of a new revolution
  int64_t utime = 0;       // host time when the sample's last byte arrived, microseconds
};

// Requests.
std::vector<uint8_t> MakeRequest(uint8_t cmd);
std::vector<uint8_t> MakeRequest(uint8_t cmd, const std::vector<uint8_t>& payload);
std::vector<uint8_t> MakeMotorPwmRequest(uint16_t pwm);
// EXPRESS_SCAN with working mode 0 (legacy capsules).
std::vector<uint8_t> MakeExpressScanRequest();

// Response descriptors.
std::array<uint8_t, kDescriptorSize> EncodeDescriptor(const Descriptor& d);
// `p` points at 7 bytes starting with A5 5A. Returns false when the sync bytes are wrong.
bool DecodeDescriptor(const uint8_t* p, Descriptor* d);

std::vector<uint8_t> EncodeDeviceInfo(const DeviceInfo& info);
DeviceInfo DecodeDeviceInfo(const uint8_t* p);  // kDevInfoSize bytes
std::vector<uint8_t> EncodeHealth(const Health& h);
Health DecodeHealth(const uint8_t* p);  // kHealthSize bytes
std::vector<uint8_t> EncodeSampleRate(const SampleRate& r);
SampleRate DecodeSampleRate(const uint8_t* p);  // kSampleRateSize bytes

// Standard 5-byte nodes.
// True when the start bit S and its complement !S differ and the check bit C is 1.
bool StandardSampleChecksPass(const uint8_t* p);
// Decodes one node without checking it: angle = ((b2 << 7) | (b1 >> 1)) / 64 degrees,
// distance = ((b4 << 8) | b3) / 4 mm, quality = b0 >> 2, start = b0 & 1.
Sample DecodeStandardSample(const uint8_t* p);
std::array<uint8_t, kSampleSize> EncodeStandardSample(double angle_deg, double distance_mm,
                                                      uint8_t quality, bool start);

// Legacy express capsules: 2 sync nibbles (0xA, 0x5) carrying an 8-bit XOR checksum of bytes
// 2..83, a start angle in q6 (bit 15 = first capsule after the scan started), then 16 cabins of
// two distances (q2, low 2 bits = high bits of the angle offset) and two 4-bit angle offsets (q3).
struct Cabin {
  uint16_t distance_angle_1 = 0;
  uint16_t distance_angle_2 = 0;
  uint8_t offset_angles_q3 = 0;
};
struct Capsule {
  uint16_t start_angle_q6 = 0;  // without the start flag
  bool start = false;
  std::array<Cabin, 16> cabins{};
};
// Checks the sync nibbles and the checksum.
bool CapsuleSyncMatches(const uint8_t* p);
bool CapsuleChecksumMatches(const uint8_t* p);
Capsule DecodeCapsule(const uint8_t* p);  // kCapsuleSize bytes, unchecked
std::array<uint8_t, kCapsuleSize> EncodeCapsule(const Capsule& c);
// The 32 samples of `prev`, whose angles run from prev's start angle to `next`'s (the SDK's
// _capsuleToNormal). Revolution starts are where the angle wraps through 0.
void CapsuleToSamples(const Capsule& prev, const Capsule& next, int64_t utime,
                      std::vector<Sample>* out);

}  // namespace omni::rplidar
