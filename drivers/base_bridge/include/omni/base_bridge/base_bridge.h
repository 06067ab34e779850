// The base bridge: host side of the base controller's CAN link. No LCM in here (the node
// does the bus I/O); time is passed in, so tests drive it frame by frame.
//
// Commands (twist, e-stop, clear faults) go in through OnCommand(); Tick() turns the latest
// twist into a SET_BODY_TWIST frame at a fixed rate, after clamping it to the configured
// speed limits (counted) and ramping it to the acceleration limits. Frames from the firmware
// go in through OnFrame(): encoder positions are integrated into a pose with the forward
// kinematics (eq. (1) inverted, eq. (2)), heartbeats and sequence numbers are watched, so a
// silent firmware, lost feedback and malformed frames are detected and counted.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "omni/base_bridge/slip_monitor.h"
#include "omni/common/kinematics.h"
#include "omni/common/result.h"
#include "omni/firmware/can_protocol.h"
#include "omni/firmware/hal.h"

namespace omni::base_bridge {

struct BaseBridgeOptions {
  std::string can_url = "socketcan:can0";
  int node_id = 1;
  // Geometry: must match the firmware (checked at connect through GET_PARAM).
  double alpha_rad = 2.0943951023931954923;
  double center_to_wheel_m = 0.15;
  double wheel_radius_m = 0.05;
  double ticks_per_rev = 1440.0;
  double feedback_period_s = 0.01;  // firmware feedback period (for mcu time and twist)
  // Limits applied to every command before it reaches CAN.
  double max_vx_m_s = 1.0;
  double max_vy_m_s = 1.0;
  double max_omega_rad_s = 2.0;
  double max_linear_accel_m_s2 = 1.0;
  double max_angular_accel_rad_s2 = 3.0;
  // Timing.
  double send_rate_hz = 100.0;     // SET_BODY_TWIST rate while commanding
  double command_timeout_s = 0.3;  // host command older than this: ramp to zero, then stop
  double firmware_heartbeat_period_s = 0.1;
  int missed_heartbeats_for_silent = 3;
  double reconnect_period_s = 0.5;
  double status_rate_hz = 10.0;
  // Odometry uncertainty: variance growth per metre travelled / radian turned, and a fixed
  // twist variance.
  double odom_var_xy_per_m = 1e-4;     // m^2 per m
  double odom_var_yaw_per_rad = 1e-3;  // rad^2 per rad
  double twist_var_linear = 1e-4;      // (m/s)^2
  double twist_var_angular = 1e-3;     // (rad/s)^2
  std::string odom_frame = "odom";
  std::string base_frame = "base";
  // LCM channels.
  std::string cmd_channel = "BASE_CMD";
  std::string odom_channel = "WHEEL_ODOM";
  std::string encoders_channel = "WHEEL_ENCODERS";
  std::string status_channel = "BASE_STATUS";
  // Wheel slip against the IMU's gyro (imu_t on imu_channel; the node subscribes to it).
  std::string imu_channel = "IMU";
  SlipOptions slip;
};

Result<BaseBridgeOptions> LoadBaseBridgeOptions(const std::string& path);
Result<BaseBridgeOptions> LoadBaseBridgeOptionsFromString(const std::string& yaml,
                                                          const std::string& name);

struct Command {
  // = base_cmd_t MODE_*; kInvalid: a mode the message does not define (refused and counted).
  // The fixed underlying type makes every int8_t a valid value, so a bad mode is never UB.
  enum Mode : int8_t { kTwist = 0, kEstop = 1, kClearFaults = 2, kInvalid = -1 } mode = kTwist;
  double vx_m_s = 0, vy_m_s = 0, omega_rad_s = 0;
};

struct Odometry {
  int64_t utime = 0;
  int64_t seq = 0;
  double x_m = 0, y_m = 0, yaw_rad = 0;            // in the odom frame
  double vx_m_s = 0, vy_m_s = 0, omega_rad_s = 0;  // body frame
  double pose_cov[9] = {0};
  double twist_cov[9] = {0};
};

struct Encoders {
  int64_t utime = 0;
  int64_t mcu_time_us = 0;
  int32_t seq = 0;
  int64_t position_ticks[3] = {0, 0, 0};
  float velocity_rad_s[3] = {0, 0, 0};
  float current_a[3] = {0, 0, 0};
};

struct BaseStatus {
  int64_t utime = 0;
  int8_t state = 0;  // firmware state (base_status_t STATE_*); BOOT until the first heartbeat
  int32_t fault_bits = 0;
  bool firmware_alive = false;
  int32_t missed_heartbeats = 0;  // since the last one received
  float bus_voltage_v = 0;
  float wheel_speed_rad_s[3] = {0, 0, 0};
  float wheel_setpoint_rad_s[3] = {0, 0, 0};
};

struct Counters {
  int64_t commands_in = 0;
  int64_t commands_clamped = 0;   // above a speed limit: clamped
  int64_t accel_limited = 0;      // send periods in which an acceleration limit held the twist back
  int64_t commands_rejected = 0;  // non-finite values or unknown mode
  int64_t commands_in_estop = 0;  // twists refused while ESTOP is latched (until CLEAR_FAULTS)
  int64_t commands_expired = 0;   // commands that went stale (no newer one within the timeout)
  int64_t firmware_restarts_seen = 0;  // feedback numbering started again: encoders re-based
  int64_t estops_sent = 0;  // ESTOP frames, first and repeated until the firmware shows it
  int64_t frames_sent = 0;
  int64_t frames_in = 0;
  int64_t can_rx_errors = 0;         // our node, wrong length
  int64_t unknown_frames = 0;        // our node, unknown or host->fw command
  int64_t missed_heartbeats = 0;     // total, from gaps between firmware heartbeats
  int64_t feedback_frames_lost = 0;  // gaps in the feedback sequence
  int64_t reconnects = 0;            // CAN interface re-opened after being lost
  int64_t link_losses = 0;
  int64_t geometry_mismatches = 0;  // firmware parameters found to differ from ours
  int64_t firmware_returns = 0;     // the firmware came back after a silence (maybe a restart):
                                    // encoders re-based, geometry checked again
  int64_t firmware_rx_unknown = 0;  // as reported by the firmware's diagnostics frame
  int64_t firmware_rx_bad_length = 0;
  int64_t firmware_tx_dropped = 0;
  int64_t firmware_max_step_us = 0;
  int64_t firmware_watchdog_trips = 0;  // from the firmware's second diagnostics frame
  int64_t firmware_commands_limited = 0;
  int64_t firmware_rx_overruns = 0;
  int64_t clock_steps_back = 0;  // the wall clock went back: the bridge's own times followed it
  int64_t clears_refused = 0;  // CLEAR_FAULTS asked while the CAN link was down: not kept for later
};

class BaseBridge {
 public:
  explicit BaseBridge(const BaseBridgeOptions& options);

  void OnCommand(const Command& cmd, int64_t now_us);
  // A remote (RTR) or extended-id frame read from the bus: never ours, counted as unknown.
  void OnForeignFrame() { ++counters_.unknown_frames; }
  void OnFrame(const firmware::CanFrame& f, int64_t now_us);
  // Periodic work; appends frames to send. Call often (every few ms).
  void Tick(int64_t now_us, std::vector<firmware::CanFrame>* out);
  // The CAN link went away / came back (node calls these; they reset the feedback tracking).
  void OnLinkDown(int64_t now_us);
  void OnLinkUp(int64_t now_us);

  // Odometry updated by the latest encoder frame (false if none since the last call).
  bool TakeOdometry(Odometry* out);
  bool TakeEncoders(Encoders* out);
  BaseStatus status(int64_t now_us) const;
  const Counters& counters() const { return counters_; }
  bool link_up() const { return link_up_; }
  // Human-readable health for the process heartbeat ("" when all is well).
  std::string Problem(int64_t now_us) const;
  // The twist last sent on CAN (after limits and ramps).
  const kinematics::BodyTwist<double>& sent_twist() const { return sent_; }

 private:
  void HandleEncoders(const firmware::can::EncoderFeedback& e, int64_t now_us);
  void HandleParamReply(const firmware::can::ParamReply& r);
  int64_t SilentForUs(int64_t now_us) const;

  BaseBridgeOptions o_;
  kinematics::OmniGeometry<double> geom_;
  uint8_t node_;
  // Commands.
  Command cmd_;
  int64_t cmd_us_ = 0;
  bool have_cmd_ = false;
  bool pending_estop_ = false;
  bool pending_clear_ = false;
  bool latched_before_clear_ = false;  // the ESTOP latch a pending CLEAR_FAULTS released
  // ESTOP is latched here too: from MODE_ESTOP until MODE_CLEAR_FAULTS twists are refused, and
  // ESTOP is sent again every kEstopRepeatUs while the firmware's heartbeat does not show it (a
  // frame lost on a full queue or a dead link, a board reset that forgot its latch).
  bool estop_latched_ = false;
  int64_t last_estop_us_ = 0;
  kinematics::BodyTwist<double> sent_;
  int64_t last_send_us_ = 0;
  int64_t last_tick_us_ = 0;
  bool sending_ = false;
  uint16_t cmd_seq_ = 0;
  // Feedback.
  bool have_enc_ = false;
  uint16_t last_enc_seq_ = 0;
  int64_t last_enc_us_ = 0;
  std::map<uint16_t, std::string> mismatches_;  // parameter id -> what differs
  uint16_t last_raw_[3] = {0, 0, 0};
  int64_t ticks_[3] = {0, 0, 0};
  Odometry odom_;
  bool odom_new_ = false;
  Encoders enc_;
  bool enc_new_ = false;
  float speed_[3] = {0, 0, 0};
  float current_[3] = {0, 0, 0};
  float setpoint_[3] = {0, 0, 0};
  // Heartbeat.
  bool have_hb_ = false;
  int64_t last_hb_us_ = 0;
  int8_t fw_state_ = 0;
  uint32_t fw_faults_ = 0;
  float bus_voltage_ = 0;
  // Link.
  bool link_up_ = true;
  int64_t link_down_since_us_ = 0;
  bool geometry_checked_ = false;   // every geometry parameter has answered once
  uint32_t geometry_answered_ = 0;  // which have (bits in kGeometryParams' order)
  void FirmwareReturned();
  void FollowClock(int64_t now_us);  // every entry point first: a clock set back shifts our times
  int64_t clock_us_ = 0;             // the latest time seen
  // The firmware's time at the latest feedback: its feedback periods counted by their numbers
  // (lost frames included), a silence by its length here, from 0 at a restart seen.
  int64_t mcu_time_us_ = 0;
  int64_t SilenceUs() const;  // missed_heartbeats_for_silent heartbeat periods
  int64_t geometry_query_us_ = 0;
  std::string last_mismatch_;  // the first of mismatches_, "" when all agree
  Counters counters_;
};

}  // namespace omni::base_bridge
