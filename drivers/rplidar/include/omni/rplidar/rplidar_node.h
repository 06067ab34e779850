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
  // The next sequence number: scans published plus revolutions missed (the number skips
  // them, so that the mappers' scans_lost counts them).
  int64_t published() const { return seq_; }
  int64_t revolutions_missed() const { return revolutions_missed_; }
  // Streaming without a whole revolution for this long (a motor that does not turn under a
  // forced scan, noise that decodes to nothing) makes the heartbeat DEGRADED.
  static constexpr double kNoRevolutionS = 1.0;

 private:
  bus::Bus* bus_;
  RplidarDriver* driver_;
  NodeOptions options_;
  const Clock* clock_;
  bus::Heartbeat heartbeat_;
  int64_t seq_ = 0;
  int64_t revolutions_missed_ = 0;
  int64_t last_scan_utime_ = -1;   // the last published scan's stamp
  double last_scan_time_s_ = 0;    // and its revolution time
  int64_t last_publish_mono_ = 0;  // monotonic time it was published
  int64_t progress_us_ = -1;       // monotonic: the last revolution, or when streaming began
};

}  // namespace omni::rplidar
