#include "omni/firmware/firmware.h"

namespace omni::firmware {
namespace {

constexpr int kMaxFramesPerStep = 8;  // bounded work per period
constexpr float kTwoPi = 6.28318530718f;
constexpr float kStoppedRadS = 0.3f;  // |speed| below this counts as stopped
// A wheel measured this fast against its drive is not braking: a healthy wheel's speed follows
// its setpoint through zero within a few periods of a reversal.
constexpr float kRunawayRadS = 2.f;
// After the stop ramp reaches zero, the wheels have this long to come to rest.
constexpr uint32_t kStopSettleUs = 300000;

float Abs(float v) { return v < 0.f ? -v : v; }
bool Finite(float v) { return v == v && v < 3.0e38f && v > -3.0e38f; }

}  // namespace

FwStatus Firmware::Init() {
  LoadParamStore();
  uint16_t bad = 0;
  if (ValidateParams(params_, &bad) != FwStatus::kOk) return FwStatus::kInvalid;
  for (int w = 0; w < kNumWheels; ++w) {
    counters16_[w].Reset(hal_->ReadEncoder(w));
    estimators_[w].Reset(0);
    pids_[w].Reset();
    wheels_[w] = WheelState{};
    stall_ms_[w] = 0;
    runaway_ms_[w] = 0;
  }
  MotorsOff();
  UpdateForwardMatrix();
  fault_bits_ = 0;
  uptime_ms_ = 0;
  step_accum_us_ = 0;
  state_ = State::kIdle;
  return FwStatus::kOk;
}

void Firmware::UpdateForwardMatrix() {
  for (int w = 0; w < kNumWheels; ++w) {
    omni::kinematics::WheelSpeeds<float> unit;
    unit.v_m_s[w] = 1.f;
    omni::kinematics::BodyTwist<float> col;
    if (!omni::kinematics::WheelsToBody(Geometry(), unit, &col)) col = {};
    forward_[0][w] = col.vx_m_s;
    forward_[1][w] = col.vy_m_s;
    forward_[2][w] = col.omega_rad_s;
  }
}

void Firmware::MotorsOff() {
  for (int w = 0; w < kNumWheels; ++w) {
    hal_->WritePwm(w, 0.f);
    wheels_[w].duty = 0.f;
    wheels_[w].target_rad_s = 0.f;
    wheels_[w].setpoint_rad_s = 0.f;
    pids_[w].Reset();
  }
  hal_->SetMotorEnable(false);
}

void Firmware::EnterFault(uint32_t bit) {
  fault_bits_ |= bit;
  if (bit == kFaultEstop) {
    state_ = State::kEstop;
  } else if (state_ != State::kEstop) {
    state_ = State::kFault;
  }
  MotorsOff();
}

void Firmware::Send(const CanFrame& f) {
  if (tx_count_ == kTxQueue) DrainTx();  // mailboxes may have freed since the last drain
  if (tx_count_ == kTxQueue) {
    ++counters_.tx_dropped;
  } else {
    tx_queue_[(tx_head_ + tx_count_) % kTxQueue] = f;
    ++tx_count_;
  }
  DrainTx();
}

void Firmware::DrainTx() {
  if (hal_->CanBusOff()) {
    // Nothing leaves a bus-off controller; what is queued would be stale when it recovers.
    counters_.tx_dropped += static_cast<uint32_t>(tx_count_);
    tx_count_ = 0;
    return;
  }
  while (tx_count_ > 0 && hal_->CanWrite(tx_queue_[tx_head_]) == FwStatus::kOk) {
    tx_head_ = (tx_head_ + 1) % kTxQueue;
    --tx_count_;
  }
}

void Firmware::OnMotionCommand(const float target_rad_s[kNumWheels]) {
  if (state_ == State::kFault || state_ == State::kEstop || state_ == State::kBoot) return;
  float peak = 0.f;
  for (int w = 0; w < kNumWheels; ++w) {
    if (!Finite(target_rad_s[w])) {
      fault_bits_ |= kFaultBadCommand;
      return;
    }
    if (Abs(target_rad_s[w]) > peak) peak = Abs(target_rad_s[w]);
  }
  // Above the wheel speed limit: scale all three alike, so the direction of travel holds.
  const float scale =
      peak > params_.max_wheel_speed_rad_s ? params_.max_wheel_speed_rad_s / peak : 1.f;
  if (scale < 1.f) ++counters_.commands_limited;
  for (int w = 0; w < kNumWheels; ++w) wheels_[w].target_rad_s = target_rad_s[w] * scale;
  fault_bits_ &= ~(kFaultWatchdog | kFaultBadCommand);
  ++counters_.commands;
  last_command_ms_ = uptime_ms_;
  if (state_ != State::kRunning) {
    if (state_ == State::kIdle) {
      for (int w = 0; w < kNumWheels; ++w) pids_[w].Reset();
    }
    state_ = State::kRunning;
    hal_->SetMotorEnable(true);
  }
}

void Firmware::HandleParam(const CanFrame& f, bool set) {
  can::ParamRequest req;
  if (!can::DecodeParamRequest(f, &req)) return;
  can::ParamReply reply;
  reply.id = req.id;
  reply.of_set = set ? 1 : 0;
  FwStatus s = FwStatus::kOk;
  if (set) {
    s = SetParam(&params_, req.id, req.value);
    if (s != FwStatus::kOk) fault_bits_ |= kFaultBadCommand;
    if (s == FwStatus::kOk) UpdateForwardMatrix();
  }
  if (s == FwStatus::kOk) s = GetParam(params_, req.id, &reply.value);
  switch (s) {
    case FwStatus::kOk:
      reply.result = can::kParamOk;
      break;
    case FwStatus::kUnknown:
      reply.result = can::kParamUnknown;
      break;
    case FwStatus::kReadOnly:
      reply.result = can::kParamReadOnly;
      break;
    default:
      reply.result = can::kParamOutOfRange;
      break;
  }
  if (reply.result != can::kParamOk) (void)GetParam(params_, req.id, &reply.value);
  Send(can::EncodeParamValue(params_.node_id, reply));
}

void Firmware::LoadParamStore() {
  stored_count_ = 0;
  stored_crc_ = 0;
  if (!hal_->has_param_store()) {
    store_state_ = ParamStoreState::kNoStore;
    return;
  }
  uint8_t buf[kParamStoreMaxBytes] = {};
  const uint32_t n = hal_->ParamStoreRead(buf, sizeof(buf));
  int applied = 0;
  const FwStatus s = DecodeParamStore(buf, n > sizeof(buf) ? 0 : n, &params_, &applied);
  if (n == 0) {
    store_state_ = ParamStoreState::kEmpty;
  } else if (s != FwStatus::kOk) {
    store_state_ = ParamStoreState::kCorrupt;  // compiled defaults; the host can re-save
  } else {
    store_state_ = ParamStoreState::kLoaded;
    stored_count_ = static_cast<uint8_t>(applied);
    stored_crc_ = Crc32(buf, n);
  }
}

void Firmware::HandleSaveParams(uint8_t action) {
  can::ParamStoreStatus st;
  st.action = action;
  st.boot_state = static_cast<uint8_t>(store_state_);
  const bool motors_off =
      state_ == State::kIdle || state_ == State::kFault || state_ == State::kEstop;
  if (action > can::kStoreQuery) {
    st.result = can::kStoreBadAction;
    fault_bits_ |= kFaultBadCommand;
  } else if (action == can::kStoreQuery) {
    st.result = can::kStoreOk;
  } else if (!hal_->has_param_store()) {
    st.result = can::kStoreUnavailable;
  } else if (!motors_off) {
    st.result = can::kStoreRefusedMoving;
    fault_bits_ |= kFaultBadCommand;
  } else {
    uint8_t buf[kParamStoreMaxBytes] = {};
    const size_t len = action == can::kStoreSave ? EncodeParamStore(params_, buf, sizeof(buf)) : 0;
    untimed_step_ = true;
    const FwStatus w = hal_->ParamStoreWrite(buf, static_cast<uint32_t>(len));
    // Read it back: only what is really there counts as stored.
    uint8_t back[kParamStoreMaxBytes] = {};
    const uint32_t n = hal_->ParamStoreRead(back, sizeof(back));
    Params check = params_;
    int applied = 0;
    const bool same =
        n == len && (len == 0 || (DecodeParamStore(back, n, &check, &applied) == FwStatus::kOk &&
                                  Crc32(back, n) == Crc32(buf, len)));
    if (w != FwStatus::kOk || !same) {
      st.result = can::kStoreWriteFailed;
    } else {
      st.result = can::kStoreOk;
      stored_count_ = static_cast<uint8_t>(applied);
      stored_crc_ = len == 0 ? 0 : Crc32(buf, len);
    }
  }
  st.stored = stored_count_;
  st.crc = stored_crc_;
  Send(can::EncodeParamStoreStatus(params_.node_id, st));
}

void Firmware::HandleFrame(const CanFrame& f) {
  if (f.id == can::kForeignFrameId) {
    // A remote or extended-id frame (node 63's id otherwise): counted whatever our node is.
    ++counters_.rx_frames;
    ++counters_.rx_unknown;
    return;
  }
  if (can::NodeOf(f.id) != params_.node_id) return;  // another node's traffic: not ours
  ++counters_.rx_frames;
  const uint8_t cmd = can::CommandOf(f.id);
  switch (cmd) {
    case can::kEstop:
    case can::kClearFaults:
    case can::kSetBodyTwist:
    case can::kSetWheelSpeeds:
    case can::kGetParam:
    case can::kSetParam:
    case can::kSaveParams:
      break;
    default:
      ++counters_.rx_unknown;
      return;
  }
  if (!can::CheckLength(f)) {
    ++counters_.rx_bad_length;
    return;
  }
  switch (cmd) {
    case can::kEstop:
      EnterFault(kFaultEstop);
      break;
    case can::kClearFaults:
      if (state_ == State::kFault || state_ == State::kEstop) state_ = State::kIdle;
      fault_bits_ = 0;
      under_voltage_ms_ = 0;
      for (int w = 0; w < kNumWheels; ++w) {
        stall_ms_[w] = 0;
        runaway_ms_[w] = 0;
        wheels_[w].over_current_ms = 0;
      }
      break;
    case can::kSetBodyTwist: {
      can::BodyTwist t;
      if (!can::DecodeBodyTwist(f, &t)) return;
      last_cmd_seq_ = t.seq;
      // Eq. (1): body twist -> rim speeds (m/s) -> wheel angular speeds (rad/s).
      const omni::kinematics::BodyTwist<float> twist{t.vx_m_s, t.vy_m_s, t.omega_rad_s};
      const auto rim = omni::kinematics::BodyToWheels(Geometry(), twist);
      float target[kNumWheels];
      for (int w = 0; w < kNumWheels; ++w) target[w] = rim.v_m_s[w] / params_.wheel_radius_m;
      OnMotionCommand(target);
      break;
    }
    case can::kSetWheelSpeeds: {
      can::WheelTriple ws;
      if (!can::DecodeWheelSpeeds(f, &ws)) return;
      last_cmd_seq_ = ws.seq;
      OnMotionCommand(ws.v);
      break;
    }
    case can::kGetParam:
      HandleParam(f, /*set=*/false);
      break;
    case can::kSetParam:
      HandleParam(f, /*set=*/true);
      break;
    case can::kSaveParams: {
      uint8_t action = 0;
      if (can::DecodeSaveParams(f, &action)) HandleSaveParams(action);
      break;
    }
    default:
      break;
  }
}

void Firmware::CheckFaults(float dt_s) {
  (void)dt_s;
  if (hal_->CanBusOff()) EnterFault(kFaultCanBusOff);
  if (bus_voltage_v_ < params_.under_voltage_v) {
    if (++under_voltage_ms_ >= params_.under_voltage_ms) EnterFault(kFaultUnderVoltage);
  } else {
    under_voltage_ms_ = 0;
  }
  const bool driving = state_ == State::kRunning || state_ == State::kStopping;
  for (int w = 0; w < kNumWheels; ++w) {
    WheelState& ws = wheels_[w];
    if (Abs(ws.current_a) > params_.current_limit_a) {
      if (++ws.over_current_ms >= params_.over_current_ms) EnterFault(kFaultOverCurrent);
    } else {
      ws.over_current_ms = 0;
    }
    if (driving && Abs(ws.duty) >= params_.stall_duty &&
        estimators_[w].periods_since_change() > 0) {
      if (++stall_ms_[w] >= params_.stall_ms) EnterFault(kFaultEncoderStall);
    } else {
      stall_ms_[w] = 0;
    }
    // Driven one way, measured turning the other: the loop pushes harder the faster it runs
    // (a reversed encoder or motor lead), and neither a zero command nor the watchdog's stop
    // would end it.
    if (driving && Abs(ws.duty) >= params_.stall_duty && Abs(ws.speed_rad_s) > kRunawayRadS &&
        (ws.duty > 0.f) != (ws.speed_rad_s > 0.f)) {
      if (++runaway_ms_[w] >= params_.stall_ms) EnterFault(kFaultRunaway);
    } else {
      runaway_ms_[w] = 0;
    }
  }
}

void Firmware::Step() {
  const uint32_t t0 = hal_->MicrosNow();
  const float dt = static_cast<float>(params_.control_period_us) * 1e-6f;
  ++counters_.steps;
  step_accum_us_ += params_.control_period_us;
  const bool new_ms = step_accum_us_ >= 1000;
  while (step_accum_us_ >= 1000) {
    ++uptime_ms_;
    step_accum_us_ -= 1000;
  }

  // 1. Frames still queued from the last step go out first; then commands (and the frames the
  // controller had to drop since the last step).
  DrainTx();
  counters_.rx_overruns += hal_->TakeCanRxOverruns();
  CanFrame f;
  for (int n = 0; n < kMaxFramesPerStep && hal_->CanRead(&f); ++n) HandleFrame(f);

  // 2. Encoders, speeds, currents, supply.
  const float counts_to_rad_s = kTwoPi / (params_.ticks_per_rev * dt);
  float rim[kNumWheels];
  for (int w = 0; w < kNumWheels; ++w) {
    WheelState& ws = wheels_[w];
    (void)counters16_[w].Update(hal_->ReadEncoder(w));
    ws.position = counters16_[w].position();
    ws.speed_rad_s = estimators_[w].Update(ws.position) * counts_to_rad_s;
    ws.current_a = hal_->ReadCurrentA(w);
    rim[w] = ws.speed_rad_s * params_.wheel_radius_m;
  }
  bus_voltage_v_ = hal_->ReadBusVoltageV();
  // Forward kinematics (wheel rim speeds -> body twist), see UpdateForwardMatrix().
  float* twist[3] = {&measured_twist_.vx_m_s, &measured_twist_.vy_m_s,
                     &measured_twist_.omega_rad_s};
  for (int r = 0; r < 3; ++r) {
    *twist[r] = forward_[r][0] * rim[0] + forward_[r][1] * rim[1] + forward_[r][2] * rim[2];
  }

  // 3. Watchdog, then faults.
  if (state_ == State::kRunning && uptime_ms_ - last_command_ms_ >= params_.watchdog_ms) {
    state_ = State::kStopping;
    fault_bits_ |= kFaultWatchdog;
    ++counters_.watchdog_trips;
    float fastest = 0.f;
    for (WheelState& ws : wheels_) {
      ws.target_rad_s = 0.f;
      if (Abs(ws.setpoint_rad_s) > fastest) fastest = Abs(ws.setpoint_rad_s);
    }
    stopping_us_ = 0;
    stop_deadline_us_ = static_cast<uint32_t>(fastest / params_.stop_decel_rad_s2 * 1e6f) +
                        params_.control_period_us + kStopSettleUs;
  }
  CheckFaults(dt);
  // A stop that has not come to rest by its deadline is not going to: motors off, latched.
  if (state_ == State::kStopping) {
    stopping_us_ += params_.control_period_us;
    if (stopping_us_ > stop_deadline_us_) EnterFault(kFaultRunaway);
  }

  // 4./5. Speed loop and PWM.
  if (state_ == State::kRunning || state_ == State::kStopping) {
    const PidGains gains{params_.kp, params_.ki, params_.kd, params_.kff, params_.max_duty};
    const float rate =
        state_ == State::kStopping ? params_.stop_decel_rad_s2 : params_.max_wheel_accel_rad_s2;
    bool stopped = true;
    for (int w = 0; w < kNumWheels; ++w) {
      WheelState& ws = wheels_[w];
      ws.setpoint_rad_s = RampTowards(ws.setpoint_rad_s, ws.target_rad_s, rate, dt);
      ws.duty = pids_[w].Update(gains, ws.setpoint_rad_s, ws.speed_rad_s, dt);
      hal_->WritePwm(w, ws.duty);
      if (ws.setpoint_rad_s != 0.f || Abs(ws.speed_rad_s) > kStoppedRadS) stopped = false;
    }
    if (state_ == State::kStopping && stopped) {
      MotorsOff();
      state_ = State::kIdle;
    }
  }

  // 6. Feedback, once per millisecond boundary.
  if (new_ms) SendFeedback();
  hal_->SetStatusLed(state_ == State::kFault || state_ == State::kEstop ||
                     (state_ == State::kRunning && (uptime_ms_ / 250) % 2 == 0));

  const uint32_t took = hal_->MicrosNow() - t0;
  if (took > counters_.max_step_us && !untimed_step_) counters_.max_step_us = took;
  untimed_step_ = false;
}

void Firmware::SendFeedback() {
  const uint8_t node = params_.node_id;
  if (uptime_ms_ - feedback_ms_ >= params_.feedback_period_ms) {
    feedback_ms_ = uptime_ms_;
    feedback_seq_ = can::NextFeedbackSeq(feedback_seq_);
    can::EncoderFeedback enc;
    can::WheelTriple speed, current;
    enc.seq = speed.seq = current.seq = feedback_seq_;
    for (int w = 0; w < kNumWheels; ++w) {
      enc.position_low16[w] = static_cast<uint16_t>(wheels_[w].position);
      speed.v[w] = wheels_[w].speed_rad_s;
      current.v[w] = wheels_[w].current_a;
    }
    can::BodyTwist twist{measured_twist_.vx_m_s, measured_twist_.vy_m_s,
                         measured_twist_.omega_rad_s, feedback_seq_};
    Send(can::EncodeEncoderFeedback(node, enc));
    Send(can::EncodeSpeedFeedback(node, speed));
    Send(can::EncodeCurrentFeedback(node, current));
    Send(can::EncodeBodyTwistFeedback(node, twist));
  }
  if (uptime_ms_ - heartbeat_ms_ >= params_.heartbeat_period_ms) {
    heartbeat_ms_ = uptime_ms_;
    can::Heartbeat hb;
    hb.fault_bits = fault_bits_;
    hb.state = static_cast<uint8_t>(state_);
    hb.counter = ++heartbeat_counter_;
    hb.bus_voltage_v = bus_voltage_v_;
    Send(can::EncodeHeartbeat(node, hb));
    can::WheelTriple sp;
    sp.seq = last_cmd_seq_;
    for (int w = 0; w < kNumWheels; ++w) sp.v[w] = wheels_[w].setpoint_rad_s;
    Send(can::EncodeSetpointFeedback(node, sp));
    if (heartbeat_counter_ % 10 == 0) {
      can::Diagnostics d;
      d.rx_unknown = can::SaturateCount(counters_.rx_unknown);
      d.rx_bad_length = can::SaturateCount(counters_.rx_bad_length);
      d.tx_dropped = can::SaturateCount(counters_.tx_dropped);
      d.max_step_us = can::SaturateCount(counters_.max_step_us);
      Send(can::EncodeDiagnostics(node, d));
    } else if (heartbeat_counter_ % 10 == 5) {
      can::Diagnostics2 d;
      d.watchdog_trips = can::SaturateCount(counters_.watchdog_trips);
      d.commands_limited = can::SaturateCount(counters_.commands_limited);
      d.rx_overruns = can::SaturateCount(counters_.rx_overruns);
      Send(can::EncodeDiagnostics2(node, d));
    }
  }
}

}  // namespace omni::firmware
