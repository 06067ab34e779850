// The base bridge process's bus side: subscribes to BASE_CMD, owns the CAN bus (re-opening it
// when it goes away), publishes WHEEL_ODOM, WHEEL_ENCODERS, BASE_STATUS and the heartbeat.
#pragma once

#include <atomic>
#include <memory>

#include "omni/base_bridge/base_bridge.h"
#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/can/can_bus.h"
#include "omni/common/time.h"

namespace omni::base_bridge {

class BaseBridgeNode {
 public:
  BaseBridgeNode(const BaseBridgeOptions& options, bus::Bus* bus, const Clock* clock);
  // Runs until *stop becomes true (or for max_s seconds if > 0).
  void Run(const std::atomic<bool>* stop, double max_s = -1);
  // One iteration (waits at most ~2 ms for CAN traffic). Public for tests.
  void SpinOnce();
  const BaseBridge& bridge() const { return bridge_; }
  const SlipMonitor& slip() const { return slip_; }

 private:
  void TryOpen(int64_t now_us);
  void Publish(int64_t now_us);

  BaseBridgeOptions o_;
  bus::Bus* bus_;
  const Clock* clock_;
  BaseBridge bridge_;
  SlipMonitor slip_;
  bool slip_logged_ = false;  // for the log lines
  int64_t fw_overruns_logged_ = 0;
  bus::Heartbeat heartbeat_;
  std::unique_ptr<can::CanBus> can_;
  int64_t last_open_try_us_ = 0;
  int64_t tx_errors_ = 0;  // CAN sends that failed (queue full, interface gone)
  int64_t last_tx_error_log_us_ = 0;
  int64_t last_status_us_ = 0;
  bool fw_alive_logged_ = false, fw_alive_ever_ = false;  // for the log lines
  bool ever_opened_ = false;
  std::string open_error_;
};

}  // namespace omni::base_bridge
