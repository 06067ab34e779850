#include "omni/imu/imu_node.h"

#include <cmath>
#include <limits>

#include "omni/heartbeat_t.hpp"

namespace omni::imu {
namespace {

void Diagonal(const std::array<double, 3>& var, double out[9]) {
  for (int i = 0; i < 9; ++i) out[i] = 0;
  for (int i = 0; i < 3; ++i) out[4 * i] = var[static_cast<size_t>(i)];
}

}  // namespace

omni::imu_t MakeImuMessage(const StampedSample& s, int64_t seq, const NodeOptions& node) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const ImuSample& x = s.sample;
  omni::imu_t m;
  m.utime = s.utime;
  m.seq = seq;
  m.frame = node.frame;
  for (size_t i = 0; i < 4; ++i) m.orientation_wxyz[i] = x.orientation_wxyz[i];
  for (size_t i = 0; i < 3; ++i) {
    m.angular_velocity_rad_s[i] = x.gyro_rad_s[i];
    m.linear_acceleration_m_s2[i] = x.accel_m_s2[i];
    m.magnetic_field_t[i] =
        (x.has_mag && node.mag_tesla_per_lsb > 0) ? x.mag_raw[i] * node.mag_tesla_per_lsb : nan;
  }
  Diagonal(node.orientation_var, m.orientation_covariance);
  if (!x.has_orientation) {
    m.orientation_covariance[0] = -1;  // imu_t: "not provided"
  }
  Diagonal(node.angular_velocity_var, m.angular_velocity_covariance);
  Diagonal(node.linear_acceleration_var, m.linear_acceleration_covariance);
  m.temperature_c = x.has_temperature ? static_cast<float>(x.temperature_c)
                                      : std::numeric_limits<float>::quiet_NaN();
  return m;
}

ImuNode::ImuNode(bus::Bus* bus, ImuDriver* driver, NodeOptions options, const Clock* clock)
    : bus_(bus),
      driver_(driver),
      options_(std::move(options)),
      heartbeat_(bus, "imu_driver", clock) {
  const ImuDriver* d = driver_;
  heartbeat_.AddCounter("messages", [this] { return seq_; });
  heartbeat_.AddCounter("frames", [d] { return d->frame_counters().frames; });
  heartbeat_.AddCounter("checksum_errors", [d] { return d->frame_counters().checksum_errors; });
  heartbeat_.AddCounter("resyncs", [d] { return d->frame_counters().resyncs; });
  heartbeat_.AddCounter("bytes_skipped", [d] { return d->frame_counters().bytes_skipped; });
  heartbeat_.AddCounter("unconfirmed", [d] { return d->frame_counters().unconfirmed; });
  heartbeat_.AddCounter("reconnects", [d] { return d->counters().reconnects; });
  heartbeat_.AddCounter("connect_failures", [d] { return d->counters().connect_failures; });
  heartbeat_.AddCounter("timeouts", [d] { return d->counters().timeouts; });
  heartbeat_.AddCounter("dropped_frames", [d] { return d->counters().dropped_frames; });
  heartbeat_.AddCounter("incomplete_samples", [d] { return d->counters().incomplete_samples; });
  heartbeat_.AddCounter("configurations", [d] { return d->counters().configurations; });
  heartbeat_.AddCounter("config_failures", [d] { return d->counters().config_failures; });
  heartbeat_.AddCounter("rate_mismatches", [d] { return d->counters().rate_mismatches; });
  heartbeat_.AddCounter("cycle_relearns", [d] { return d->counters().cycle_relearns; });
  heartbeat_.AddCounter("clock_steps_back", [d] { return d->counters().clock_steps_back; });
  heartbeat_.AddCounter("measured_rate_hz",
                        [d] { return static_cast<int64_t>(std::lround(d->measured_rate_hz())); });
}

void ImuNode::RunOnce(int timeout_ms) {
  std::vector<StampedSample> samples;
  driver_->Step(timeout_ms, &samples);
  for (const StampedSample& s : samples) {
    bus_->Publish(options_.channel, MakeImuMessage(s, seq_, options_));
    ++seq_;
  }
  // DEGRADED while no sample closes after a re-learn of the frame cycle, and in at least one
  // heartbeat after each re-learn, however soon the samples come back.
  const int64_t relearns = driver_->counters().cycle_relearns;
  if (driver_->state() != DriverState::kStreaming) {
    heartbeat_.SetState(omni::heartbeat_t::STATE_ERROR,
                        "device lost, retrying: " + driver_->status_text());
  } else if (driver_->degraded() || relearns != relearns_published_) {
    heartbeat_.SetState(omni::heartbeat_t::STATE_DEGRADED, driver_->relearn_reason());
  } else {
    heartbeat_.SetState(omni::heartbeat_t::STATE_OK, driver_->status_text());
  }
  if (heartbeat_.Tick()) relearns_published_ = relearns;
}

void ImuNode::Run(const std::atomic<bool>* stop, double max_s) {
  const int64_t start = MonotonicMicros();
  while (!stop->load()) {
    if (max_s > 0 && MonotonicMicros() - start > SecondsToUtime(max_s)) break;
    RunOnce(50);
  }
  heartbeat_.SetState(omni::heartbeat_t::STATE_STOPPING, "stopping");
  heartbeat_.Tick(true);
  driver_->Shutdown();
}

}  // namespace omni::imu
