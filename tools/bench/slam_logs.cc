#include "omni/bench/slam_logs.h"

namespace omni::bench {

const std::vector<SlamLog>& SlamLogs() {
  static const std::vector<SlamLog> logs = [] {
    std::vector<SlamLog> v;
    v.push_back({"intel-raw", "intel-raw/intel.clf", "intel-raw/intel.rawlog",
                 "intel-raw/intel.reference.txt", 1, 0.10});
    for (const char* n : {"aces", "intel", "csail", "freiburg-079"}) {
      const std::string b = std::string("slam-noisy-odom/") + n;
      v.push_back({std::string(n) + "-noisy", b + ".noisy.clf.gz", b + ".noisy.rawlog",
                   b + ".reference.txt", 0, std::string(n) == "freiburg-079" ? 0.05 : 0.10});
    }
    return v;
  }();
  return logs;
}

double SlamAteGoal(const std::string& name) {
  for (const SlamLog& l : SlamLogs())
    if (l.name == name) return l.ate_goal_m;
  return 0.10;
}

bool CheckCoverage(size_t matched, size_t reference_poses, std::string* note) {
  if (matched >= reference_poses) return true;
  *note += (note->empty() ? "" : "; ") + std::string("covers ") + std::to_string(matched) + " of " +
           std::to_string(reference_poses) + " reference poses";
  return matched * 20 >= reference_poses * 19;
}

}  // namespace omni::bench
