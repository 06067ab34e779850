#include "omni/io/trajectory_io.h"

#include <fstream>

#include <gtest/gtest.h>

#include "test_paths.h"

namespace omni::io {
namespace {

TEST(Trajectory, ReadsDatasetReference) {
  OMNI_REQUIRE_DATASET(path, "intel-raw/intel.reference.txt");
  auto t = ReadTrajectory(path);
  ASSERT_TRUE(t.ok()) << t.error().message;
  EXPECT_EQ(t->format, Trajectory::Format::kIndexed2D);
  EXPECT_EQ(t->entries.size(), 174u);
  EXPECT_EQ(t->entries[0].index, 40);
  EXPECT_NEAR(t->entries[0].position.x(), 0.679250, 1e-9);
  EXPECT_NEAR(t->entries[0].yaw(), -1.926040, 1e-9);
}

TEST(Trajectory, TumRoundTripAndErrors) {
  const std::string dir = omni::testing::TempDir();
  {
    std::ofstream f(dir + "/tum.txt");
    f << "# t x y z qx qy qz qw\n1.0 1 2 3 0 0 0.7071068 0.7071068\n";
  }
  auto t = ReadTrajectory(dir + "/tum.txt");
  ASSERT_TRUE(t.ok()) << t.error().message;
  EXPECT_EQ(t->format, Trajectory::Format::kTum);
  EXPECT_NEAR(t->entries[0].yaw(), M_PI / 2, 1e-6);
  {
    std::ofstream f(dir + "/bad.txt");
    f << "0 1.0 2 3\n";
  }
  auto bad = ReadTrajectory(dir + "/bad.txt");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("bad.txt:1"), std::string::npos);
  std::vector<TrajectoryEntry> e{MakeEntry2D(3, 10.5, Pose2(1, 2, 0.3))};
  ASSERT_TRUE(WriteTrajectory2D(dir + "/out.txt", e).ok());
  auto back = ReadTrajectory(dir + "/out.txt");
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->entries[0].index, 3);
  EXPECT_NEAR(back->entries[0].yaw(), 0.3, 1e-6);
  // A scan index is a whole number: 0.9 used to be read as 0, 1e300 cast to nothing defined.
  for (const char* index : {"0.9", "-1", "1e300", "nan"}) {
    std::ofstream(dir + "/idx.txt") << index << " 10.5 1 2 0.3\n";
    auto r = ReadTrajectory(dir + "/idx.txt");
    ASSERT_FALSE(r.ok()) << index;
    EXPECT_NE(r.error().message.find("idx.txt:1"), std::string::npos) << r.error().message;
  }
}

}  // namespace
}  // namespace omni::io
