#include "omni/base_bridge/base_bridge.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <sstream>

#include "omni/common/time.h"
#include "omni/firmware/firmware.h"
#include "omni/firmware/params.h"

namespace omni::base_bridge {

namespace fwcan = omni::firmware::can;

namespace {
constexpr int64_t kEstopRepeatUs = 100000;
// The parameters whose values the bridge's odometry depends on, checked at connect.
// The heartbeat period and watchdog are checked with them: a firmware beating slower than the
// config says looked silent and "returned" at every beat (each return re-bases the encoders,
// dropping a feedback period of motion), and a watchdog shorter than two of the bridge's send
// periods stopped the base between commands.
constexpr uint16_t kGeometryParams[] = {firmware::kParamAlpha,
                                        firmware::kParamCenterToWheel,
                                        firmware::kParamWheelRadius,
                                        firmware::kParamTicksPerRev,
                                        firmware::kParamFeedbackPeriodMs,
                                        firmware::kParamHeartbeatPeriodMs,
                                        firmware::kParamWatchdogMs};
constexpr uint32_t kAllGeometryBits = (1u << std::size(kGeometryParams)) - 1;
uint32_t GeometryBit(uint16_t id) {
  for (size_t i = 0; i < std::size(kGeometryParams); ++i)
    if (kGeometryParams[i] == id) return 1u << i;
  return 0;
}
}  // namespace

BaseBridge::BaseBridge(const BaseBridgeOptions& options)
    : o_(options),
      geom_{options.alpha_rad, options.center_to_wheel_m, options.wheel_radius_m},
      node_(static_cast<uint8_t>(options.node_id)) {}

void BaseBridge::FollowClock(int64_t now_us) {
  if (clock_us_ != 0 && now_us < clock_us_) {
    // The wall clock set back (NTP, by hand): every time kept moves back by the step, so what is
    // measured across it (the firmware's silence, a command's age, the send period) stays what it
    // was. Before, a firmware silent before the step looked alive for the length of the step.
    const int64_t step = clock_us_ - now_us;
    for (int64_t* t : {&cmd_us_, &last_estop_us_, &last_send_us_, &last_enc_us_, &last_hb_us_,
                       &link_down_since_us_, &geometry_query_us_}) {
      if (*t != 0) *t -= step;
    }
    ++counters_.clock_steps_back;
  }
  clock_us_ = now_us;
}

void BaseBridge::OnCommand(const Command& cmd, int64_t now_us) {
  FollowClock(now_us);
  ++counters_.commands_in;
  switch (cmd.mode) {
    case Command::kEstop:
      pending_estop_ = true;
      estop_latched_ = true;
      have_cmd_ = false;
      sent_ = {};
      return;
    case Command::kClearFaults:
      // Not kept for the link's return: sent minutes later, it would clear whatever the firmware
      // latched meanwhile (an over-current, another ESTOP) under a commander still streaming.
      if (!link_up_) {
        ++counters_.clears_refused;
        return;
      }
      pending_clear_ = true;
      latched_before_clear_ = latched_before_clear_ || estop_latched_;
      estop_latched_ = false;
      return;
    case Command::kTwist:
      if (estop_latched_) {
        ++counters_.commands_in_estop;
        return;
      }
      break;
    default:
      ++counters_.commands_rejected;
      return;
  }
  if (!std::isfinite(cmd.vx_m_s) || !std::isfinite(cmd.vy_m_s) || !std::isfinite(cmd.omega_rad_s)) {
    ++counters_.commands_rejected;
    return;
  }
  Command c = cmd;
  bool clamped = false;
  auto clamp = [&clamped](double* v, double limit) {
    if (std::fabs(*v) > limit) {
      *v = std::copysign(limit, *v);
      clamped = true;
    }
  };
  clamp(&c.vx_m_s, o_.max_vx_m_s);
  clamp(&c.vy_m_s, o_.max_vy_m_s);
  clamp(&c.omega_rad_s, o_.max_omega_rad_s);
  if (clamped) ++counters_.commands_clamped;
  cmd_ = c;
  cmd_us_ = now_us;
  have_cmd_ = true;
}

void BaseBridge::Tick(int64_t now_us, std::vector<firmware::CanFrame>* out) {
  FollowClock(now_us);
  last_tick_us_ = now_us;
  if (!link_up_) return;
  const bool fw_in_estop = have_hb_ && fw_state_ == static_cast<int8_t>(firmware::State::kEstop);
  if (pending_estop_ ||
      (estop_latched_ && !fw_in_estop && PeriodDue(now_us, last_estop_us_, kEstopRepeatUs))) {
    out->push_back(fwcan::EncodeEstop(node_));
    ++counters_.estops_sent;
    last_estop_us_ = now_us;
    pending_estop_ = false;
    sending_ = false;
  }
  if (pending_clear_) {
    out->push_back(fwcan::EncodeClearFaults(node_));
    pending_clear_ = false;
    latched_before_clear_ = false;
  }
  // Once the firmware answers, check that it uses our geometry (else odometry would be wrong);
  // while a parameter differs, ask again every 5 s so a corrected one clears the warning.
  // Until each of the five has answered, the ones still missing are asked again every second
  // (a request lost in a full receive FIFO on the board used to leave its check undone for good).
  const int64_t recheck_us = geometry_checked_ ? 5000000 : 1000000;
  if ((!geometry_checked_ || !mismatches_.empty()) && have_hb_ &&
      PeriodDue(now_us, geometry_query_us_, recheck_us + 1)) {
    geometry_query_us_ = now_us;
    for (uint16_t id : kGeometryParams) {
      if (!geometry_checked_ && (geometry_answered_ & GeometryBit(id))) continue;
      out->push_back(fwcan::EncodeGetParam(node_, id));
    }
  }
  const int64_t period_us = static_cast<int64_t>(1e6 / o_.send_rate_hz);
  if (!PeriodDue(now_us, last_send_us_, period_us)) return;
  const bool at_rest = sent_.vx_m_s == 0 && sent_.vy_m_s == 0 && sent_.omega_rad_s == 0;
  // The clock set back: the step is not a period of motion. From rest (quiet since the last
  // stop), the first step is one period's, not up to five periods' worth of acceleration.
  int64_t dt_us =
      last_send_us_ == 0 || now_us < last_send_us_ || at_rest ? period_us : now_us - last_send_us_;
  dt_us = std::min<int64_t>(dt_us, 5 * period_us);
  // The clock set back past the command's stamp: its age restarts from now, so it lives at most
  // one more timeout (never the length of the step).
  if (have_cmd_ && now_us < cmd_us_) cmd_us_ = now_us;
  // A command that went stale stays dead: a later step back of the clock cannot revive the last
  // twist of a commander that has stopped (it did: the base drove off again, unattended).
  if (have_cmd_ && now_us - cmd_us_ > static_cast<int64_t>(o_.command_timeout_s * 1e6)) {
    have_cmd_ = false;
    ++counters_.commands_expired;
  }
  const bool fresh = have_cmd_;
  kinematics::BodyTwist<double> target;
  if (fresh) target = {cmd_.vx_m_s, cmd_.vy_m_s, cmd_.omega_rad_s};
  if (!fresh && at_rest) {
    // Nothing to say: the firmware's watchdog parks the base (motors off) after its timeout.
    sending_ = false;
    return;
  }
  last_send_us_ = now_us;
  const double dt = static_cast<double>(dt_us) * 1e-6;
  // Acceleration limits: the linear change as a vector (keeps the direction of travel).
  const double dvx = target.vx_m_s - sent_.vx_m_s, dvy = target.vy_m_s - sent_.vy_m_s;
  const double dv = std::hypot(dvx, dvy), dv_max = o_.max_linear_accel_m_s2 * dt;
  const double k = dv > dv_max ? dv_max / dv : 1.0;
  sent_.vx_m_s += k * dvx;
  sent_.vy_m_s += k * dvy;
  const double dw = target.omega_rad_s - sent_.omega_rad_s,
               dw_max = o_.max_angular_accel_rad_s2 * dt;
  if (k < 1.0 || std::fabs(dw) > dw_max) ++counters_.accel_limited;
  sent_.omega_rad_s += std::clamp(dw, -dw_max, dw_max);
  sending_ = true;
  fwcan::BodyTwist t{static_cast<float>(sent_.vx_m_s), static_cast<float>(sent_.vy_m_s),
                     static_cast<float>(sent_.omega_rad_s), ++cmd_seq_};
  out->push_back(fwcan::EncodeSetBodyTwist(node_, t));
  counters_.frames_sent += static_cast<int64_t>(out->size());
}

void BaseBridge::OnFrame(const firmware::CanFrame& f, int64_t now_us) {
  FollowClock(now_us);
  if (fwcan::NodeOf(f.id) != node_) return;  // another node on the bus
  ++counters_.frames_in;
  bool ok = true;
  switch (fwcan::CommandOf(f.id)) {
    case fwcan::kHeartbeat: {
      fwcan::Heartbeat hb;
      if (!(ok = fwcan::DecodeHeartbeat(f, &hb))) break;
      if (have_hb_) {
        const double gap = static_cast<double>(now_us - last_hb_us_) * 1e-6;
        const int64_t missed = std::llround(gap / o_.firmware_heartbeat_period_s) - 1;
        if (missed > 0) counters_.missed_heartbeats += missed;
        // Silent as status() counts it (missed_heartbeats_for_silent periods): back now.
        if (now_us - last_hb_us_ >= SilenceUs()) FirmwareReturned();
      }
      have_hb_ = true;
      last_hb_us_ = now_us;
      fw_state_ = static_cast<int8_t>(hb.state);
      // A base stopped by its firmware (a fault, ESTOP) starts again from rest: the ramp must
      // not resume from the speed last sent, up to the limit at once. (Not its watchdog's
      // STOPPING: the base is still moving, slowing down, and the next command resumes it.)
      if (hb.state == static_cast<uint8_t>(firmware::State::kFault) ||
          hb.state == static_cast<uint8_t>(firmware::State::kEstop))
        sent_ = {};
      fw_faults_ = hb.fault_bits;
      bus_voltage_ = hb.bus_voltage_v;
      break;
    }
    case fwcan::kEncoderFeedback: {
      fwcan::EncoderFeedback e;
      if (!(ok = fwcan::DecodeEncoderFeedback(f, &e))) break;
      HandleEncoders(e, now_us);
      break;
    }
    case fwcan::kSpeedFeedback: {
      fwcan::WheelTriple s;
      if (!(ok = fwcan::DecodeWheelSpeeds(f, &s))) break;
      std::copy(s.v, s.v + 3, speed_);
      break;
    }
    case fwcan::kCurrentFeedback: {
      fwcan::WheelTriple s;
      if (!(ok = fwcan::DecodeCurrents(f, &s))) break;
      std::copy(s.v, s.v + 3, current_);
      break;
    }
    case fwcan::kSetpointFeedback: {
      fwcan::WheelTriple s;
      if (!(ok = fwcan::DecodeWheelSpeeds(f, &s))) break;
      std::copy(s.v, s.v + 3, setpoint_);
      break;
    }
    case fwcan::kBodyTwistFeedback: {
      fwcan::BodyTwist t;
      if (!(ok = fwcan::DecodeBodyTwist(f, &t))) break;
      odom_.vx_m_s = t.vx_m_s;
      odom_.vy_m_s = t.vy_m_s;
      odom_.omega_rad_s = t.omega_rad_s;
      break;
    }
    case fwcan::kParamValue: {
      fwcan::ParamReply r;
      if (!(ok = fwcan::DecodeParamReply(f, &r))) break;
      HandleParamReply(r);
      break;
    }
    case fwcan::kDiagnostics: {
      fwcan::Diagnostics d;
      if (!(ok = fwcan::DecodeDiagnostics(f, &d))) break;
      counters_.firmware_rx_unknown = d.rx_unknown;
      counters_.firmware_rx_bad_length = d.rx_bad_length;
      counters_.firmware_tx_dropped = d.tx_dropped;
      counters_.firmware_max_step_us = d.max_step_us;
      break;
    }
    case fwcan::kDiagnostics2: {
      fwcan::Diagnostics2 d;
      if (!(ok = fwcan::DecodeDiagnostics2(f, &d))) break;
      counters_.firmware_watchdog_trips = d.watchdog_trips;
      counters_.firmware_commands_limited = d.commands_limited;
      counters_.firmware_rx_overruns = d.rx_overruns;
      break;
    }
    default:
      ++counters_.unknown_frames;  // unknown, or a host->firmware command from someone else
      return;
  }
  if (!ok) ++counters_.can_rx_errors;
}

void BaseBridge::HandleParamReply(const firmware::can::ParamReply& r) {
  double ours = 0;
  const char* what = "";
  switch (r.id) {
    case firmware::kParamAlpha:
      ours = o_.alpha_rad;
      what = "alpha_rad";
      break;
    case firmware::kParamCenterToWheel:
      ours = o_.center_to_wheel_m;
      what = "center_to_wheel_m";
      break;
    case firmware::kParamWheelRadius:
      ours = o_.wheel_radius_m;
      what = "wheel_radius_m";
      break;
    case firmware::kParamTicksPerRev:
      ours = o_.ticks_per_rev;
      what = "ticks_per_rev";
      break;
    case firmware::kParamFeedbackPeriodMs:
      ours = o_.feedback_period_s * 1000.0;
      what = "feedback_period";
      break;
    case firmware::kParamHeartbeatPeriodMs:
      ours = o_.firmware_heartbeat_period_s * 1000.0;
      what = "heartbeat_period (timing.firmware_heartbeat_period_s, ms)";
      break;
    case firmware::kParamWatchdogMs:
      what = "watchdog_ms";
      break;
    default:
      return;
  }
  // An error answer (a firmware without that parameter) counts as answered: asking again every
  // second for ever would not change it, and there is nothing to compare.
  geometry_answered_ |= GeometryBit(r.id);
  geometry_checked_ = geometry_answered_ == kAllGeometryBits;
  if (r.result != fwcan::kParamOk) return;
  // The watchdog is not ours to match, only to leave room for: two send periods at least.
  const double send_period_ms = 1000.0 / o_.send_rate_hz;
  const bool differs = r.id == firmware::kParamWatchdogMs
                           ? r.value < 2.0 * send_period_ms
                           : std::fabs(r.value - ours) > 1e-4 * std::max(1.0, std::fabs(ours));
  if (differs) {
    std::ostringstream s;
    if (r.id == firmware::kParamWatchdogMs) {
      s << "firmware watchdog_ms = " << r.value << " is under two send periods ("
        << 2.0 * send_period_ms << " ms at timing.send_rate_hz " << o_.send_rate_hz
        << "): the base stops between commands";
    } else {
      s << "firmware " << what << " = " << r.value << " but config says " << ours;
    }
    auto [it, added] = mismatches_.insert_or_assign(r.id, s.str());
    (void)it;
    if (added) ++counters_.geometry_mismatches;  // counted once per parameter going wrong
  } else {
    mismatches_.erase(r.id);
  }
  last_mismatch_ = mismatches_.empty() ? std::string() : mismatches_.begin()->second;
}

int64_t BaseBridge::SilenceUs() const {
  return static_cast<int64_t>(
      std::llround(o_.missed_heartbeats_for_silent * o_.firmware_heartbeat_period_s * 1e6));
}

void BaseBridge::FirmwareReturned() {
  // Silent long enough to have restarted (a brown-out, a reflash): its counters may have
  // started again from zero, and its parameters may be others now.
  ++counters_.firmware_returns;
  have_enc_ = false;
  geometry_checked_ = false;
  geometry_answered_ = 0;
  sent_ = {};  // a board that restarted is at rest: ramp up from there
}

void BaseBridge::HandleEncoders(const firmware::can::EncoderFeedback& e, int64_t now_us) {
  // Feedback that stopped for the silence time (and for at least three of its own periods, so a
  // slow feedback rate is never taken for silence): re-base, whatever the sequence says (a
  // board up for more than 2^15 feedback periods restarts with a sequence that looks "ahead").
  const int64_t gap_us =
      std::max<int64_t>(SilenceUs(), static_cast<int64_t>(3.0 * o_.feedback_period_s * 1e6));
  if (have_enc_ && now_us - last_enc_us_ > gap_us) have_enc_ = false;
  // Re-basing after a gap (a silence, a link outage, a firmware return seen first in its
  // heartbeat): the gap's length by our clock goes into the firmware's time (its periods are
  // unknown). A restart told by the numbering starts it from 0 below.
  if (!have_enc_ && last_enc_us_ != 0 && now_us > last_enc_us_)
    mcu_time_us_ += now_us - last_enc_us_;
  last_enc_us_ = now_us;
  if (have_enc_) {
    const int32_t d = fwcan::FeedbackSeqStep(last_enc_seq_, e.seq);
    if (d == 0) return;  // duplicate
    if (d < 0) {
      // The firmware restarted (its cycle numbers never come back into 0-255 otherwise), or the
      // number went back: re-base before its counts, which started again, are taken as motion.
      ++counters_.firmware_restarts_seen;
      // As after a silence: its parameters may be others now (set, not saved, before the reset).
      FirmwareReturned();
      mcu_time_us_ = 0;
    } else {
      if (d > 1) counters_.feedback_frames_lost += d - 1;  // positions are absolute: no loss
      mcu_time_us_ += d * std::llround(o_.feedback_period_s * 1e6);
    }
  }
  if (!have_enc_) {
    for (int w = 0; w < 3; ++w) last_raw_[w] = e.position_low16[w];
    last_enc_seq_ = e.seq;
    have_enc_ = true;
    return;
  }
  last_enc_seq_ = e.seq;
  kinematics::WheelSpeeds<double> rim;  // rim displacement of each wheel, m
  const double m_per_tick = 2.0 * M_PI * o_.wheel_radius_m / o_.ticks_per_rev;
  for (int w = 0; w < 3; ++w) {
    const int16_t dt =
        static_cast<int16_t>(static_cast<uint16_t>(e.position_low16[w] - last_raw_[w]));
    last_raw_[w] = e.position_low16[w];
    ticks_[w] += dt;
    rim.v_m_s[w] = dt * m_per_tick;
  }
  // Forward kinematics is linear: wheel displacements -> body displacement.
  kinematics::BodyTwist<double> d;
  if (kinematics::WheelsToBody(geom_, rim, &d)) {
    const double mid = odom_.yaw_rad + 0.5 * d.omega_rad_s;
    odom_.x_m += std::cos(mid) * d.vx_m_s - std::sin(mid) * d.vy_m_s;
    odom_.y_m += std::sin(mid) * d.vx_m_s + std::cos(mid) * d.vy_m_s;
    odom_.yaw_rad = std::remainder(odom_.yaw_rad + d.omega_rad_s, 2.0 * M_PI);
    if (odom_.yaw_rad <= -M_PI) odom_.yaw_rad += 2.0 * M_PI;
    const double dist = std::hypot(d.vx_m_s, d.vy_m_s);
    odom_.pose_cov[0] += o_.odom_var_xy_per_m * dist;
    odom_.pose_cov[4] += o_.odom_var_xy_per_m * dist;
    odom_.pose_cov[8] += o_.odom_var_yaw_per_rad * std::fabs(d.omega_rad_s);
  }
  odom_.twist_cov[0] = odom_.twist_cov[4] = o_.twist_var_linear;
  odom_.twist_cov[8] = o_.twist_var_angular;
  odom_.utime = now_us;
  ++odom_.seq;
  odom_new_ = true;
  enc_.utime = now_us;
  enc_.seq = e.seq;
  enc_.mcu_time_us = mcu_time_us_;
  for (int w = 0; w < 3; ++w) {
    enc_.position_ticks[w] = ticks_[w];
    enc_.velocity_rad_s[w] = speed_[w];
    enc_.current_a[w] = current_[w];
  }
  enc_new_ = true;
}

void BaseBridge::OnLinkDown(int64_t now_us) {
  FollowClock(now_us);
  if (!link_up_) return;
  link_up_ = false;
  link_down_since_us_ = now_us;
  ++counters_.link_losses;
  have_enc_ = false;  // motion while the link is down is lost; re-base on the next frame
  have_hb_ = false;   // the link, not the firmware, was away: no "firmware returned" for it
  sending_ = false;
  sent_ = {};
  last_send_us_ = 0;
  // A clear not sent yet goes as one asked while down: not sent when the link is back, and the
  // ESTOP it would have released is latched again.
  if (pending_clear_) {
    ++counters_.clears_refused;
    estop_latched_ = estop_latched_ || latched_before_clear_;
  }
  pending_clear_ = false;
  latched_before_clear_ = false;
}

void BaseBridge::OnLinkUp(int64_t now_us) {
  FollowClock(now_us);
  if (link_up_) return;
  link_up_ = true;
  ++counters_.reconnects;
  geometry_checked_ = false;
  geometry_answered_ = 0;
}

bool BaseBridge::TakeOdometry(Odometry* out) {
  if (!odom_new_) return false;
  *out = odom_;
  odom_new_ = false;
  return true;
}

bool BaseBridge::TakeEncoders(Encoders* out) {
  if (!enc_new_) return false;
  *out = enc_;
  enc_new_ = false;
  return true;
}

int64_t BaseBridge::SilentForUs(int64_t now_us) const {
  return have_hb_ ? now_us - last_hb_us_ : -1;
}

BaseStatus BaseBridge::status(int64_t now_us) const {
  BaseStatus s;
  s.utime = now_us;
  s.state = have_hb_ ? fw_state_ : 0;
  s.fault_bits = static_cast<int32_t>(fw_faults_);
  const int64_t period_us = static_cast<int64_t>(o_.firmware_heartbeat_period_s * 1e6);
  const int64_t silent = SilentForUs(now_us);
  s.missed_heartbeats = silent > 0 ? static_cast<int32_t>(silent / period_us) : 0;
  s.firmware_alive = link_up_ && have_hb_ && s.missed_heartbeats < o_.missed_heartbeats_for_silent;
  s.bus_voltage_v = bus_voltage_;
  std::copy(speed_, speed_ + 3, s.wheel_speed_rad_s);
  std::copy(setpoint_, setpoint_ + 3, s.wheel_setpoint_rad_s);
  return s;
}

std::string BaseBridge::Problem(int64_t now_us) const {
  std::ostringstream s;
  if (!link_up_) {
    s << "CAN " << o_.can_url << " down for " << (now_us - link_down_since_us_) / 1000 << " ms";
    return s.str();
  }
  const BaseStatus st = status(now_us);
  if (!have_hb_) return "no firmware heartbeat yet";
  if (!st.firmware_alive) {
    s << "firmware silent: " << st.missed_heartbeats << " heartbeats missed";
    return s.str();
  }
  if (fw_faults_ & firmware::kLatchedFaults) {
    s << "firmware fault bits 0x" << std::hex << fw_faults_;
    return s.str();
  }
  return last_mismatch_;
}

}  // namespace omni::base_bridge
