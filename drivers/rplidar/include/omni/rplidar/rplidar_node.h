// Bus side of the RPLidar driver: publishes each revolution as omni.laser_scan_t and a
// heartbeat with the driver's counters (samples, check-bit and checksum errors, resyncs,
// reconnects, timeouts, dropped samples).
#pragma once

#include <atomic>
#include <cstdint>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/laser_scan_t.hpp"
#include "omni/rplidar/driver.h"

namespace omni::rplidar {

// The message for one revolution (pure function, for tests and replays).
omni::laser_scan_t MakeLaserScan(const PlanarScan& scan, int64_t seq, const NodeOptions& node,
                                 const ScanOptions& options);

class RplidarNode {
 public:
  RplidarNode(bus::Bus* bus, RplidarDriver* driver, NodeOptions options, const Clock* clock);
  // One driver step (at most `timeout_ms`), publications and the heartbeat.
  void RunOnce(int timeout_ms);
  // Until *stop (or `max_s` seconds when > 0).
  void Run(const std::atomic<bool>* stop, double max_s = -1);
  int64_t published() const { return seq_; }

 private:
  bus::Bus* bus_;
  RplidarDriver* driver_;
  NodeOptions options_;
  const Clock* clock_;
  bus::Heartbeat heartbeat_;
  int64_t seq_ = 0;
};

}  // namespace omni::rplidar
