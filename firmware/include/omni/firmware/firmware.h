// The portable core of the base controller: a fixed-rate (1 kHz) control loop.
//
// Each Step():
//   1. drains received CAN frames (commands, parameters, e-stop, clear faults);
//   2. reads the three encoder counters and estimates wheel speeds;
//   3. checks the command watchdog and the fault conditions;
//   4. ramps each wheel setpoint towards its target (acceleration limit) and runs the PI(D)
//      speed loop (anti-windup, clamped output);
//   5. writes the PWM duties (or disables the bridges when not running);
//   6. sends cyclic feedback (encoder, speed, current, body twist) and the heartbeat.
// No heap, no exceptions, no RTTI; every fallible call returns FwStatus.
//
// State machine (values = omni.base_status_t STATE_*):
//   BOOT -Init-> IDLE -command-> RUNNING -watchdog-> STOPPING -stopped-> IDLE
//   any -fault-> FAULT, any -e-stop-> ESTOP; FAULT/ESTOP -clear faults (cause gone)-> IDLE.
// Fault bits (values = omni.base_status_t FAULT_*): ESTOP, ENCODER_STALL, OVER_CURRENT,
// UNDER_VOLTAGE and CAN_BUS_OFF are latched and keep the motors off until CLEAR_FAULTS;
// WATCHDOG (set when the watchdog stopped the base) and BAD_COMMAND (a command or parameter
// write was refused) are warnings, cleared by the next accepted command.
#pragma once

#include <cstdint>

#include "omni/common/kinematics.h"
#include "omni/firmware/can_protocol.h"
#include "omni/firmware/hal.h"
#include "omni/firmware/param_store.h"
#include "omni/firmware/params.h"
#include "omni/firmware/pid.h"
#include "omni/firmware/quadrature.h"
#include "omni/firmware/speed_estimator.h"
#include "omni/firmware/status.h"

namespace omni::firmware {

enum class State : uint8_t {
  kBoot = 0,
  kIdle = 1,
  kRunning = 2,
  kStopping = 3,
  kFault = 4,
  kEstop = 5
};

enum FaultBit : uint32_t {
  kFaultWatchdog = 1,
  kFaultEstop = 2,
  kFaultEncoderStall = 4,
  kFaultOverCurrent = 8,
  kFaultUnderVoltage = 16,
  kFaultCanBusOff = 32,
  kFaultBadCommand = 64,
  // A wheel turns against its drive (|duty| >= stall_duty, the measured speed of the other sign
  // and above 2 rad/s, for stall_ms: a reversed encoder or motor lead), or the controlled stop
  // after the watchdog has not brought every wheel to rest by its deadline.
  kFaultRunaway = 128,
};
inline constexpr uint32_t kLatchedFaults = kFaultEstop | kFaultEncoderStall | kFaultOverCurrent |
                                           kFaultUnderVoltage | kFaultCanBusOff | kFaultRunaway;

struct WheelState {
  int32_t position = 0;        // accumulated x4 counts
  float speed_rad_s = 0.f;     // estimated
  float target_rad_s = 0.f;    // commanded (after the speed limit)
  float setpoint_rad_s = 0.f;  // after the acceleration ramp: what the PI loop tracks
  float duty = 0.f;            // written to the PWM
  float current_a = 0.f;
  uint32_t over_current_ms = 0;
};

struct Counters {
  uint32_t steps = 0;
  uint32_t rx_frames = 0;         // frames addressed to this node
  uint32_t rx_unknown = 0;        // ... with an unknown command
  uint32_t rx_bad_length = 0;     // ... with a wrong DLC
  uint32_t rx_overruns = 0;       // receive-FIFO overruns reported by the HAL (frames lost)
  uint32_t tx_dropped = 0;        // frames lost: the transmit queue full, or the controller bus-off
  uint32_t commands = 0;          // accepted motion commands
  uint32_t commands_limited = 0;  // motion commands scaled down to max_wheel_speed
  uint32_t watchdog_trips = 0;
  uint32_t max_step_us = 0;
};

class Firmware {
 public:
  Firmware(Hal* hal, const Params& params) : hal_(hal), params_(params) {}

  // Applies the parameter store's record if there is a valid one (param_store.h), validates
  // the parameters, zeroes the encoders, disables the motors, enters IDLE.
  [[nodiscard]] FwStatus Init();
  // One control period. Call every params().control_period_us.
  void Step();

  // Processes one frame (Step() calls this for every received frame; public for tests).
  void HandleFrame(const CanFrame& f);

  State state() const { return state_; }
  uint32_t fault_bits() const { return fault_bits_; }
  const WheelState& wheel(int i) const { return wheels_[i]; }
  const Counters& counters() const { return counters_; }
  const Params& params() const { return params_; }
  // Time since Init, from the step count (deterministic), milliseconds.
  uint32_t uptime_ms() const { return uptime_ms_; }
  // What Init() found in the parameter store, and what it holds now (count 0: empty).
  ParamStoreState param_store_state() const { return store_state_; }
  uint8_t params_stored() const { return stored_count_; }
  // Body twist measured from the wheel speeds (forward kinematics).
  const omni::kinematics::BodyTwist<float>& measured_twist() const { return measured_twist_; }

 private:
  void OnMotionCommand(const float target_rad_s[kNumWheels]);
  void HandleParam(const CanFrame& f, bool set);
  void LoadParamStore();
  void HandleSaveParams(uint8_t action);
  void EnterFault(uint32_t bit);
  void MotorsOff();
  void CheckFaults(float dt_s);
  void SendFeedback();
  // Queues a frame and hands what the controller's transmit mailboxes take (FIFO order).
  void Send(const CanFrame& f);
  // Hands queued frames to the controller while it takes them; called by Send and at the start
  // of every step (mailboxes freed since by frames that went out on the wire).
  void DrainTx();
  // Forward kinematics as a matrix: the shared WheelsToBody applied to unit wheel speeds
  // (it is linear), computed at Init and whenever a geometry parameter changes, so the 1 kHz
  // step does not redo the trigonometry and the 3x3 solve.
  void UpdateForwardMatrix();
  omni::kinematics::OmniGeometry<float> Geometry() const {
    return {params_.alpha_rad, params_.center_to_wheel_m, params_.wheel_radius_m};
  }

  Hal* hal_;
  Params params_;
  State state_ = State::kBoot;
  uint32_t fault_bits_ = 0;
  WheelState wheels_[kNumWheels];
  EncoderCounter counters16_[kNumWheels];
  SpeedEstimator estimators_[kNumWheels];
  SpeedPid pids_[kNumWheels];
  uint32_t stall_ms_[kNumWheels] = {0, 0, 0};
  uint32_t runaway_ms_[kNumWheels] = {0, 0, 0};
  uint32_t stopping_us_ = 0;       // time in STOPPING so far
  uint32_t stop_deadline_us_ = 0;  // set at the watchdog's trip: the ramp's length + settling
  uint32_t under_voltage_ms_ = 0;
  float bus_voltage_v_ = 0.f;
  uint32_t uptime_ms_ = 0;
  uint32_t step_accum_us_ = 0;
  uint32_t last_command_ms_ = 0;
  uint32_t feedback_ms_ = 0;
  uint32_t heartbeat_ms_ = 0;
  uint16_t feedback_seq_ = 0;
  uint8_t heartbeat_counter_ = 0;
  uint16_t last_cmd_seq_ = 0;
  ParamStoreState store_state_ = ParamStoreState::kNoStore;
  uint8_t stored_count_ = 0;
  uint32_t stored_crc_ = 0;
  bool untimed_step_ = false;  // a flash write ran in this step: not a control-step time
  Counters counters_;
  // Transmit queue in front of the controller's mailboxes (3 on the bxCAN): a feedback step
  // writes 4 frames, one every 100 ms 6-7, far faster than one goes out on the wire (~130 us at
  // 1 Mbit/s), so without it the 4th frame onwards was dropped every time on the board.
  static constexpr int kTxQueue = 16;
  CanFrame tx_queue_[kTxQueue];
  int tx_head_ = 0, tx_count_ = 0;
  omni::kinematics::BodyTwist<float> measured_twist_;
  float forward_[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};  // body twist = forward_ * rim speeds
};

}  // namespace omni::firmware
