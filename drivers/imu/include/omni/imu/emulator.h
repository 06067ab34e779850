// A software WitMotion WT901 on a pseudo-terminal: streams 0x51 acceleration, 0x52 angular rate,
// 0x53 angles (and optionally 0x54 magnetometer, 0x59 quaternion) frames every period, in the
// device's ascending order, of a simulated motion: a constant tilt and a slow yaw rotation,
// gravity on the tilted z axis. Faults for tests: garbage spliced into a frame, vanish/restore
// (USB unplugged), silence with the port open.
// Configuration: register writes (0xFF 0xAA ...) after the unlock key set the output rate, the
// frames sent and the baud rate; SAVE keeps them over an unplug (a power cycle), which otherwise
// restores the saved ones. With a baud rate set, the line must be at it: at any other speed the
// bytes each way are garbled (no frame can be read, no write understood), as on a real UART.
// Single-threaded: the owner calls Step() in its loop (its own thread or process).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "omni/common/result.h"
#include "omni/imu/witmotion.h"
#include "omni/serial/pty.h"

namespace omni::imu {

struct EmulatorOptions {
  std::string link_path;        // symlink drivers open, e.g. /tmp/imu
  double rate_hz = 100.0;       // output periods per second
  double yaw_rate_rad_s = 0.2;  // slow rotation about the world z axis
  double yaw0_rad = 0.0;        // yaw when streaming starts
  double roll_rad = 0.0;        // constant tilt
  double pitch_rad = 0.0;
  double temperature_c = 25.0;
  bool send_time = false;       // 0x50 frames
  bool send_accel = true;       // 0x51 frames
  bool send_gyro = true;        // 0x52 frames
  bool send_angle = true;       // 0x53 frames
  bool send_mag = true;         // 0x54 frames
  bool send_quaternion = true;  // 0x59 frames
  int baud = 0;                 // the device's serial rate; 0: any line speed is understood
  bool accept_writes = true;    // false: a device that ignores configuration writes
};

// The simulated truth at `t_s` seconds after the stream started.
struct MotionState {
  std::array<double, 3> accel_m_s2{};  // specific force in the body frame (gravity included)
  std::array<double, 3> gyro_rad_s{};  // body-frame angular rate
  std::array<double, 3> euler_rad{};   // roll, pitch, yaw (yaw wrapped to [-pi, pi])
  std::array<double, 4> orientation_wxyz{1, 0, 0, 0};
  std::array<double, 3> mag_raw{};  // magnetometer LSB: a fixed world field seen from the body
};
MotionState SimulatedMotion(const EmulatorOptions& options, double t_s);

// The frames of one period for `m`, in the order the device sends them.
std::vector<uint8_t> EncodePeriod(const EmulatorOptions& options, const MotionState& m);

struct EmulatorCounters {
  int64_t periods = 0;           // periods sent
  int64_t frames = 0;            // frames sent (corrupted ones included)
  int64_t frames_corrupted = 0;  // frames cut by spliced garbage
  int64_t bytes_streamed = 0;
  int64_t bytes_dropped = 0;   // nobody reading: the pty buffer was full
  int64_t writes = 0;          // configuration writes applied
  int64_t writes_ignored = 0;  // locked, unknown register or value, or writes not accepted
  int64_t saves = 0;
  int64_t bytes_garbled = 0;  // sent or received at a line speed that is not the device's
};

class ImuEmulator {
 public:
  static Result<std::unique_ptr<ImuEmulator>> Create(EmulatorOptions options);

  // Streams the periods due by `now_us` (monotonic microseconds). The first call starts the
  // clock of the motion; periods missed while absent or silent are skipped, not sent late.
  void Step(int64_t now_us);
  int fd() const { return pty_ ? pty_->master_fd() : -1; }
  const std::string& path() const { return options_.link_path; }
  const EmulatorOptions& options() const { return options_; }

  // Faults.
  void Vanish();     // close the pty and remove the link (USB unplugged)
  Status Restore();  // a new pty behind the same link (plugged back in)
  bool present() const { return pty_ != nullptr; }
  // `bytes` random bytes spliced into the middle of the next frame, which is then broken for
  // sure (as line noise would); sent at once when not streaming.
  void InjectGarbage(size_t bytes, uint32_t seed);
  // The device stops (or resumes) sending with the port still open.
  void SetStreaming(bool on) { streaming_ = on; }
  bool streaming() const { return streaming_; }
  const EmulatorCounters& counters() const { return counters_; }
  // options() holds the settings in effect (rate, frames sent, baud); saved() those kept over
  // an unplug.
  const EmulatorOptions& saved() const { return saved_; }

 private:
  explicit ImuEmulator(EmulatorOptions o) : options_(std::move(o)) {}
  void Send(const uint8_t* data, size_t size);
  void DrainInput(int64_t now_us);
  void RestartPeriods();
  void Apply(const RegisterWrite& w, int64_t now_us);
  bool LineMatches() const;  // the line is at the device's baud rate (or any is accepted)

  EmulatorOptions options_;
  EmulatorOptions saved_;  // restored when plugged back in
  bool unlocked_ = false;
  int64_t unlocked_until_us_ = 0;
  WriteParser writes_;
  std::unique_ptr<serial::Pty> pty_;
  bool streaming_ = true;
  bool started_ = false;
  int64_t start_us_ = 0;
  int64_t next_period_ = 0;
  bool restart_pending_ = false;  // start_us_ moves to the next Step's time
  double t0_s_ = 0;  // motion time at start_us_ (the period count restarts when the rate changes)
  std::vector<uint8_t> garbage_;  // to splice into the next frame
  uint32_t garbage_seed_ = 0;
  EmulatorCounters counters_;
};

}  // namespace omni::imu
