// The RPLidar driver state machine (no bus): open the port, stop any running scan, read the
// device info and health (health "error" -> RESET and check again), start the motor (PWM
// command on A2/A3/S, DTR on A1 with DTR failure non-fatal), start SCAN / EXPRESS_SCAN /
// FORCE_SCAN and decode revolutions. A device that vanishes (read error, hang-up) or goes quiet
// for `data_timeout_s` is closed and reopened every `reconnect_interval_s` until it answers.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "omni/common/result.h"
#include "omni/common/time.h"
#include "omni/rplidar/parser.h"
#include "omni/rplidar/protocol.h"
#include "omni/rplidar/scan.h"
#include "omni/serial/serial_port.h"

namespace omni {
class ConfigReader;
}  // namespace omni

namespace omni::rplidar {

struct DriverOptions {
  std::string port = "/dev/rplidar";
  int baud = 0;                        // 0: by model (try 256000 for A3, then 115200 for A1/A2)
  std::string model = "auto";          // auto | a1 | a2 | a3 (a1: motor by DTR)
  std::string scan_mode = "standard";  // standard | express | force
  int motor_pwm = kDefaultMotorPwm;    // 0..1023
  double data_timeout_s = 2.0;         // no bytes for this long while scanning -> reconnect
  double reconnect_interval_s = 1.0;
  double response_timeout_s = 0.5;  // answer to GET_INFO / GET_HEALTH / scan start
  double reset_wait_s = 0.5;        // after RESET, before asking the health again
  int resync_lookahead = 4;
  ScanOptions scan;
};

// Reads config/rplidar_driver.yaml's driver keys (the node reads its own).
struct NodeOptions {
  std::string channel = "LIDAR_SCAN";
  std::string frame = "laser";
  double mount_x_m = 0, mount_y_m = 0, mount_yaw_rad = 0;
  std::string bus_url;
};
Status LoadRplidarOptions(const std::string& path, DriverOptions* driver, NodeOptions* node);
// The same from a reader already open (a string in the config fuzz target); Finish()es it.
Status LoadRplidarOptions(ConfigReader& reader, DriverOptions* driver, NodeOptions* node);

struct DriverCounters {
  int64_t revolutions = 0;
  int64_t reconnects = 0;        // successful reconnections after a loss
  int64_t connect_failures = 0;  // attempts that failed
  int64_t timeouts = 0;          // data timeouts while scanning
  int64_t health_resets = 0;     // RESET commands sent because health was "error"
  int64_t dtr_failures = 0;      // DTR ioctl refused (pty, adapter without modem lines)
  int64_t dropped_samples = 0;   // samples of revolutions cut by a reconnect
};

enum class DriverState { kDisconnected, kStreaming };

class RplidarDriver {
 public:
  RplidarDriver(DriverOptions options, const Clock* clock);
  ~RplidarDriver();

  // Opens and starts scanning. The error names the port (absent, not answering, unhealthy).
  Status Connect();
  // Reads for at most `timeout_ms`, appends completed revolutions to `out`, and handles losses:
  // a vanished or silent device is closed and retried at the reconnect interval.
  void Step(int timeout_ms, std::vector<std::vector<Sample>>* out);
  // Stops the scan and the motor (best effort) and closes the port.
  void Shutdown();

  DriverState state() const { return state_; }
  const std::string& status_text() const { return status_; }
  const DeviceInfo& info() const { return info_; }
  const Health& health() const { return health_; }
  const DriverCounters& counters() const { return counters_; }
  const ParserCounters& parser_counters() const { return parser_.counters(); }
  const RevolutionAssembler& assembler() const { return assembler_; }
  const DriverOptions& options() const { return options_; }

 private:
  Status Handshake();
  // Sends `request` and waits for a descriptor of `type`; fills `payload` (single answers) or
  // leaves the bytes after the descriptor in `leftover` (scans).
  Status Transact(const std::vector<uint8_t>& request, uint8_t type, std::vector<uint8_t>* payload,
                  std::vector<uint8_t>* leftover);
  Status StartMotor(int major_model);
  void Lose(const std::string& why);
  void SleepMs(int ms);

  DriverOptions options_;
  const Clock* clock_;
  std::unique_ptr<serial::SerialPort> port_;
  MeasurementParser parser_;
  RevolutionAssembler assembler_;
  DriverState state_ = DriverState::kDisconnected;
  std::string status_ = "starting";
  DeviceInfo info_;
  Health health_;
  DriverCounters counters_;
  int64_t last_data_us_ = 0;     // monotonic
  int64_t next_attempt_us_ = 0;  // monotonic
  bool ever_connected_ = false;
  std::vector<Sample> samples_;
  // Sample stamps: a read returns every sample that came since the one before, all with the
  // read's time; each is put back by the sample period (estimated from reads: time between
  // them over samples in them) from the read's time, the newest at it, so that a revolution's
  // first sample and its length (laser_scan_t's utime and scan_time_s) hold also when the
  // process was held up and one read brings two revolutions.
  double sample_period_us_ = 0;   // 0: not estimated yet
  int64_t last_read_utime_ = -1;  // clock_ time of the last read that brought samples
  int64_t last_stamp_ = -1;       // the last sample's stamp (stamps only go forward)
};

}  // namespace omni::rplidar
