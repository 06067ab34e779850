// The files a pose-graph SLAM run leaves behind, written the same way by the offline runner
// (omni-posegraph-slam) and the bus process (pose_graph_mapper):
//   DIR/trajectory.txt   scan_index timestamp x y theta, every accepted scan, final estimate
//   DIR/map.{pgm,yaml,png}, DIR/map_trajectory.png   grid of the optimised keyframes
//   DIR/graph.g2o        keyframe graph at the final estimate
//   DIR/stats.json       counters, wall time, window-update and global-optimisation latency
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "omni/common/result.h"
#include "omni/pose_graph_mapper/pose_graph_slam.h"

namespace omni::pgm {

struct SlamRunInfo {
  std::string system = "omni-posegraph";
  std::string input;          // log path or bus URL
  double wall_s = 0;          // whole run
  int64_t decode_errors = 0;  // undecodable input messages or lines
  double grid_resolution_m = 0.05;
  int window_size = 0;  // reported in stats.json
  // Extra integer fields appended to stats.json (e.g. the bus node's counters).
  std::vector<std::pair<std::string, int64_t>> extra;
};

// The p-quantile (0..1) of `v` by nearest rank; 0 when empty.
double Percentile(std::vector<double> v, double p);

// Writes every file above; an error names the file that failed. Fails when no scan was accepted.
Status WriteSlamOutputs(const PoseGraphSlam& slam, const std::string& dir, const SlamRunInfo& info);

}  // namespace omni::pgm
