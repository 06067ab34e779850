// The logs both online SLAM benchmarks (omni-bench-rbpf, omni-bench-pgslam) map, under one set
// of names, and the accuracy goal issues 5 and 6 set for each: ATE RMSE <= 0.10 m, 0.05 m on
// Freiburg 079 (where the peer already reaches about 0.08 m).
#pragma once

#include <cstddef>
#include <string>
#include <vector>

namespace omni::bench {

struct SlamLog {
  std::string name;       // intel-raw, aces-noisy, intel-noisy, csail-noisy, freiburg-079-noisy
  std::string log;        // CARMEN log, relative to the datasets folder
  std::string rawlog;     // the same log as MRPT's rawlog (the peer's input), relative
  std::string reference;  // indexed reference trajectory, relative
  int peer_index_offset;  // our scan index of MRPT's step 0
  double ate_goal_m;      // the issues' ATE RMSE goal on this log
};

// intel-raw first, then the four noisy-odometry logs.
const std::vector<SlamLog>& SlamLogs();

// The goal of the log called `name`; 0.10 m for a name that is not one of SlamLogs().
double SlamAteGoal(const std::string& name);

// A run scored on `matched` of the reference's `reference_poses` poses: appends "covers N of M
// reference poses" to `note` when some are left out, and returns false (a failed row, not a
// figure) below 95 % of the reference (a crash, or a peer whose log reader gave up).
bool CheckCoverage(size_t matched, size_t reference_poses, std::string* note);

}  // namespace omni::bench
