// The CARMEN importer on real data: every scan and odometry line becomes one decodable bus
// message, in time order.
#include <filesystem>

#include <gtest/gtest.h>

#include "../../unit/common/test_paths.h"
#include "omni/io/lcm_log.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odometry_t.hpp"
#include "run.h"

namespace omni {
namespace {

TEST(Import, IntelRawBecomesOrderedLog) {
  OMNI_REQUIRE_DATASET(clf, "intel-raw/intel.clf");
  const std::string out = testing::TempDir() + "/intel.lcmlog";
  const auto r = testing::Run(testing::Bin("omni-import") + " carmen " + clf + " " + out);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("2726 laser scans"), std::string::npos) << r.output;

  auto reader = io::LcmLogReader::Open(out);
  ASSERT_TRUE(reader.ok());
  io::LcmLogEvent ev;
  int scans = 0, odoms = 0;
  int64_t last = 0, last_scan_seq = -1;
  for (;;) {
    auto more = reader->Next(&ev);
    ASSERT_TRUE(more.ok()) << more.error().message;
    if (!*more) break;
    EXPECT_GE(ev.utime, last) << "event " << ev.event_number << " goes back in time";
    last = ev.utime;
    if (ev.channel == "LIDAR_SCAN") {
      omni::laser_scan_t s;
      ASSERT_GE(s.decode(ev.data.data(), 0, static_cast<int>(ev.data.size())), 0);
      EXPECT_EQ(s.num_ranges, 180);
      EXPECT_EQ(s.utime, ev.utime);
      EXPECT_EQ(s.seq, last_scan_seq + 1);
      last_scan_seq = s.seq;
      ++scans;
    } else if (ev.channel == "WHEEL_ODOM") {
      omni::odometry_t o;
      ASSERT_GE(o.decode(ev.data.data(), 0, static_cast<int>(ev.data.size())), 0);
      ++odoms;
    } else {
      ADD_FAILURE() << "unexpected channel " << ev.channel;
    }
  }
  EXPECT_EQ(scans, 2726);
  EXPECT_EQ(odoms, 2727);
}

TEST(Import, GzipLogWithOtherTags) {
  OMNI_REQUIRE_DATASET(log, "carmen-corrected/csail-corrected.log.gz");
  // Into a folder that does not exist yet (`out/` on a fresh checkout): it is made.
  std::filesystem::remove_all(testing::TempDir() + "/import_new");
  const std::string out = testing::TempDir() + "/import_new/logs/csail.lcmlog";
  const auto r = testing::Run(testing::Bin("omni-import") + " carmen " + log + " " + out);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("406 laser scans"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("2394 odometry"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("NEFF x406"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace omni
