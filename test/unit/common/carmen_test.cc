#include "omni/io/carmen.h"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <sstream>

#include <gtest/gtest.h>

#include "test_paths.h"

namespace omni::io {
namespace {

TEST(Carmen, IntelRawCounts) {
  OMNI_REQUIRE_DATASET(path, "intel-raw/intel.clf");
  auto log = ReadCarmenLog(path);
  ASSERT_TRUE(log.ok()) << log.error().message;
  EXPECT_EQ(log->num_lasers, 2726u);
  EXPECT_EQ(log->num_odometry, 2727u);
  const CarmenLaser* first = nullptr;
  for (const auto& r : log->records)
    if (r.kind == CarmenRecord::Kind::kLaser) {
      first = &r.laser;
      break;
    }
  ASSERT_NE(first, nullptr);
  EXPECT_EQ(first->ranges_m.size(), 180u);
  EXPECT_NEAR(first->angle_min_rad, -M_PI / 2, 1e-6);
  EXPECT_NEAR(first->angle_increment_rad, M_PI / 180, 1e-7);
  EXPECT_NEAR(first->ranges_m[0], 1.07f, 1e-6);
  EXPECT_NEAR(first->timestamp_s, 1155923634.713750, 1e-6);
}

// The sensor's range is the largest reading most lines share (a beam without a return is written
// as it), not each line's own largest reading: on intel.clf 1447 of 2726 lines have no 30 m
// reading, and their farthest real return was read as "no return".
TEST(Carmen, TheSensorRangeIsTheLogsNotTheLines) {
  OMNI_REQUIRE_DATASET(path, "intel-raw/intel.clf");
  auto log = ReadCarmenLog(path);
  ASSERT_TRUE(log.ok()) << log.error().message;
  EXPECT_FLOAT_EQ(log->max_range_m.at("FLASER"), 30.f);
  size_t lines_without_max = 0, returns_below = 0;
  for (const auto& r : log->records) {
    if (r.kind != CarmenRecord::Kind::kLaser) continue;
    EXPECT_FLOAT_EQ(r.laser.max_range_m, 30.f);
    float line_max = 0.f;
    for (float v : r.laser.ranges_m) line_max = std::max(line_max, v);
    if (line_max < 30.f) ++lines_without_max;
    for (float v : r.laser.ranges_m) returns_below += v < r.laser.max_range_m;
  }
  EXPECT_EQ(lines_without_max, 1447u);
  EXPECT_GT(returns_below, 2726u * 150);
  // A log with one line: its largest reading. Three lines, none shared: the overall largest.
  std::istringstream one("FLASER 3 1 2 3 0 0 0 0 0 0 1.0 host 1.0\n");
  auto l1 = ParseCarmenLog(one, "one.clf");
  ASSERT_TRUE(l1.ok());
  EXPECT_FLOAT_EQ(l1->records[0].laser.max_range_m, 3.f);
  std::istringstream mixed(
      "FLASER 3 1 2 80 0 0 0 0 0 0 1.0 host 1.0\nFLASER 3 1 2 5 0 0 0 0 0 0 2.0 host 2.0\n"
      "FLASER 3 1 2 80 0 0 0 0 0 0 3.0 host 3.0\nFLASER 3 1 2 7 0 0 0 0 0 0 4.0 host 4.0\n");
  auto l2 = ParseCarmenLog(mixed, "mixed.clf");
  ASSERT_TRUE(l2.ok());
  for (const auto& r : l2->records) EXPECT_FLOAT_EQ(r.laser.max_range_m, 80.f);
}

TEST(Carmen, GzipCorrectedLogCountsAndSkipsOtherTags) {
  OMNI_REQUIRE_DATASET(path, "carmen-corrected/aces-corrected.log.gz");
  auto log = ReadCarmenLog(path);
  ASSERT_TRUE(log.ok()) << log.error().message;
  EXPECT_EQ(log->num_lasers, 440u);
  EXPECT_EQ(log->num_odometry, 7814u);
  EXPECT_EQ(log->skipped.at("NEFF"), 440u);
  EXPECT_EQ(log->skipped.at("PARAM"), 4u);
}

// A .gz cut short reads as an end of file in zlib unless its error is asked for: the cut at
// 73838 bytes of the noisy Intel log ends on a line boundary and imported 558 of 1824 lines
// without a word. Cut anywhere, it is an error naming the file.
TEST(Carmen, ATruncatedGzipFileIsAnErrorNotAShortLog) {
  OMNI_REQUIRE_DATASET(path, "slam-noisy-odom/intel.noisy.clf.gz");
  std::ifstream in(path, std::ios::binary);
  const std::string whole((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(whole.size(), 130000u);
  const std::string cut_path = ::testing::TempDir() + "/omni_carmen_cut.clf.gz";
  for (size_t cut : {size_t{73838}, size_t{120000}}) {
    {
      std::ofstream out(cut_path, std::ios::binary | std::ios::trunc);
      out.write(whole.data(), static_cast<std::streamsize>(cut));
    }
    auto log = ReadCarmenLog(cut_path);
    ASSERT_FALSE(log.ok()) << "cut at " << cut << ": " << log->num_lasers << " scans read";
    EXPECT_NE(log.error().message.find("truncated"), std::string::npos) << log.error().message;
    EXPECT_NE(log.error().message.find(cut_path), std::string::npos) << log.error().message;
  }
  std::remove(cut_path.c_str());
  auto full = ReadCarmenLog(path);
  EXPECT_TRUE(full.ok()) << full.error().message;
}

TEST(Carmen, NoisyFreiburgCounts) {
  OMNI_REQUIRE_DATASET(path, "slam-noisy-odom/freiburg-079.noisy.clf.gz");
  auto log = ReadCarmenLog(path);
  ASSERT_TRUE(log.ok()) << log.error().message;
  EXPECT_EQ(log->num_lasers, 4791u);
  EXPECT_EQ(log->num_odometry, 4791u);
}

TEST(Carmen, HalfDegreeBeamsAndRobotLaser) {
  std::istringstream in(
      "# comment\n"
      "ROBOTLASER1 0 -1.5708 3.14159 0.0174533 30 0.01 0 3 1.0 2.0 3.0 0 0.1 0.2 0.3 0.0 0.0 0.0 0 "
      "0 0 0 0 "
      "12.5 host 12.5\n");
  auto log = ParseCarmenLog(in, "mem");
  ASSERT_TRUE(log.ok()) << log.error().message;
  ASSERT_EQ(log->num_lasers, 1u);
  const auto& l = log->records[0].laser;
  EXPECT_EQ(l.ranges_m.size(), 3u);
  EXPECT_NEAR(l.laser_pose.x, 0.1, 1e-12);
  EXPECT_NEAR(l.timestamp_s, 12.5, 1e-12);
  EXPECT_NEAR(CarmenBeamIncrementRad(361), M_PI / 360, 1e-7);
}

TEST(Carmen, TruncatedLineNamesFileAndLine) {
  std::istringstream in("ODOM 0 0 0 0 0 0 1.0 host 1.0\nFLASER 180 1.0 2.0 3.0\n");
  auto log = ParseCarmenLog(in, "broken.clf");
  ASSERT_FALSE(log.ok());
  EXPECT_NE(log.error().message.find("broken.clf:2"), std::string::npos) << log.error().message;
}

TEST(Carmen, NonNumberNamed) {
  std::istringstream in("ODOM 0 0 zero 0 0 0 1.0 host 1.0\n");
  auto log = ParseCarmenLog(in, "bad.clf");
  ASSERT_FALSE(log.ok());
  EXPECT_NE(log.error().message.find("bad.clf:1"), std::string::npos);
  EXPECT_NE(log.error().message.find("'zero'"), std::string::npos) << log.error().message;
}

// Found by fuzzing (test/fuzz/carmen_fuzz.cc): a NaN or absurd stamp was accepted, and the
// importer's sort by stamp and the conversion to microseconds are undefined on it. Poses must be
// finite too; ranges may be anything (the mappers count invalid beams), and one too large for a
// float becomes an infinity rather than an undefined conversion.
TEST(Carmen, NonFiniteStampsAndPosesAreErrorsNamingTheLine) {
  for (const char* line :
       {"ODOM 0 0 0 0 0 0 nan host 1.0", "ODOM 0 0 0 0 0 0 1e300 host 1.0",
        "ODOM 0 inf 0 0 0 0 1.0 host 1.0", "FLASER 3 1 2 3 0 0 nan 0 0 0 1.0 host 1.0"}) {
    std::istringstream in(std::string("ODOM 0 0 0 0 0 0 0.5 host 0.5\n") + line + "\n");
    auto log = ParseCarmenLog(in, "bad.clf");
    ASSERT_FALSE(log.ok()) << line;
    EXPECT_NE(log.error().message.find("bad.clf:2"), std::string::npos) << log.error().message;
    EXPECT_NE(log.error().message.find("not a finite number"), std::string::npos)
        << log.error().message;
  }
  std::istringstream in("FLASER 3 nan 1e300 3 0 0 0 0 0 0 1.0 host 1.0\n");
  auto log = ParseCarmenLog(in, "ranges.clf");
  ASSERT_TRUE(log.ok()) << log.error().message;
  const CarmenLaser& l = log->records[0].laser;
  EXPECT_TRUE(std::isnan(l.ranges_m[0]));
  EXPECT_TRUE(std::isinf(l.ranges_m[1]));
  EXPECT_FLOAT_EQ(l.max_range_m, 3.f);
}

TEST(Carmen, MissingFile) {
  auto log = ReadCarmenLog("/nonexistent.clf");
  ASSERT_FALSE(log.ok());
  EXPECT_NE(log.error().message.find("/nonexistent.clf"), std::string::npos);
}

}  // namespace
}  // namespace omni::io
