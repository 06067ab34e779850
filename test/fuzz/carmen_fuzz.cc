// CARMEN logs (`omni import`, `omni-slam`, the benchmarks): any text into the parser. A log it
// accepts holds only finite poses and beam geometry and stamps that convert to microseconds;
// the ranges themselves may be NaN or infinite (the mappers count such beams). Seeds:
// the first lines of the real logs in ../shared/datasets (raw odometry, noisy odometry, the
// corrected logs), read in place.
#include <cmath>
#include <sstream>

#include "fuzz.h"
#include "omni/io/carmen.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::istringstream in(std::string(reinterpret_cast<const char*>(data), size));
  auto log = omni::io::ParseCarmenLog(in, "fuzz");
  if (!log.ok()) {
    OMNI_FUZZ_CHECK(!log.status().message().empty());
    return 0;
  }
  size_t lasers = 0, odoms = 0;
  for (const auto& r : log.value().records) {
    // Stamps convert to microseconds without overflow (the reader's +-73,000-year bound).
    OMNI_FUZZ_CHECK(std::isfinite(r.timestamp_s()) && std::fabs(r.timestamp_s()) <= 2.3e12);
    if (r.kind == omni::io::CarmenRecord::Kind::kLaser) {
      ++lasers;
      const auto& l = r.laser;
      OMNI_FUZZ_CHECK(std::isfinite(l.max_range_m));
      OMNI_FUZZ_CHECK(std::isfinite(l.angle_min_rad) && std::isfinite(l.angle_increment_rad));
      OMNI_FUZZ_CHECK(std::isfinite(l.laser_pose.x) && std::isfinite(l.laser_pose.y) &&
                      std::isfinite(l.laser_pose.theta));
      OMNI_FUZZ_CHECK(std::isfinite(l.robot_pose.x) && std::isfinite(l.robot_pose.y) &&
                      std::isfinite(l.robot_pose.theta));
    } else {
      ++odoms;
      const auto& o = r.odom;
      OMNI_FUZZ_CHECK(std::isfinite(o.pose.x) && std::isfinite(o.pose.y) &&
                      std::isfinite(o.pose.theta));
    }
  }
  OMNI_FUZZ_CHECK(lasers == log.value().num_lasers && odoms == log.value().num_odometry);
  return 0;
}

void omni::fuzz::Seeds(SeedList* seeds) {
  for (const char* file : {"intel-raw/intel.clf", "slam-noisy-odom/aces.noisy.clf.gz",
                           "carmen-corrected/freiburg-079-corrected.log.gz",
                           "carmen-corrected/intel-corrected.log.gz"})
    seeds->AddDatasetLines(file, 12000);
}
