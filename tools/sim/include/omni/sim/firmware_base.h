// The simulated base as the robot has it: the base controller's firmware core (firmware/src:
// eq. (3) inverse kinematics, the per-wheel PI speed loops, the watchdog, the CAN protocol) on
// the motor-and-wheel plant model (firmware/platform/host), linked by CAN frames in memory to
// the host's base bridge (drivers/base_bridge), whose odometry, encoder and status messages are
// what the stack receives. Everything steps in simulated time, so a run is deterministic and
// runs faster than real time.
//
// The simulator's waypoint follower commands a body twist, as a planner would on BASE_CMD; the
// bridge clamps and ramps it and sends SET_BODY_TWIST at its rate, the firmware turns it into
// wheel speeds and tracks them, the plant moves the base (with per-wheel slip: the encoders see
// the motor, the ground sees less), and the true pose is the plant's.
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "host_hal.h"
#include "omni/base_bridge/base_bridge.h"
#include "omni/common/geometry.h"
#include "omni/common/kinematics.h"
#include "omni/firmware/firmware.h"
#include "omni/sim/event.h"
#include "plant.h"

namespace omni::sim {

struct FirmwareBaseStats {
  int64_t frames_to_firmware = 0;
  int64_t frames_from_firmware = 0;
  int64_t odometry = 0, encoders = 0, status = 0;  // bus messages produced
};

class FirmwareBase {
 public:
  // The bridge's limits, timing, odometry covariances and channels as config/base_bridge.yaml
  // ships them (a test checks that they agree), for a base of the given geometry.
  static base_bridge::BaseBridgeOptions ShippedBridgeOptions();

  // Boots the firmware with the simulated base's geometry. The bridge runs with `bridge`'s
  // limits, timing, covariances and channels; its geometry (and encoder resolution) is always
  // the plant's, whatever `bridge` says, since those describe the simulated base, not a robot.
  FirmwareBase(double center_to_wheel_m, double wheel_radius_m,
               const base_bridge::BaseBridgeOptions& bridge = ShippedBridgeOptions());

  // False (with the reason) if the firmware refused its parameters at boot.
  bool booted(std::string* why) const;

  // A command from the host (BASE_CMD: twist, e-stop, clear faults) arriving at now_us, for a
  // caller that drives the base itself; Advance(nullptr, ...) then steps without a new one.
  void OnCommand(const base_bridge::Command& cmd, int64_t now_us) {
    bridge_.OnCommand(cmd, now_us);
  }

  // Advances dt_s of simulated time from now_us with the host's twist command issued at now_us
  // (nullptr: no command, as when the planner goes quiet; the bridge then ramps down and stops
  // sending, and the firmware's watchdog parks the motors). The bridge's bus messages (WHEEL_ODOM,
  // WHEEL_ENCODERS, BASE_STATUS) go to `sink`, stamped when the bridge produced them, in (now_us,
  // now_us + dt_s].
  void Advance(const kinematics::BodyTwist<double>* cmd, int64_t now_us, double dt_s,
               const std::function<void(const SimEvent&)>& sink);

  // True pose of the base in its start frame (the plant's ground-contact integration).
  Pose2 pose() const;
  // Fraction of rim motion wheel w loses at its contact (the encoders do not see it).
  void SetSlip(int w, double slip) { plant_.SetSlip(w, slip); }

  const firmware::Firmware& firmware() const { return fw_; }
  const base_bridge::BaseBridge& bridge() const { return bridge_; }
  const base_bridge::BaseBridgeOptions& bridge_options() const { return bo_; }
  const FirmwareBaseStats& stats() const { return stats_; }
  // The bridge's health text at `now_us` ("" when all is well), as its heartbeat reports it.
  std::string Problem(int64_t now_us) const { return bridge_.Problem(now_us); }

 private:
  base_bridge::BaseBridgeOptions bo_;
  firmware::sim::Plant plant_;
  firmware::sim::HostHal hal_;
  firmware::Firmware fw_;
  base_bridge::BaseBridge bridge_;
  bool booted_ = false;
  int64_t clock_us_ = 0;    // the firmware's microsecond clock (simulated)
  int64_t pending_us_ = 0;  // simulated time not yet covered by a control period
  int64_t last_status_us_ = 0;
  FirmwareBaseStats stats_;
};

}  // namespace omni::sim
