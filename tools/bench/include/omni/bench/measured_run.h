// Running a program the way a benchmark measures it: wall time and peak resident memory of the
// child alone, its output to a log file, an optional time limit.
#pragma once

#include <string>
#include <vector>

namespace omni::bench {

struct MeasuredRun {
  bool started = false;    // fork succeeded
  int exit_code = -1;      // 128 + signal when killed; 127 when the program could not start
  bool timed_out = false;  // killed at the time limit
  double wall_s = 0;
  long peak_rss_kb = 0;  // the child's maximum resident set (getrusage)
  bool ok() const { return started && !timed_out && exit_code == 0; }
  double peak_rss_mb() const { return static_cast<double>(peak_rss_kb) / 1024.0; }
};

// Runs argv (argv[0] a path) with stdin from /dev/null and stdout+stderr to `log_path`, in
// `cwd` when given; kills it after `timeout_s` seconds when that is > 0.
MeasuredRun RunMeasured(const std::vector<std::string>& argv, const std::string& log_path,
                        double timeout_s = 0, const std::string& cwd = "");

// The first executable `name` on PATH, or "".
std::string FindInPath(const std::string& name);

// Median of repeated measurements (mean of the middle two for an even count; 0 when empty).
double Median(std::vector<double> v);

}  // namespace omni::bench
