#include "omni/base_bridge/base_bridge_node.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "omni/base_bridge/messages.h"
#include "omni/base_cmd_t.hpp"
#include "omni/common/log.h"
#include "omni/heartbeat_t.hpp"
#include "omni/imu_t.hpp"

namespace omni::base_bridge {

BaseBridgeNode::BaseBridgeNode(const BaseBridgeOptions& options, bus::Bus* bus, const Clock* clock)
    : o_(options),
      bus_(bus),
      clock_(clock),
      bridge_(options),
      slip_(options.slip),
      heartbeat_(bus, "base_bridge", clock) {
  bus_->Subscribe<omni::base_cmd_t>(o_.cmd_channel, [this](const omni::base_cmd_t& m, int64_t) {
    bridge_.OnCommand(FromMessage(m), clock_->NowUtime());
  });
  if (o_.slip.enabled) {
    // The IMU driver stamps with this machine's clock, as the bridge stamps its odometry.
    bus_->Subscribe<omni::imu_t>(o_.imu_channel, [this](const omni::imu_t& m, int64_t) {
      (void)slip_.AddGyro(m.utime, m.angular_velocity_rad_s[2]);
    });
    const SlipCounters* sc = &slip_.counters();
    heartbeat_.AddCounter("imu_in", [sc] { return sc->gyro_in; });
    heartbeat_.AddCounter("imu_rejected", [sc] { return sc->gyro_rejected; });
    heartbeat_.AddCounter("slip_windows", [sc] { return sc->windows; });
    heartbeat_.AddCounter("slip_windows_slipping", [sc] { return sc->slip_windows; });
    heartbeat_.AddCounter("slip_events", [sc] { return sc->slip_events; });
    heartbeat_.AddCounter("slip_time_rebases", [sc] { return sc->time_rebases; });
    heartbeat_.AddCounter("slip_odom_duplicates", [sc] { return sc->odom_duplicates; });
    heartbeat_.AddCounter("slipping", [this] { return int64_t{slip_.slipping() ? 1 : 0}; });
    heartbeat_.AddCounter("gyro_bias_samples", [this] { return slip_.bias_samples(); });
    heartbeat_.AddCounter("gyro_bias_uncovered", [this] { return slip_.bias_uncovered(); });
    heartbeat_.AddCounter("gyro_bias_urad_s", [this] {
      return static_cast<int64_t>(std::llround(slip_.gyro_bias() * 1e6));
    });
  }
  const Counters* c = &bridge_.counters();
  heartbeat_.AddCounter("commands_clamped", [c] { return c->commands_clamped; });
  heartbeat_.AddCounter("accel_limited", [c] { return c->accel_limited; });
  heartbeat_.AddCounter("commands_rejected", [c] { return c->commands_rejected; });
  heartbeat_.AddCounter("commands_in_estop", [c] { return c->commands_in_estop; });
  heartbeat_.AddCounter("commands_expired", [c] { return c->commands_expired; });
  heartbeat_.AddCounter("firmware_restarts_seen", [c] { return c->firmware_restarts_seen; });
  heartbeat_.AddCounter("estops_sent", [c] { return c->estops_sent; });
  heartbeat_.AddCounter("can_rx_errors", [c] { return c->can_rx_errors; });
  heartbeat_.AddCounter("unknown_frames", [c] { return c->unknown_frames; });
  heartbeat_.AddCounter("missed_fw_heartbeats", [c] { return c->missed_heartbeats; });
  heartbeat_.AddCounter("feedback_frames_lost", [c] { return c->feedback_frames_lost; });
  heartbeat_.AddCounter("reconnects", [c] { return c->reconnects; });
  heartbeat_.AddCounter("link_losses", [c] { return c->link_losses; });
  heartbeat_.AddCounter("geometry_mismatches", [c] { return c->geometry_mismatches; });
  heartbeat_.AddCounter("firmware_returns", [c] { return c->firmware_returns; });
  heartbeat_.AddCounter("fw_rx_unknown", [c] { return c->firmware_rx_unknown; });
  heartbeat_.AddCounter("fw_rx_bad_length", [c] { return c->firmware_rx_bad_length; });
  heartbeat_.AddCounter("fw_tx_dropped", [c] { return c->firmware_tx_dropped; });
  heartbeat_.AddCounter("fw_max_step_us", [c] { return c->firmware_max_step_us; });
  heartbeat_.AddCounter("fw_watchdog_trips", [c] { return c->firmware_watchdog_trips; });
  heartbeat_.AddCounter("fw_commands_limited", [c] { return c->firmware_commands_limited; });
  heartbeat_.AddCounter("fw_rx_overruns", [c] { return c->firmware_rx_overruns; });
  heartbeat_.AddCounter("clock_steps_back", [c] { return c->clock_steps_back; });
  heartbeat_.AddCounter("clears_refused", [c] { return c->clears_refused; });
  heartbeat_.AddCounter("can_tx_errors", [this] { return tx_errors_; });
  heartbeat_.AddCounter("can_rx_overruns",
                        [this] { return can_ ? can_->stats().rx_overruns : int64_t{0}; });
  heartbeat_.SetState(omni::heartbeat_t::STATE_STARTING, "opening " + o_.can_url);
}

void BaseBridgeNode::TryOpen(int64_t now_us) {
  last_open_try_us_ = now_us;
  auto r = can::OpenCanBus(o_.can_url);
  if (!r.ok()) {
    if (open_error_ != r.error().message) {
      LOG_WARN << r.error().ToString() << " (retrying)";
    }
    open_error_ = r.error().message;
    return;
  }
  can_ = std::move(r).value();
  open_error_.clear();
  LOG_INFO << "CAN " << can_->name() << " open";
  if (ever_opened_) bridge_.OnLinkUp(now_us);
  ever_opened_ = true;
}

void BaseBridgeNode::SpinOnce() {
  int64_t now = clock_->NowUtime();
  if (!can_ &&
      PeriodDue(now, last_open_try_us_, static_cast<int64_t>(o_.reconnect_period_s * 1e6))) {
    TryOpen(now);
    if (!can_ && !ever_opened_) {
      ever_opened_ = true;  // the first failure counts as a link loss, later successes reconnect
      bridge_.OnLinkDown(now);
    }
  }
  // Bus commands first (non-blocking), then CAN with a short wait.
  while (bus_->HandleTimeout(0) > 0) {
  }
  if (can_) {
    can::Frame f;
    for (int n = 0; n < 256; ++n) {
      auto r = can_->Receive(&f, n == 0 ? 2 : 0);
      if (!r.ok()) {
        LOG_WARN << r.error().ToString();
        can_.reset();
        bridge_.OnLinkDown(clock_->NowUtime());
        break;
      }
      if (!r.value()) break;
      if (f.extended || f.rtr) {
        bridge_.OnForeignFrame();  // not our protocol's: counted with the unknown frames
        continue;
      }
      firmware::CanFrame ff;
      ff.id = static_cast<uint16_t>(f.id);
      ff.dlc = f.dlc;
      std::copy(f.data, f.data + 8, ff.data);
      bridge_.OnFrame(ff, clock_->NowUtime());
    }
  } else {
    struct timespec ts {
      0, 2000000
    };
    nanosleep(&ts, nullptr);
  }
  now = clock_->NowUtime();
  std::vector<firmware::CanFrame> out;
  bridge_.Tick(now, &out);
  for (const auto& ff : out) {
    if (!can_) break;
    can::Frame f;
    f.id = ff.id;
    f.dlc = ff.dlc;
    std::copy(ff.data, ff.data + 8, f.data);
    const omni::Status s = can_->Send(f);
    if (!s.ok()) {
      // At 100 Hz a full queue (a bus-off controller, no one acking) would be 100 lines a
      // second: the first, then one every 5 s with the count.
      ++tx_errors_;
      if (PeriodDue(now, last_tx_error_log_us_, 5000000)) {
        LOG_WARN << s.error().ToString() << " (" << tx_errors_ << " send errors so far)";
        last_tx_error_log_us_ = now;
      }
      if (s.error().code == ErrorCode::kUnavailable) {
        can_.reset();
        bridge_.OnLinkDown(now);
      }
    }
  }
  Publish(now);
}

void BaseBridgeNode::Publish(int64_t now) {
  Odometry od;
  if (bridge_.TakeOdometry(&od)) {
    bus_->Publish(o_.odom_channel, ToMessage(od, o_));
    if (o_.slip.enabled) slip_.AddOdometry(od.utime, Pose2(od.x_m, od.y_m, od.yaw_rad));
  }
  Encoders en;
  if (bridge_.TakeEncoders(&en)) bus_->Publish(o_.encoders_channel, ToMessage(en, o_));
  if (PeriodDue(now, last_status_us_, static_cast<int64_t>(1e6 / o_.status_rate_hz))) {
    last_status_us_ = now;
    const BaseStatus s = bridge_.status(now);
    bus_->Publish(o_.status_channel, ToMessage(s, bridge_.counters()));
    // Say it in the log too when the firmware goes silent or comes back.
    if (s.firmware_alive != fw_alive_logged_) {
      if (s.firmware_alive) {
        LOG_INFO << "firmware answering"
                 << (fw_alive_ever_ ? " again (encoders re-based, geometry re-checked)" : "");
      } else if (fw_alive_ever_ && bridge_.link_up()) {
        LOG_WARN << "firmware silent: " << s.missed_heartbeats << " heartbeats missed";
      }
      fw_alive_ever_ = fw_alive_ever_ || s.firmware_alive;
      fw_alive_logged_ = s.firmware_alive;
    }
    // Frames lost on the board: its receive FIFO overran (the host sends faster than the
    // firmware reads, or the board stalled). Said once per rise of the firmware's count.
    const int64_t overruns = bridge_.counters().firmware_rx_overruns;
    if (overruns > fw_overruns_logged_) {
      LOG_WARN << "base firmware: its CAN receive FIFO overran (" << overruns
               << " times since boot): frames to it were lost";
    }
    fw_overruns_logged_ = overruns;
    if (slip_.slipping() != slip_logged_) {
      if (slip_.slipping()) {
        LOG_WARN << slip_.Problem();
      } else {
        LOG_INFO << "wheels grip again";
      }
      slip_logged_ = slip_.slipping();
    }
    std::string problem = bridge_.Problem(now);
    if (slip_.slipping()) problem += (problem.empty() ? "" : "; ") + slip_.Problem();
    if (problem.empty()) {
      heartbeat_.SetState(omni::heartbeat_t::STATE_OK, "ok");
    } else {
      const bool broken = !bridge_.link_up() || !s.firmware_alive;
      heartbeat_.SetState(
          broken ? omni::heartbeat_t::STATE_ERROR : omni::heartbeat_t::STATE_DEGRADED, problem);
    }
  }
  heartbeat_.Tick();
}

void BaseBridgeNode::Run(const std::atomic<bool>* stop, double max_s) {
  const int64_t start = MonotonicMicros();
  while (!stop->load()) {
    SpinOnce();
    if (max_s > 0 && (MonotonicMicros() - start) * 1e-6 > max_s) break;
  }
  heartbeat_.SetState(omni::heartbeat_t::STATE_STOPPING, "stopping");
  heartbeat_.Tick(/*force=*/true);
}

}  // namespace omni::base_bridge
