// Whether a laser scan's geometry is one a real lidar could produce, before any mapper uses it.
// A finite but absurd angle increment (0, 1e30), a mount pose kilometres off the base or a
// range limit of 1e5 m passes a finiteness check and then builds starbursts or multi-GB grids.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "omni/common/geometry.h"

namespace omni {

// A stamp within +-2^61 us (tens of thousands of years either side of the epoch): the time
// arithmetic on two such stamps (differences, a sweep's end) cannot overflow. Beyond, the stamp
// is corrupt and is refused before any of it.
inline constexpr int64_t kMaxStampUs = std::numeric_limits<int64_t>::max() / 4;
inline bool StampInRange(int64_t utime) { return utime <= kMaxStampUs && utime >= -kMaxStampUs; }

// Beams per scan above which a scan is refused (an RPLidar gives ~2000, a Hokuyo ~1100).
inline constexpr size_t kMaxScanBeams = 100000;

// A scan's range_max as a bound on its returns: 0 (a driver that gives none) is no limit, as the
// three mappers read it.
inline float ScanRangeLimit(float range_max_m) {
  return range_max_m > 0 ? range_max_m : std::numeric_limits<float>::infinity();
}

inline bool PlausibleScanGeometry(double angle_min_rad, double angle_increment_rad, size_t beams,
                                  double range_max_m, const Pose2& sensor_in_base) {
  constexpr double kTwoPi = 2.0 * M_PI;
  if (beams > kMaxScanBeams) return false;
  if (!std::isfinite(angle_min_rad) || std::abs(angle_min_rad) > kTwoPi) return false;
  if (!std::isfinite(angle_increment_rad)) return false;
  // One revolution at most, and distinct beams.
  if (beams > 1 && (angle_increment_rad == 0.0 ||
                    std::abs(angle_increment_rad) * static_cast<double>(beams - 1) > kTwoPi + 1e-3))
    return false;
  // range_max: not beyond what any 2D lidar measures (1 km); 0 is no limit (ScanRangeLimit).
  if (!(range_max_m >= 0) || !(range_max_m <= 1000.0)) return false;
  // The sensor on the robot: within 10 m of the base's origin, a finite heading.
  return std::isfinite(sensor_in_base.x) && std::isfinite(sensor_in_base.y) &&
         std::isfinite(sensor_in_base.theta) && std::abs(sensor_in_base.x) <= 10.0 &&
         std::abs(sensor_in_base.y) <= 10.0;
}

// An odometry pose a real base could report: finite, within 1000 km of the odometry's origin and
// a heading within a million radians (an unwrapped one after 160,000 turns). Beyond that, double
// precision cannot hold centimetre steps (at 1e17 m a step of 1 m rounds away), so a pose such as
// 1e232 m, finite though it is, would freeze the odometry and send poses and grids to absurd
// places.
inline constexpr double kMaxOdometryM = 1e6;
inline constexpr double kMaxOdometryRad = 1e6;

inline bool PlausibleOdometryPose(const Pose2& p) {
  return std::abs(p.x) <= kMaxOdometryM && std::abs(p.y) <= kMaxOdometryM &&
         std::abs(p.theta) <= kMaxOdometryRad;  // (false for NaN too)
}

}  // namespace omni
