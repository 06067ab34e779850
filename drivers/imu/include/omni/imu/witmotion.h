// The WitMotion WT901/JY901 serial protocol ("0x55" frames): 11 bytes each,
//   0x55, type, 4 little-endian int16 values, checksum = (sum of the first 10 bytes) & 0xFF.
// Types: 0x50 time, 0x51 acceleration (±16 g), 0x52 angular rate (±2000 deg/s),
// 0x53 angles (roll, pitch, yaw, ±180 deg), 0x54 magnetometer (raw LSB), 0x59 quaternion.
// The 4th value of 0x51..0x54 is the temperature in 1/100 degrees Celsius.
// Configuration (host to device) is a register write of 5 bytes: 0xFF 0xAA, register, value
// low byte, value high byte; writes take effect after the unlock key (register 0x69 = 0xB588)
// and are kept over a power cycle only after a SAVE (register 0x00 = 0).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace omni::imu {

inline constexpr uint8_t kHeader = 0x55;
inline constexpr size_t kFrameSize = 11;
inline constexpr uint8_t kTypeTime = 0x50;
inline constexpr uint8_t kTypeAccel = 0x51;
inline constexpr uint8_t kTypeGyro = 0x52;
inline constexpr uint8_t kTypeAngle = 0x53;
inline constexpr uint8_t kTypeMag = 0x54;
inline constexpr uint8_t kTypeQuaternion = 0x59;
inline constexpr double kGravity = 9.80665;

// Registers written by the driver (WitMotion's register map).
inline constexpr uint8_t kRegSave = 0x00;     // 0: store the settings in flash
inline constexpr uint8_t kRegOutputs = 0x02;  // RSW: bit (type - 0x50) sends that frame type
inline constexpr uint8_t kRegRate = 0x03;     // RRATE: output rate code (RateCode)
inline constexpr uint8_t kRegBaud = 0x04;     // BAUD: serial rate code (BaudCode)
inline constexpr uint8_t kRegKey = 0x69;      // KEY: kUnlockKey enables writes
inline constexpr uint16_t kUnlockKey = 0xB588;
inline constexpr size_t kWriteSize = 5;

std::array<uint8_t, kWriteSize> EncodeWrite(uint8_t reg, uint16_t value);
// The RRATE code of an output rate (0.2, 0.5, 1, 2, 5, 10, 20, 50, 100, 200 Hz); 0 for any other.
uint8_t RateCode(double hz);
// The rate of a RRATE code; 0 for codes that are not a periodic rate.
double RateOfCode(uint8_t code);
// The BAUD code of a serial rate (4800 ... 921600); 0 for any other.
uint8_t BaudCode(int baud);
int BaudOfCode(uint8_t code);
// The RSW bit of a frame type (0x50 ... 0x5A), 0 for others.
uint16_t OutputBit(uint8_t type);

struct RegisterWrite {
  uint8_t reg = 0;
  uint16_t value = 0;
};

// Device side of the configuration writes (for the emulator): finds 0xFF 0xAA + 3 bytes in a
// byte stream; anything else is skipped and counted.
class WriteParser {
 public:
  void Feed(const uint8_t* data, size_t size, std::vector<RegisterWrite>* out);
  int64_t bytes_skipped() const { return bytes_skipped_; }

 private:
  std::vector<uint8_t> buf_;
  int64_t bytes_skipped_ = 0;
};

struct Frame {
  uint8_t type = 0;
  std::array<int16_t, 4> v{};
  std::array<uint8_t, 8> raw{};  // the 8 payload bytes (0x50 time frames are bytes, not int16)
  // Its bytes had all arrived before the Feed() that returned it: it was held back until the
  // bytes after it came (the driver stamps its sample with the earlier read's time).
  bool held = false;
};

std::array<uint8_t, kFrameSize> EncodeFrame(uint8_t type, const std::array<int16_t, 4>& v);
bool IsKnownType(uint8_t type);

struct FrameCounters {
  int64_t frames = 0;
  int64_t checksum_errors = 0;  // header and type right, checksum wrong, while aligned
  int64_t resyncs = 0;          // times alignment was lost and found again
  int64_t bytes_skipped = 0;
  // Windows that check out but are not followed by a frame: a frame that lost a byte (its
  // other bytes and the next frame's header pass the checksum about once in 256), or a chance
  // match in noise. Dropped, never decoded.
  int64_t unconfirmed = 0;
};

// Streaming frame decoder: finds 0x55 + a known type + a matching checksum; never trusts
// alignment, so garbage costs only the frames it corrupted. A frame is returned only once the
// bytes after it confirm it: the next frame's header and type, or (in sync) line noise with no
// frame starting inside it. The last frame of a read is therefore held until the next read
// (at the device's rate, the closing frame of a period waits for the next period); when the
// stream ends (the port is closed) a held frame is dropped, as it cannot be confirmed.
class FrameParser {
 public:
  void Feed(const uint8_t* data, size_t size, std::vector<Frame>* out);
  void Reset();
  const FrameCounters& counters() const { return counters_; }
  // The type of the frame held back for confirmation, 0 when there is none.
  uint8_t held_type() const;

 private:
  enum class Check { kYes, kNo, kWait };
  bool FrameAt(size_t at) const;
  // Whether the bytes after the window at `at` (which checks out) confirm it as a frame.
  Check Confirm(size_t at) const;
  std::vector<uint8_t> buf_;
  size_t pos_ = 0;
  bool in_sync_ = false;
  bool ever_synced_ = false;
  FrameCounters counters_;
};

// One IMU sample in physical units, in the sensor's frame (x forward, y left, z up).
struct ImuSample {
  std::array<double, 3> accel_m_s2{};
  std::array<double, 3> gyro_rad_s{};
  std::array<double, 3> euler_rad{};  // roll, pitch, yaw
  std::array<double, 4> orientation_wxyz{1, 0, 0, 0};
  bool has_orientation = false;
  std::array<double, 3> mag_raw{};  // magnetometer, sensor LSB
  bool has_mag = false;
  double temperature_c = 0;
  bool has_temperature = false;
};

// Physical units of one frame's values.
double AccelToMs2(int16_t v);
double GyroToRadS(int16_t v);
double AngleToRad(int16_t v);
int16_t Ms2ToAccel(double a);
int16_t RadSToGyro(double w);
int16_t RadToAngle(double a);

// Collects the frames of one output period into a sample. The sensor sends 0x51, 0x52, 0x53
// (0x54, 0x59 if enabled) per period; a sample is complete when the frame of `trigger_type`
// arrives after at least an acceleration and an angular rate.
class SampleAssembler {
 public:
  explicit SampleAssembler(uint8_t trigger_type = kTypeAngle) : trigger_(trigger_type) {}
  // Returns true and fills `out` when `f` completed a sample.
  bool Add(const Frame& f, ImuSample* out);
  int64_t incomplete() const { return incomplete_; }

 private:
  uint8_t trigger_;
  ImuSample cur_;
  bool have_accel_ = false;
  bool have_gyro_ = false;
  bool have_quat_ = false;
  int64_t incomplete_ = 0;
};

// Rotation Rz(yaw) * Ry(pitch) * Rx(roll) as a unit quaternion w, x, y, z.
std::array<double, 4> EulerToQuaternion(double roll, double pitch, double yaw);

// Microseconds a period of `frames` frames takes on the serial line at `baud` (11 bytes a
// frame, 10 bits a byte with start and stop bits): how long before its closing frame arrived
// the period's sample was taken (0 when the baud rate is unknown). 4 frames at the factory
// 9600 baud: 45.8 ms, about 2.6 degrees of heading at 1 rad/s.
inline int64_t SerialLineDelayUs(size_t frames, int baud) {
  if (baud <= 0) return 0;
  return static_cast<int64_t>(frames) * static_cast<int64_t>(kFrameSize) * 10 * 1000000 / baud;
}

}  // namespace omni::imu
