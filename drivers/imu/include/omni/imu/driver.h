// The WitMotion IMU driver state machine (no bus): open the serial port at the configured baud
// (or try 9600 then 115200), feed the bytes to the 0x55 frame parser, learn the device's frame
// cycle, assemble each output period into one ImuSample and stamp it. A device that vanishes
// (read error, hang-up) or goes quiet for `data_timeout_s` is closed and reopened every
// `reconnect_interval_s` until frames arrive again; the process never has to restart.
#pragma once

#include <array>
#include <cstdint>
#include <map>
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
// Once learned, a new type joins only when it is seen in two consecutive periods (its frame was
// lost while learning): one stray frame that passed the parser (noise) must not join, because
// with trigger auto a type above the last one would become the closing frame and no sample
// would close again.
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
  int prev_ = -1;       // index in types_ of the previous frame, -1 when unknown
  int64_t period_ = 0;  // periods since learned (counted when the type index wraps)
  std::map<uint8_t, int64_t> candidates_;  // types not in the cycle -> period last seen in
};

// The frames of one connection into samples: learns the cycle, closes a sample on the trigger
// frame (a fixed type, or with trigger auto the cycle's last type), from the first type of a
// period on so that a sample never mixes two periods.
class SampleBuilder {
 public:
  explicit SampleBuilder(uint8_t fixed_trigger = 0) : fixed_(fixed_trigger) {}
  // Notes `f` in the cycle (counting frames missing from it); false while the cycle is being
  // learned, and then `f` is not to be assembled.
  bool Learn(const Frame& f);
  // Assembles `f` (after Learn returned true); true with `*out` filled when it closed a sample.
  bool Assemble(const Frame& f, ImuSample* out);
  // Forgets the cycle and the sample being assembled (a new connection, or a re-learn); the
  // counts are kept.
  void Reset();
  const FrameCycle& cycle() const { return cycle_; }
  uint8_t trigger() const { return trigger_; }  // 0 until the cycle is learned
  int64_t dropped_frames() const { return dropped_; }
  int64_t incomplete() const { return past_incomplete_ + assembler_.incomplete(); }

 private:
  uint8_t fixed_;
  FrameCycle cycle_;
  SampleAssembler assembler_;
  uint8_t trigger_ = 0;
  bool aligned_ = false;  // assembling from the first type of a period on
  int64_t dropped_ = 0;
  int64_t past_incomplete_ = 0;  // of assemblers replaced by a new one
};

// Sample times: the read time, with the samples that arrived in one read spread back by the
// output period (at most evenly over the time since the previous stamp), strictly increasing
// across small steps of the clock back (jitter, NTP slewing). A step back of more than
// kClockStepBackUs is a clock that was set back: the stamps follow it (counted), so that
// consumers that detect such a step and re-base (GyroRateHistory) see it, instead of every
// sample for that long being stamped 1 us after the previous one.
class SampleStamper {
 public:
  static constexpr Utime kClockStepBackUs = 1'000'000;
  explicit SampleStamper(double rate_hz)
      : period_us_(rate_hz > 0 ? SecondsToUtime(1.0 / rate_hz) : 0) {}
  // Stamp of sample `i` of `n` completed by the bytes read at `read_utime` (i = 0, 1, .. n-1).
  Utime Stamp(Utime read_utime, size_t i, size_t n);
  int64_t steps_back() const { return steps_back_; }

 private:
  Utime period_us_;
  Utime step_ = 0;  // spacing of the current read's samples
  Utime last_ = 0;
  int64_t steps_back_ = 0;
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
  int64_t cycle_relearns = 0;      // frames came but no sample closed for a while: re-learned
  int64_t clock_steps_back = 0;    // stamps that followed the clock set back by more than 1 s
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
  const FrameCycle& cycle() const { return builder_.cycle(); }
  int baud() const { return port_ ? port_->baud() : 0; }
  // Settings still to be written, or written and not yet confirmed by the stream.
  bool configuring() const { return config_pending_ || config_verifying_; }
  // Samples per second over the last whole 2 s window while streaming; 0 before the first.
  double measured_rate_hz() const { return measured_rate_hz_; }
  // Streaming, but no sample has closed since the frame cycle was last re-learned (the reason
  // is relearn_reason()); the heartbeat is then DEGRADED.
  bool degraded() const { return degraded_; }
  const std::string& relearn_reason() const { return relearn_reason_; }

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
  // Frames keep coming but no sample closes (a stray type joined the cycle while it was learned,
  // a device without gyro frames): learns the cycle again and says so.
  void Relearn(int64_t now_us);

  DriverOptions options_;
  const Clock* clock_;
  std::unique_ptr<serial::SerialPort> port_;
  FrameParser parser_;
  FrameCounters past_;  // parser counters of earlier connections
  SampleBuilder builder_;
  SampleStamper stamper_;
  // The read that completed the frame now held back by the parser: its time, and when that
  // frame closes a sample, how many samples that read completed with it (the group it is
  // stamped in; 0 otherwise).
  Utime held_read_utime_ = 0;
  size_t held_group_ = 0;
  // Samples closing: the last one (monotonic; also reset at each streaming start and by the
  // time spent writing settings), how long without one starts a re-learn (doubled after each
  // re-learn that brought none, so a slow device is never re-learned for ever), and why.
  int64_t last_sample_us_ = 0;
  int64_t no_sample_limit_us_ = 0;
  bool degraded_ = false;
  std::string relearn_reason_;
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
