// SeqGaps: sweeps lost between a driver and a mapper, from their sequence numbers.
#include "omni/common/seq_gaps.h"

#include <cstdint>
#include <initializer_list>

#include <gtest/gtest.h>

namespace omni {
namespace {

SeqGaps Fed(std::initializer_list<int64_t> seqs) {
  SeqGaps g;
  for (int64_t s : seqs) g.Add(s);
  return g;
}

TEST(SeqGaps, GapsAreLostAndALateMessageFillsOne) {
  EXPECT_EQ(Fed({1, 2, 3, 4}).lost(), 0);
  EXPECT_EQ(Fed({1, 2, 5, 6}).lost(), 2);
  // 9, 11, 10, 12: nothing lost (counted 2 before: the late 10 moved the newest back).
  const SeqGaps reordered = Fed({9, 11, 10, 12});
  EXPECT_EQ(reordered.lost(), 0);
  EXPECT_EQ(reordered.late(), 1);
  EXPECT_EQ(reordered.newest(), 12);
  // A repeat of the newest is neither lost nor late.
  EXPECT_EQ(Fed({4, 4, 5}).lost(), 0);
  EXPECT_EQ(Fed({4, 4, 5}).late(), 0);
  // Unnumbered messages are ignored.
  EXPECT_EQ(Fed({-1, 3, -1, 4}).lost(), 0);
  EXPECT_EQ(Fed({-1}).newest(), -1);
}

TEST(SeqGaps, ARestartedOrCorruptCountIsNotALoss) {
  // A driver restarted: its count begins again at 1; the sweeps after it are counted from there.
  const SeqGaps restarted = Fed({5000000, 5000001, 1, 2, 4});
  EXPECT_EQ(restarted.restarts(), 1);
  EXPECT_EQ(restarted.lost(), 1);
  EXPECT_EQ(restarted.newest(), 4);
  // A driver restarted after 3000 scans counts from 0 again: the losses counted before stay,
  // and those after the restart are counted (late scans within 100 of the newest only).
  SeqGaps early;
  // 1502 comes where 1500 should: 1500 and 1501 skipped, then 1501 comes late (1500 lost).
  for (int64_t s = 0; s <= 3000; ++s) early.Add(s == 1500 ? 1502 : s);
  EXPECT_EQ(early.lost(), 1);
  for (int64_t s : {0, 1, 2, 5, 6}) early.Add(s);
  EXPECT_EQ(early.restarts(), 1);
  EXPECT_EQ(early.lost(), 3);  // 1500 before the restart, 3 and 4 after it
  // A corrupt number far ahead: not ~9e18 sweeps lost.
  const SeqGaps corrupt = Fed({7, INT64_MAX, INT64_MAX - 5});
  EXPECT_EQ(corrupt.restarts(), 1);
  EXPECT_EQ(corrupt.lost(), 0);
  EXPECT_EQ(corrupt.late(), 1);
}

}  // namespace
}  // namespace omni
