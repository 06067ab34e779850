#include "omni/rplidar/scan.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace omni::rplidar {

PlanarScan RevolutionToScan(const std::vector<Sample>& revolution, const ScanOptions& options) {
  PlanarScan scan;
  const int n = options.beams > 0 ? options.beams : 720;
  const double step = 2.0 * M_PI / n;
  // The lidar turns clockwise: beams run clockwise from where the revolution began, so that
  // beam i is the i-th measured (the mappers place beam i at utime + i / (n - 1) *
  // scan_time_s when they undo the base's motion during the sweep). Bins counter-clockwise
  // from -pi would put the first sample in the middle of the scan and run time backwards.
  scan.angle_increment_rad = -step;
  auto ccw = [&](const Sample& s) {
    return std::remainder(-s.angle_deg * M_PI / 180.0 + options.angle_offset_rad, 2.0 * M_PI);
  };
  scan.ranges_m.assign(static_cast<size_t>(n), std::numeric_limits<float>::quiet_NaN());
  scan.intensities.assign(static_cast<size_t>(n), 0.0f);
  // Beam 0 on the bin lattice nearest the first sample, so that the beams' angles stay the same
  // from one revolution to the next.
  scan.angle_min_rad =
      revolution.empty()
          ? std::remainder(options.angle_offset_rad, 2.0 * M_PI)
          : std::remainder(std::round(ccw(revolution.front()) / step) * step, 2.0 * M_PI);
  if (revolution.empty()) return scan;
  // The first sample's place in beam 0 (within half a bin of its centre): samples up to a bin's
  // eighth behind it are angle jitter at the start; further behind, the turn's last ones.
  const double d0 = std::remainder(scan.angle_min_rad - ccw(revolution.front()), 2.0 * M_PI);
  scan.utime = revolution.front().utime;
  scan.scan_time_s = (revolution.back().utime - revolution.front().utime) * 1e-6;
  for (const Sample& s : revolution) {
    const double r = s.distance_mm * 1e-3;
    if (!(r >= options.range_min_m) || r >= options.range_max_m) continue;
    // Clockwise from beam 0's centre: a sample just behind the first one is jitter at the start
    // (beam 0), one further behind is from the end of the turn (beam n - 1, not beam 0).
    double d = std::remainder(scan.angle_min_rad - ccw(s), 2.0 * M_PI);
    if (d < d0 - step / 8) d += 2.0 * M_PI;
    const long bin = std::clamp<long>(std::lround(d / step), 0, n - 1);
    float& slot = scan.ranges_m[static_cast<size_t>(bin)];
    if (std::isnan(slot) || r < slot) {
      slot = static_cast<float>(r);
      scan.intensities[static_cast<size_t>(bin)] = s.quality;
    }
    ++scan.samples_used;
  }
  return scan;
}

}  // namespace omni::rplidar
