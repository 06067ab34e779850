// The RPLidar parser on real bytes: standard-scan captures of an RPLidar A3
// (../shared/datasets/rplidar/derived, see its SOURCE.md).
#include <cmath>
#include <fstream>
#include <iterator>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/rplidar/parser.h"

namespace omni::rplidar {
namespace {

const std::string kDir = std::string(OMNI_DATASETS_DIR) + "/rplidar/derived/";

bool ReadBytes(const std::string& path, std::vector<uint8_t>* out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  out->assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  return true;
}

std::vector<Sample> DecodeAll(const std::vector<uint8_t>& bytes, MeasurementParser* parser,
                              size_t chunk = 64) {
  std::vector<Sample> out;
  for (size_t i = 0; i < bytes.size(); i += chunk) {
    parser->Feed(bytes.data() + i, std::min(chunk, bytes.size() - i), 0, &out);
  }
  parser->Finish(0, &out);
  return out;
}

TEST(RplidarDataset, DecodesTestVectorExactly) {
  std::vector<uint8_t> bytes;
  if (!ReadBytes(kDir + "rplidar_data_1.bin", &bytes)) {
    GTEST_SKIP() << "dataset " << kDir << "rplidar_data_1.bin absent";
  }
  std::ifstream tsv(kDir + "rplidar_data_1.decoded.tsv");
  ASSERT_TRUE(tsv) << "rplidar_data_1.decoded.tsv missing beside the .bin";
  std::vector<std::pair<double, double>> expected;  // angle_deg, distance_mm (firmware print)
  std::string line;
  while (std::getline(tsv, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> f;
    std::stringstream ss(line);
    std::string field;
    while (std::getline(ss, field, '\t')) f.push_back(field);
    ASSERT_EQ(f.size(), 5u) << line;
    expected.emplace_back(std::stod(f[3]), std::stod(f[4]));
  }
  ASSERT_EQ(expected.size(), 1800u);
  MeasurementParser parser(StreamMode::kStandard);
  const auto samples = DecodeAll(bytes, &parser);
  ASSERT_EQ(samples.size(), expected.size());
  for (size_t i = 0; i < samples.size(); ++i) {
    // The capture firmware printed angles truncated to 3 decimals and distances exactly.
    const double truncated = std::floor(samples[i].angle_deg * 1000.0) / 1000.0;
    ASSERT_NEAR(truncated, expected[i].first, 1e-9) << "sample " << i;
    ASSERT_DOUBLE_EQ(samples[i].distance_mm, expected[i].second) << "sample " << i;
  }
  EXPECT_EQ(parser.counters().checkbit_errors, 0);
  EXPECT_EQ(parser.counters().bytes_skipped, 0);
}

TEST(RplidarDataset, AllCapturesDecodeWithoutCheckBitFailures) {
  const char* names[] = {"longvalues_at_60", "valid_data_1",   "valid_data_2",    "values_at_100",
                         "values_at_25",     "values_at_50",   "values_at_50_v2", "values_at_60",
                         "values_at_60_v2",  "values_at_60_v3"};
  int found = 0;
  for (const char* name : names) {
    std::vector<uint8_t> bytes;
    if (!ReadBytes(kDir + name + ".bin", &bytes)) continue;
    ++found;
    MeasurementParser parser(StreamMode::kStandard);
    RevolutionAssembler revs;
    std::vector<Sample> done;
    const auto samples = DecodeAll(bytes, &parser);
    for (const Sample& s : samples) revs.Add(s, &done);
    EXPECT_EQ(samples.size(), bytes.size() / kSampleSize) << name;
    EXPECT_EQ(parser.counters().checkbit_errors, 0) << name;
    EXPECT_EQ(parser.counters().bytes_skipped, 0) << name;
    EXPECT_GE(revs.revolutions(), 2) << name;  // SOURCE.md: 3..18 start flags per file
    for (const Sample& s : samples) {
      ASSERT_GE(s.angle_deg, 0.0) << name;
      ASSERT_LT(s.angle_deg, 360.0) << name;
    }
  }
  if (found == 0) GTEST_SKIP() << "dataset " << kDir << " absent";
}

// Random garbage spliced into a real capture costs only the samples it corrupted.
TEST(RplidarDataset, SplicedGarbageCostsOnlyCorruptedSamples) {
  std::vector<uint8_t> clean;
  if (!ReadBytes(kDir + "longvalues_at_60.bin", &clean)) {
    GTEST_SKIP() << "dataset " << kDir << "longvalues_at_60.bin absent";
  }
  MeasurementParser reference(StreamMode::kStandard);
  const auto expected = DecodeAll(clean, &reference);
  std::mt19937 rng(42);
  // 40 bursts of 1..40 random bytes at random byte offsets (inside or between nodes).
  std::vector<size_t> cuts;
  std::uniform_int_distribution<size_t> where(1, clean.size() - 1);
  for (int i = 0; i < 40; ++i) cuts.push_back(where(rng));
  std::sort(cuts.begin(), cuts.end());
  std::vector<uint8_t> dirty;
  std::vector<bool> node_damaged(clean.size() / kSampleSize, false);
  size_t next_cut = 0;
  std::uniform_int_distribution<int> len(1, 40), byte(0, 255);
  for (size_t i = 0; i < clean.size(); ++i) {
    while (next_cut < cuts.size() && cuts[next_cut] == i) {
      // Garbage inside a node breaks that node; garbage at a boundary breaks nothing.
      if (i % kSampleSize != 0) node_damaged[i / kSampleSize] = true;
      const int n = len(rng);
      for (int k = 0; k < n; ++k) dirty.push_back(static_cast<uint8_t>(byte(rng)));
      ++next_cut;
    }
    dirty.push_back(clean[i]);
  }
  MeasurementParser parser(StreamMode::kStandard);
  const auto got = DecodeAll(dirty, &parser, 37);
  // Every undamaged node must be decoded, in order.
  size_t j = 0, undamaged = 0, matched = 0;
  for (size_t i = 0; i < expected.size(); ++i) {
    if (node_damaged[i]) continue;
    ++undamaged;
    size_t k = j;
    while (k < got.size() &&
           !(got[k].angle_deg == expected[i].angle_deg &&
             got[k].distance_mm == expected[i].distance_mm && got[k].start == expected[i].start)) {
      ++k;
    }
    if (k < got.size()) {
      ++matched;
      j = k + 1;
    } else {
      ADD_FAILURE() << "undamaged node " << i << " (angle " << expected[i].angle_deg
                    << ") not decoded";
    }
  }
  EXPECT_EQ(matched, undamaged);
  const size_t spurious = got.size() - matched;
  // A random 5-byte string passes the check bits 1 time in 4 and the angle test ~7 in 10, so a
  // garbage burst can leave a sample or two that look valid; far fewer than the bursts.
  EXPECT_LE(spurious, cuts.size()) << "more than one spurious sample per garbage burst";
  EXPECT_GT(parser.counters().checkbit_errors, 0);
  EXPECT_GT(parser.counters().resyncs, 0);
  std::printf(
      "garbage: %zu bursts, %zu undamaged nodes all decoded, %zu spurious, %lld "
      "check-bit errors, %lld resyncs\n",
      cuts.size(), undamaged, spurious, static_cast<long long>(parser.counters().checkbit_errors),
      static_cast<long long>(parser.counters().resyncs));
}

}  // namespace
}  // namespace omni::rplidar
