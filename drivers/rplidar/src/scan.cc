#include "omni/rplidar/scan.h"

#include <cmath>
#include <limits>

namespace omni::rplidar {

PlanarScan RevolutionToScan(const std::vector<Sample>& revolution, const ScanOptions& options) {
  PlanarScan scan;
  const int n = options.beams > 0 ? options.beams : 720;
  scan.angle_min_rad = -M_PI;
  scan.angle_increment_rad = 2.0 * M_PI / n;
  scan.ranges_m.assign(static_cast<size_t>(n), std::numeric_limits<float>::quiet_NaN());
  scan.intensities.assign(static_cast<size_t>(n), 0.0f);
  if (revolution.empty()) return scan;
  scan.utime = revolution.front().utime;
  scan.scan_time_s = (revolution.back().utime - revolution.front().utime) * 1e-6;
  for (const Sample& s : revolution) {
    const double r = s.distance_mm * 1e-3;
    if (!(r >= options.range_min_m) || r >= options.range_max_m) continue;
    double a = -s.angle_deg * M_PI / 180.0 + options.angle_offset_rad;  // clockwise -> CCW
    a = std::remainder(a, 2.0 * M_PI);                                  // [-pi, pi]
    long bin = std::lround((a - scan.angle_min_rad) / scan.angle_increment_rad);
    bin = ((bin % n) + n) % n;
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
