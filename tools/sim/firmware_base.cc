#include "omni/sim/firmware_base.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "omni/base_bridge/messages.h"

namespace omni::sim {
namespace {

firmware::sim::PlantParams PlantFor(double center_to_wheel_m, double wheel_radius_m) {
  firmware::sim::PlantParams p;
  p.center_to_wheel_m = center_to_wheel_m;
  p.wheel_radius_m = wheel_radius_m;
  return p;
}

// The simulated board is set up as the bridge's config expects (a robot's board is set so with
// omni base-param): its timing too, which the bridge checks at connect (--bridge-config with
// another heartbeat period or a slow send rate ended the run "unhealthy" otherwise).
firmware::Params FirmwareFor(const base_bridge::BaseBridgeOptions& bo) {
  firmware::Params p;
  p.center_to_wheel_m = static_cast<float>(bo.center_to_wheel_m);
  p.wheel_radius_m = static_cast<float>(bo.wheel_radius_m);
  p.heartbeat_period_ms =
      static_cast<uint32_t>(std::lround(bo.firmware_heartbeat_period_s * 1000.0));
  p.feedback_period_ms = static_cast<uint32_t>(std::lround(bo.feedback_period_s * 1000.0));
  p.watchdog_ms = std::max<uint32_t>(
      p.watchdog_ms, static_cast<uint32_t>(std::ceil(2.0 * 1000.0 / bo.send_rate_hz)));
  return p;
}

base_bridge::BaseBridgeOptions BridgeFor(base_bridge::BaseBridgeOptions o, double center_to_wheel_m,
                                         double wheel_radius_m) {
  const firmware::sim::PlantParams plant = PlantFor(center_to_wheel_m, wheel_radius_m);
  o.can_url = "sim:in-process";
  o.center_to_wheel_m = center_to_wheel_m;
  o.wheel_radius_m = wheel_radius_m;
  o.alpha_rad = plant.alpha_rad;
  o.ticks_per_rev = plant.ticks_per_rev;
  return o;
}

}  // namespace

base_bridge::BaseBridgeOptions FirmwareBase::ShippedBridgeOptions() {
  // config/base_bridge.yaml's limits (the struct's defaults are more conservative); the rest
  // of that file is the struct's defaults.
  base_bridge::BaseBridgeOptions o;
  o.max_vx_m_s = 1.2;
  o.max_vy_m_s = 1.2;
  o.max_omega_rad_s = 3.0;
  o.max_linear_accel_m_s2 = 2.0;
  o.max_angular_accel_rad_s2 = 6.0;
  return o;
}

FirmwareBase::FirmwareBase(double center_to_wheel_m, double wheel_radius_m,
                           const base_bridge::BaseBridgeOptions& bridge)
    : bo_(BridgeFor(bridge, center_to_wheel_m, wheel_radius_m)),
      plant_(PlantFor(center_to_wheel_m, wheel_radius_m)),
      hal_(&plant_),
      fw_(&hal_, FirmwareFor(bo_)),
      bridge_(bo_) {
  hal_.UseClock(&clock_us_);
  hal_.tx_mailboxes = 3;  // as the board's bxCAN
  booted_ = fw_.Init() == firmware::FwStatus::kOk;
}

bool FirmwareBase::booted(std::string* why) const {
  if (!booted_ && why != nullptr)
    *why =
        "the base firmware refused its parameters (center_to_wheel_m or wheel_radius_m out "
        "of range)";
  return booted_;
}

void FirmwareBase::Advance(const kinematics::BodyTwist<double>* cmd, int64_t now_us, double dt_s,
                           const std::function<void(const SimEvent&)>& sink) {
  if (cmd != nullptr) {
    base_bridge::Command c;
    c.vx_m_s = cmd->vx_m_s;
    c.vy_m_s = cmd->vy_m_s;
    c.omega_rad_s = cmd->omega_rad_s;
    bridge_.OnCommand(c, now_us);
  }
  const int64_t period_us = fw_.params().control_period_us;
  const double period_s = static_cast<double>(period_us) * 1e-6;
  pending_us_ += std::llround(dt_s * 1e6);
  int64_t t = now_us;
  std::vector<firmware::CanFrame> out;
  while (pending_us_ >= period_us) {
    pending_us_ -= period_us;
    // Host to firmware: whatever the bridge sends in this period reaches the controller's FIFO.
    out.clear();
    bridge_.Tick(t, &out);
    for (const auto& f : out) hal_.Deliver(f);
    stats_.frames_to_firmware += static_cast<int64_t>(out.size());
    clock_us_ = t;
    if (booted_) fw_.Step();
    plant_.Advance(period_s);
    t += period_us;
    // Firmware to host: the frames of this period arrive at its end.
    while (!hal_.tx.empty()) {
      bridge_.OnFrame(hal_.tx.front(), t);
      hal_.tx.pop_front();
      ++stats_.frames_from_firmware;
    }
    base_bridge::Odometry od;
    if (bridge_.TakeOdometry(&od)) {
      sink(EncodeEvent(bo_.odom_channel, t, base_bridge::ToMessage(od, bo_)));
      ++stats_.odometry;
    }
    base_bridge::Encoders en;
    if (bridge_.TakeEncoders(&en)) {
      sink(EncodeEvent(bo_.encoders_channel, t, base_bridge::ToMessage(en, bo_)));
      ++stats_.encoders;
    }
    if (t - last_status_us_ >= static_cast<int64_t>(1e6 / bo_.status_rate_hz)) {
      last_status_us_ = t;
      sink(EncodeEvent(bo_.status_channel, t,
                       base_bridge::ToMessage(bridge_.status(t), bridge_.counters())));
      ++stats_.status;
    }
  }
}

Pose2 FirmwareBase::pose() const {
  return Pose2(plant_.x_m(), plant_.y_m(), WrapAngle(plant_.theta_rad()));
}

}  // namespace omni::sim
