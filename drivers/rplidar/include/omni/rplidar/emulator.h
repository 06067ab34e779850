// A software RPLidar on a pseudo-terminal: answers GET_INFO, GET_HEALTH, GET_SAMPLERATE,
// GET_ACC_BOARD_FLAG, SET_MOTOR_PWM, SCAN, FORCE_SCAN, EXPRESS_SCAN (legacy capsules), STOP and
// RESET like the real device, and streams measurements at the real rate from a range function
// (a simulated room) or a raw capture file. Faults for tests: garbage, vanish/restore, health.
// Single-threaded: the owner calls Step() in its loop (its own thread or process).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "omni/common/result.h"
#include "omni/rplidar/protocol.h"
#include "omni/serial/pty.h"

namespace omni::rplidar {

struct EmulatorOptions {
  std::string link_path;         // symlink drivers open, e.g. /tmp/rplidar
  int model = 0x31;              // device-info model byte (major in the high nibble: 3 = A3)
  double scan_hz = 10.0;         // revolutions per second
  int standard_sample_us = 250;  // SCAN: 4000 samples/s
  int express_sample_us = 125;   // EXPRESS_SCAN: 8000 samples/s
  // Range in millimetres (0 = no return) at a clockwise angle in degrees; default: a room.
  std::function<double(double angle_cw_deg)> range_mm;
  std::vector<uint8_t> capture;  // if set, SCAN streams these raw 5-byte nodes in a loop
};

struct EmulatorCounters {
  int64_t commands = 0;
  int64_t bad_requests = 0;  // request checksum wrong
  int64_t resets = 0;
  int64_t scans_started = 0;
  int64_t bytes_streamed = 0;
  int64_t bytes_dropped = 0;  // nobody reading: the pty buffer was full
};

// The default scene: a 6 m x 4 m room, the lidar at (0.7, 0.4) m from its centre, yaw 0.
double RoomRangeMm(double angle_cw_deg);

class RplidarEmulator {
 public:
  static Result<std::unique_ptr<RplidarEmulator>> Create(EmulatorOptions options);

  // Handles pending commands and streams the samples due by `now_us` (monotonic microseconds).
  void Step(int64_t now_us);
  int fd() const { return pty_ ? pty_->master_fd() : -1; }
  const std::string& path() const { return options_.link_path; }

  // Faults.
  void Vanish();     // close the pty and remove the link (USB unplugged)
  Status Restore();  // a new pty behind the same link (plugged back in)
  bool present() const { return pty_ != nullptr; }
  void InjectGarbage(size_t bytes, uint32_t seed);
  // The device goes quiet (as after a brown-out) with the port still open.
  void StopStreaming() { scanning_ = false; }
  void SetHealth(uint8_t status, uint16_t code = 0) { health_ = {status, code}; }
  bool scanning() const { return scanning_; }
  uint16_t motor_pwm() const { return motor_pwm_; }
  const EmulatorCounters& counters() const { return counters_; }

 private:
  explicit RplidarEmulator(EmulatorOptions o) : options_(std::move(o)) {}
  void HandleInput();
  void HandleCommand(uint8_t cmd, const std::vector<uint8_t>& payload);
  void Send(const uint8_t* data, size_t size);
  void Send(const std::vector<uint8_t>& b) { Send(b.data(), b.size()); }
  void StreamDue(int64_t now_us);

  EmulatorOptions options_;
  std::unique_ptr<serial::Pty> pty_;
  std::vector<uint8_t> in_;
  Health health_;
  bool scanning_ = false;
  bool express_ = false;
  bool first_capsule_ = false;
  uint16_t motor_pwm_ = 0;
  int64_t scan_start_us_ = 0;
  int64_t emitted_ = 0;  // samples (standard) or capsules (express) since the scan started
  int64_t now_us_ = 0;
  size_t capture_pos_ = 0;
  EmulatorCounters counters_;
};

}  // namespace omni::rplidar
