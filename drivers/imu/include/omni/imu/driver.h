// The WitMotion IMU driver state machine (no bus): open the serial port at the configured baud
// (or try 9600 then 115200), feed the bytes to the 0x55 frame parser, learn the device's frame
// cycle, assemble each output period into one ImuSample and stamp it. A device that vanishes
// (read error, hang-up) or goes quiet for `data_timeout_s` is closed and reopened every
// `reconnect_interval_s` until frames arrive again; the process never has to restart.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "omni/common/result.h"
#include "omni/common/time.h"
#include "omni/imu/witmotion.h"
#include "omni/serial/serial_port.h"

namespace omni {
class ConfigReader;
}  // namespace omni

namespace omni::imu {

// Settings written into the device at each connection (WitMotion register writes), so a
// factory-set WT901 (9600 baud, 10 Hz) needs no vendor tool.
struct ConfigureOptions {
  bool enabled = false;          // write rate_hz (and what is set below) at each connection
  int baud = 0;                  // switch the device and the port to this rate; 0: leave it
  std::vector<uint8_t> outputs;  // frame types the device sends (0x51 ...); empty: leave them
  bool save = false;             // also store the settings in the device's flash
  int command_gap_ms = 50;       // pause after each write (the device applies them in turn)
  int max_attempts = 3;          // consecutive tries before streaming as the device is set
};

struct DriverOptions {
  std::string port = "/dev/imu";
  int baud = 9600;               // 0: try 9600, then 115200 (the two usual WitMotion settings)
  std::string trigger = "auto";  // frame that closes a sample: auto | accel | gyro | angle |
                                 // mag | quaternion (auto: the last type of the learned cycle)
  double rate_hz = 10.0;         // the device's output rate (factory 10 Hz; spaces the stamps)
  double data_timeout_s = 1.0;   // no frame for this long while streaming -> reconnect
  double reconnect_interval_s = 1.0;
  ConfigureOptions configure;
};

// Bus-side options, read from the same file (config/imu_driver.yaml).
struct NodeOptions {
  std::string channel = "IMU";
  std::string frame = "imu";
  std::string bus_url;
  // Diagonal variances (about/along x, y, z) copied into the message's covariance matrices.
  std::array<double, 3> orientation_var{7.6e-5, 7.6e-5, 1.2e-3};    // rad^2
  std::array<double, 3> angular_velocity_var{1e-6, 1e-6, 1e-6};     // (rad/s)^2
  std::array<double, 3> linear_acceleration_var{4e-4, 4e-4, 4e-4};  // (m/s^2)^2
  double mag_tesla_per_lsb = 0;  // 0: magnetometer not published (NaN)
};

Status LoadImuOptions(const std::string& path, DriverOptions* driver, NodeOptions* node);
// The same from a reader already open (a string in the config fuzz target); Finish()es it.
Status LoadImuOptions(ConfigReader& reader, DriverOptions* driver, NodeOptions* node);

// The frame type named in the config ("accel" -> 0x51, ...); 0 for "auto" or an unknown name.
uint8_t TriggerType(const std::string& name);
// Why `rate_hz` cannot be carried by the line the device is set to (configure.baud, else baud)
// with the frames it sends; "" when it can or the baud rate is unknown (baud 0).
std::string RateBeyondLine(const DriverOptions& d);

// As TriggerType, plus "time" (0x50), for configure.outputs.
uint8_t OutputType(const std::string& name);

// The WT901 sends its output registers in ascending type order every period (0x50 time, 0x51,
// 0x52, 0x53, 0x54, ..., 0x59 quaternion; which ones is configurable on the device). This learns
// the cycle from the stream (the types seen until one repeats) and counts frames missing from it.
class FrameCycle {
 public:
  // Notes a decoded frame; returns how many frames of the cycle were missing before it.
  int Add(uint8_t type);
  // Forgets the cycle and the position (a new connection may be a differently set device).
  void Reset();
  bool learned() const { return learned_; }
  // The types of one period, ascending; the last one closes a period.
  const std::vector<uint8_t>& types() const { return types_; }
  uint8_t last_type() const { return types_.empty() ? 0 : types_.back(); }

 private:
  int IndexOf(uint8_t type) const;
  std::vector<uint8_t> types_;
  bool learned_ = false;
  int prev_ = -1;  // index in types_ of the previous frame, -1 when unknown
};

// Sample times: the read time, with the samples that arrived in one read spread back by the
// output period (at most evenly over the time since the previous stamp), strictly increasing.
class SampleStamper {
 public:
  explicit SampleStamper(double rate_hz)
      : period_us_(rate_hz > 0 ? SecondsToUtime(1.0 / rate_hz) : 0) {}
  // Stamp of sample `i` of `n` completed by the bytes read at `read_utime` (i = 0, 1, .. n-1).
  Utime Stamp(Utime read_utime, size_t i, size_t n);

 private:
  Utime period_us_;
  Utime step_ = 0;  // spacing of the current read's samples
  Utime last_ = 0;
};

struct StampedSample {
  Utime utime = 0;
  ImuSample sample;
};

struct DriverCounters {
  int64_t samples = 0;
  int64_t reconnects = 0;          // successful reconnections after a loss
  int64_t connect_failures = 0;    // open attempts that failed or saw no frame in time
  int64_t timeouts = 0;            // data timeouts while streaming
  int64_t dropped_frames = 0;      // frames missing from the device's cycle (noise, overflow)
  int64_t incomplete_samples = 0;  // periods closed without acceleration or angular rate
  int64_t configurations = 0;      // settings written and confirmed by the device's stream
  int64_t config_failures = 0;     // written, but no frames or other frame types came back
  int64_t rate_mismatches = 0;     // connections whose measured rate is > 20 % off rate_hz
};

enum class DriverState { kDisconnected, kOpening, kStreaming };

class ImuDriver {
 public:
  ImuDriver(DriverOptions options, const Clock* clock);
  ~ImuDriver();

  // Opens the port and waits (up to data_timeout_s per baud) for the first valid frame. The
  // error names the port (absent, no frames at the tried baud rates).
  Status Connect();
  // Reads for at most `timeout_ms` and appends completed samples to `out`; handles losses: a
  // vanished or silent device is closed and retried every reconnect_interval_s.
  void Step(int timeout_ms, std::vector<StampedSample>* out);
  void Shutdown();

  DriverState state() const { return state_; }
  const std::string& status_text() const { return status_; }
  const DriverCounters& counters() const { return counters_; }
  // Parser counters over all connections (frames, checksum errors, resyncs, bytes skipped).
  FrameCounters frame_counters() const;
  const DriverOptions& options() const { return options_; }
  const FrameCycle& cycle() const { return cycle_; }
  int baud() const { return port_ ? port_->baud() : 0; }
  // Settings still to be written, or written and not yet confirmed by the stream.
  bool configuring() const { return config_pending_ || config_verifying_; }
  // Samples per second over the last whole 2 s window while streaming; 0 before the first.
  double measured_rate_hz() const { return measured_rate_hz_; }

 private:
  Status Open();
  void Lose(const std::string& why);
  void FailOpening(const std::string& why);
  void Feed(const uint8_t* data, size_t size, std::vector<StampedSample>* out);
  std::vector<int> Bauds() const;
  // Writes the configured settings, switches the port's baud and waits for frames again.
  void Configure();
  // Checks the learned cycle against the configured outputs once after a configuration;
  // false when it wrote the settings again (the frames of this read are then stale).
  bool VerifyConfiguration();
  bool Write(uint8_t reg, uint16_t value);  // one register write and the gap after it
  void ResetStream();
  void MeasureRate(size_t samples);

  DriverOptions options_;
  const Clock* clock_;
  std::unique_ptr<serial::SerialPort> port_;
  FrameParser parser_;
  FrameCounters past_;  // parser counters of earlier connections
  std::unique_ptr<SampleAssembler> assembler_;
  int64_t past_incomplete_ = 0;  // of assemblers replaced by a new one
  uint8_t trigger_ = 0;
  bool aligned_ = false;  // assembling from the first type of a period on
  FrameCycle cycle_;
  SampleStamper stamper_;
  DriverState state_ = DriverState::kDisconnected;
  std::string status_ = "starting";
  DriverCounters counters_;
  size_t baud_index_ = 0;
  int64_t opened_us_ = 0;        // monotonic
  int64_t last_data_us_ = 0;     // monotonic
  int64_t next_attempt_us_ = 0;  // monotonic
  int64_t bytes_since_open_ = 0;
  bool ever_connected_ = false;
  // Configuration state: pending at the first connection and after each loss of the device.
  bool config_pending_ = false;
  bool config_verifying_ = false;    // written; waiting for the new stream to confirm it
  int config_attempts_ = 0;          // consecutive unconfirmed attempts
  bool reopened_by_config_ = false;  // the next streaming start is not a reconnection
  bool save_after_verify_ = false;   // SAVE once the stream has confirmed the settings
  bool saved_ = false;               // saved in this process: not written to flash again
  // Rate measurement.
  int64_t rate_window_start_us_ = 0;  // monotonic; 0: restart at the next sample
  int64_t rate_window_samples_ = 0;
  bool rate_checked_ = false;  // the first window of this connection was compared
  double measured_rate_hz_ = 0;
  std::vector<Frame> frames_;
  std::vector<StampedSample> pending_;  // completed while Connect() waited for the first frame
};

}  // namespace omni::imu
