// Bus side of the IMU driver: publishes each sample as omni.imu_t (channel IMU by default) and a
// heartbeat with the driver's counters (messages, frames, checksum errors, resyncs, bytes
// skipped, unconfirmed frames, reconnects, connect failures, timeouts, dropped frames, incomplete
// samples, settings written and confirmed / failed, rate mismatches, cycle re-learns, clock
// steps back, the measured rate rounded to 1 Hz).
#pragma once

#include <atomic>
#include <cstdint>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/imu/driver.h"
#include "omni/imu_t.hpp"

namespace omni::imu {

// The message for one sample (pure function, for tests and replays).
omni::imu_t MakeImuMessage(const StampedSample& s, int64_t seq, const NodeOptions& node);

class ImuNode {
 public:
  ImuNode(bus::Bus* bus, ImuDriver* driver, NodeOptions options, const Clock* clock);
  ImuNode(const ImuNode&) = delete;  // the heartbeat's counters point into this object
  ImuNode& operator=(const ImuNode&) = delete;
  // One driver step (at most `timeout_ms`), publications and the heartbeat.
  void RunOnce(int timeout_ms);
  // Until *stop (or `max_s` seconds when > 0).
  void Run(const std::atomic<bool>* stop, double max_s = -1);
  int64_t published() const { return seq_; }

 private:
  bus::Bus* bus_;
  ImuDriver* driver_;
  NodeOptions options_;
  bus::Heartbeat heartbeat_;
  int64_t seq_ = 0;
  int64_t relearns_published_ = 0;  // cycle_relearns when the last heartbeat went out
};

}  // namespace omni::imu
