// The logs the online SLAM benchmarks map: one list for both, with the issues' goals, and every
// file it names present where the datasets are (a wrong path would make a benchmark row say
// "dataset absent" instead of measuring).
#include <filesystem>
#include <set>
#include <string>

#include <gtest/gtest.h>

#include "omni/bench/slam_logs.h"
#include "test_paths.h"

namespace omni::bench {
namespace {

TEST(SlamLogs, NamesAndGoalsAreTheIssues) {
  std::set<std::string> names;
  for (const SlamLog& l : SlamLogs()) names.insert(l.name);
  EXPECT_EQ(names, (std::set<std::string>{"intel-raw", "aces-noisy", "intel-noisy", "csail-noisy",
                                          "freiburg-079-noisy"}));
  EXPECT_EQ(SlamLogs().front().name, "intel-raw");
  EXPECT_EQ(SlamAteGoal("freiburg-079-noisy"), 0.05);
  EXPECT_EQ(SlamAteGoal("intel-raw"), 0.10);
  EXPECT_EQ(SlamAteGoal("aces-noisy"), 0.10);
  EXPECT_EQ(SlamAteGoal("fr079-noisy"), 0.10);  // not a name: the default, not Freiburg's
}

TEST(SlamLogs, EveryFileIsInTheDatasets) {
  OMNI_REQUIRE_DATASET(noisy, "slam-noisy-odom");
  OMNI_REQUIRE_DATASET(raw, "intel-raw");
  for (const SlamLog& l : SlamLogs()) {
    for (const std::string& rel : {l.log, l.rawlog, l.reference}) {
      EXPECT_FALSE(omni::testing::Dataset(rel).empty()) << l.name << ": " << rel;
    }
  }
}

}  // namespace
}  // namespace omni::bench
