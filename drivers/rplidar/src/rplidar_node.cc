#include "omni/rplidar/rplidar_node.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "omni/bus/channels.h"
#include "omni/heartbeat_t.hpp"

namespace omni::rplidar {

omni::laser_scan_t MakeLaserScan(const PlanarScan& scan, int64_t seq, const NodeOptions& node,
                                 const ScanOptions& options) {
  omni::laser_scan_t m;
  m.utime = scan.utime;
  m.seq = seq;
  m.frame = node.frame;
  m.sensor_x_m = node.mount_x_m;
  m.sensor_y_m = node.mount_y_m;
  m.sensor_yaw_rad = node.mount_yaw_rad;
  m.angle_min_rad = static_cast<float>(scan.angle_min_rad);
  m.angle_increment_rad = static_cast<float>(scan.angle_increment_rad);
  m.scan_time_s = static_cast<float>(scan.scan_time_s);
  m.range_min_m = static_cast<float>(options.range_min_m);
  m.range_max_m = static_cast<float>(options.range_max_m);
  m.num_ranges = static_cast<int32_t>(scan.ranges_m.size());
  m.ranges_m = scan.ranges_m;
  m.num_intensities = static_cast<int32_t>(scan.intensities.size());
  m.intensities = scan.intensities;
  return m;
}

RplidarNode::RplidarNode(bus::Bus* bus, RplidarDriver* driver, NodeOptions options,
                         const Clock* clock)
    : bus_(bus),
      driver_(driver),
      options_(std::move(options)),
      clock_(clock),
      heartbeat_(bus, "rplidar_driver", clock) {
  const RplidarDriver* d = driver_;
  heartbeat_.AddCounter("revolutions", [d] { return d->counters().revolutions; });
  heartbeat_.AddCounter("samples", [d] { return d->parser_counters().samples; });
  heartbeat_.AddCounter("checkbit_errors", [d] { return d->parser_counters().checkbit_errors; });
  heartbeat_.AddCounter("checksum_errors", [d] { return d->parser_counters().checksum_errors; });
  heartbeat_.AddCounter("resyncs", [d] { return d->parser_counters().resyncs; });
  heartbeat_.AddCounter("bytes_skipped", [d] { return d->parser_counters().bytes_skipped; });
  heartbeat_.AddCounter("bad_angles", [d] { return d->parser_counters().bad_angles; });
  heartbeat_.AddCounter("angle_jumps", [d] { return d->parser_counters().angle_jumps; });
  heartbeat_.AddCounter("unconfirmed", [d] { return d->parser_counters().unconfirmed; });
  heartbeat_.AddCounter("implied_starts", [d] { return d->assembler().implied_starts(); });
  heartbeat_.AddCounter("partial_samples_dropped",
                        [d] { return d->assembler().partial_samples_dropped(); });
  heartbeat_.AddCounter("reconnects", [d] { return d->counters().reconnects; });
  heartbeat_.AddCounter("connect_failures", [d] { return d->counters().connect_failures; });
  heartbeat_.AddCounter("timeouts", [d] { return d->counters().timeouts; });
  heartbeat_.AddCounter("health_resets", [d] { return d->counters().health_resets; });
  heartbeat_.AddCounter("dtr_failures", [d] { return d->counters().dtr_failures; });
  heartbeat_.AddCounter("dropped_samples", [d] { return d->counters().dropped_samples; });
  heartbeat_.AddCounter("samples_without_turn",
                        [d] { return d->assembler().samples_without_turn(); });
  heartbeat_.AddCounter("revolutions_missed", [this] { return revolutions_missed_; });
}

void RplidarNode::RunOnce(int timeout_ms) {
  std::vector<std::vector<Sample>> revolutions;
  driver_->Step(timeout_ms, &revolutions);
  const int64_t read_mono = MonotonicMicros();
  for (const auto& rev : revolutions) {
    const PlanarScan scan = RevolutionToScan(rev, driver_->options().scan);
    // Revolutions that never came (the device away or silent, samples lost): the number skips
    // them, as laser_scan_t's contract says, so that a gap in time is a gap in the count.
    if (last_scan_utime_ >= 0 && last_scan_time_s_ > 0.02 && last_scan_time_s_ < 1.0 &&
        scan.utime > last_scan_utime_) {
      const double periods =
          static_cast<double>(scan.utime - last_scan_utime_) * 1e-6 / last_scan_time_s_;
      // Bounded by the time that passed here (a wall clock set forward is not a loss): one
      // revolution more than the monotonic gap holds, for the stamps' own spread.
      const double mono_periods =
          static_cast<double>(read_mono - last_publish_mono_) * 1e-6 / last_scan_time_s_;
      if (periods > 1.5 && mono_periods > 0.5) {
        const int64_t missed =
            std::min<int64_t>({std::llround(periods) - 1, std::llround(mono_periods), 100000});
        seq_ += missed;
        revolutions_missed_ += missed;
      }
    }
    last_scan_utime_ = scan.utime;
    last_publish_mono_ = read_mono;
    if (scan.scan_time_s > 0) last_scan_time_s_ = scan.scan_time_s;
    bus_->Publish(options_.channel, MakeLaserScan(scan, seq_++, options_, driver_->options().scan));
  }
  const int64_t now = MonotonicMicros();
  if (driver_->state() != DriverState::kStreaming) {
    progress_us_ = -1;
  } else if (!revolutions.empty() || progress_us_ < 0) {
    progress_us_ = now;
  }
  if (driver_->state() == DriverState::kStreaming &&
      now - progress_us_ > SecondsToUtime(kNoRevolutionS)) {
    heartbeat_.SetState(omni::heartbeat_t::STATE_DEGRADED,
                        "streaming, but no whole revolution for " +
                            std::to_string((now - progress_us_) / 1000000) +
                            " s (motor not turning? samples_without_turn counts what came)");
  } else if (driver_->state() == DriverState::kStreaming) {
    heartbeat_.SetState(omni::heartbeat_t::STATE_OK, driver_->status_text());
  } else {
    heartbeat_.SetState(omni::heartbeat_t::STATE_ERROR,
                        "device lost, retrying: " + driver_->status_text());
  }
  heartbeat_.Tick();
}

void RplidarNode::Run(const std::atomic<bool>* stop, double max_s) {
  const int64_t start = MonotonicMicros();
  while (!stop->load()) {
    if (max_s > 0 && MonotonicMicros() - start > SecondsToUtime(max_s)) break;
    RunOnce(50);
  }
  heartbeat_.SetState(omni::heartbeat_t::STATE_STOPPING, "stopping");
  heartbeat_.Tick(true);
  driver_->Shutdown();
}

}  // namespace omni::rplidar
