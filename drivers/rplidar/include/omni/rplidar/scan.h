// A revolution of RPLidar samples as a planar scan: angles counter-clockwise, 0 = the sensor's
// forward axis (the lidar reports clockwise angles, so angle_ccw = -angle_cw), one beam per
// fixed angular bin. The beams are in the order the lidar measured them: clockwise
// (angle_increment_rad < 0) from the bin of the revolution's first sample, which
// laser_scan_t's consumers need to undo the base's motion during the sweep.
#pragma once

#include <cstdint>
#include <vector>

#include "omni/rplidar/protocol.h"

namespace omni::rplidar {

struct ScanOptions {
  int beams = 720;              // angular bins per revolution (0.5 degree)
  double range_min_m = 0.15;    // closer returns are invalid (NaN)
  double range_max_m = 25.0;    // returns at or beyond are "no return" (NaN)
  double angle_offset_rad = 0;  // added to every beam: the lidar's zero vs its housing forward
};

struct PlanarScan {
  int64_t utime = 0;               // first sample of the revolution, microseconds
  double scan_time_s = 0;          // first to last sample, seconds
  double angle_min_rad = 0;        // beam 0: the first sample's bin, in [-pi, pi]
  double angle_increment_rad = 0;  // -2 pi / beams: clockwise
  std::vector<float> ranges_m;     // NaN: no valid return
  std::vector<float> intensities;  // quality 0..63 (0 where no return)
  int samples_used = 0;
};

// Bins the samples of one revolution. When two samples fall in one bin, the nearer one wins.
PlanarScan RevolutionToScan(const std::vector<Sample>& revolution, const ScanOptions& options);

}  // namespace omni::rplidar
