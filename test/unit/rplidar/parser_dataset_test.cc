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
    EXPECT_EQ(revs.implied_starts(), 0) << name << ": every revolution ends at a start flag";
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

// A start flag lost (its node corrupted, or the S bit flipped with !S): the two turns it
// separated used to come out as one scan sweeping 719 degrees with twice the scan time. The
// assembler now starts the next revolution once one has swept 370 degrees.
TEST(RplidarDataset, ALostStartFlagDoesNotJoinTwoTurns) {
  std::vector<uint8_t> bytes;
  if (!ReadBytes(kDir + "longvalues_at_60.bin", &bytes)) {
    GTEST_SKIP() << "dataset " << kDir << "longvalues_at_60.bin absent";
  }
  MeasurementParser parser(StreamMode::kStandard);
  auto samples = DecodeAll(bytes, &parser);
  int starts = 0;
  for (Sample& s : samples)
    if (s.start && ++starts == 3) s.start = false;
  ASSERT_GT(starts, 5);
  RevolutionAssembler revs;
  std::vector<Sample> done;
  int completed = 0;
  for (const Sample& s : samples) {
    if (!revs.Add(s, &done)) continue;
    ++completed;
    double sweep = 0;
    for (size_t i = 1; i < done.size(); ++i)
      sweep += std::remainder(done[i].angle_deg - done[i - 1].angle_deg, 360.0);
    EXPECT_LE(sweep, RevolutionAssembler::kMaxSweepDeg) << "revolution " << completed;
    EXPECT_GE(sweep, 340.0) << "revolution " << completed;  // after an implied start: ~350
  }
  EXPECT_EQ(revs.implied_starts(), 1);
  EXPECT_EQ(completed, starts - 1) << "as many revolutions as with the flag";
}

// A byte lost in transit (a USB-serial overrun) inside a node's distance field: the window of
// that node's first bytes and the next node's quality byte passes every check, with a range of
// ~64 mm x that byte. It used to be emitted every time (2152 of 2152 drops of byte 3, review
// 2026-12-06), and cost the next node too. Now real nodes found starting inside the window give
// it away: on every 7th node of a real capture, at most a few per cent still get through.
TEST(RplidarDataset, ALostByteInADistanceIsNotAPhantomSample) {
  std::vector<uint8_t> clean;
  if (!ReadBytes(kDir + "longvalues_at_60.bin", &clean)) {
    GTEST_SKIP() << "dataset " << kDir << "longvalues_at_60.bin absent";
  }
  MeasurementParser reference(StreamMode::kStandard);
  const auto expected = DecodeAll(clean, &reference);
  int cases = 0, phantoms = 0, next_lost = 0;
  int64_t unconfirmed = 0;
  for (size_t node = 10; node + 10 < clean.size() / kSampleSize; node += 7) {
    for (size_t byte : {3, 4}) {
      std::vector<uint8_t> dirty = clean;
      dirty.erase(dirty.begin() + static_cast<std::ptrdiff_t>(node * kSampleSize + byte));
      MeasurementParser parser(StreamMode::kStandard);
      const auto got = DecodeAll(dirty, &parser, 37);
      ++cases;
      unconfirmed += parser.counters().unconfirmed;
      // Everything before the damaged node decodes as before; then the next one should follow.
      ASSERT_GE(got.size(), node) << "node " << node;
      for (size_t i = 0; i < node; ++i) ASSERT_EQ(got[i].distance_mm, expected[i].distance_mm);
      const bool is_next = got.size() > node &&
                           got[node].angle_deg == expected[node + 1].angle_deg &&
                           got[node].distance_mm == expected[node + 1].distance_mm;
      if (!is_next) ++phantoms;
      bool found_next = false;
      for (size_t i = node; i < std::min(got.size(), node + 3); ++i)
        found_next |= got[i].angle_deg == expected[node + 1].angle_deg &&
                      got[i].distance_mm == expected[node + 1].distance_mm;
      if (!found_next) ++next_lost;
    }
  }
  std::printf(
      "one byte lost in %d distance fields: %d phantom samples, %d next nodes lost, %lld "
      "windows dropped as unconfirmed\n",
      cases, phantoms, next_lost, static_cast<long long>(unconfirmed));
  ASSERT_GT(cases, 100);
  EXPECT_LE(phantoms, cases / 20);
  EXPECT_LE(next_lost, cases / 20);
  EXPECT_GE(unconfirmed, cases * 9 / 10);
}

}  // namespace
}  // namespace omni::rplidar
