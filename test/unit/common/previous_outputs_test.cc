#include "omni/io/previous_outputs.h"

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <gtest/gtest.h>

#include "test_paths.h"

namespace omni::io {
namespace {

namespace fs = std::filesystem;

void Write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

std::string Read(const fs::path& p) {
  std::ifstream in(p);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// A mapper restarted on its folder four times: each start moves the run before into
// previous/1; three runs are kept; files that are not the process's stay where they are.
TEST(PreviousOutputs, EachRestartMovesTheRunBeforeAsideAndKeepsThree) {
  const fs::path dir = omni::testing::TempDir();
  const std::vector<std::string> names = {"map.pgm", "map.yaml"};
  EXPECT_EQ(*KeepPreviousOutputs(dir.string(), names), 0);  // a first run: nothing to keep
  EXPECT_FALSE(fs::exists(dir / "previous"));
  Write(dir / "notes.txt", "the user's");
  for (int run = 1; run <= 5; ++run) {
    Write(dir / "map.pgm", "pgm of run " + std::to_string(run));
    if (run != 3) Write(dir / "map.yaml", "yaml of run " + std::to_string(run));  // run 3: no yaml
    const Result<int> moved = KeepPreviousOutputs(dir.string(), names, 3);
    ASSERT_TRUE(moved.ok()) << moved.error().message;
    EXPECT_EQ(*moved, run == 3 ? 1 : 2);
    EXPECT_FALSE(fs::exists(dir / "map.pgm"));
    EXPECT_FALSE(fs::exists(dir / "map.yaml"));
  }
  EXPECT_EQ(Read(dir / "previous/1/map.pgm"), "pgm of run 5");
  EXPECT_EQ(Read(dir / "previous/1/map.yaml"), "yaml of run 5");
  EXPECT_EQ(Read(dir / "previous/2/map.pgm"), "pgm of run 4");
  EXPECT_EQ(Read(dir / "previous/3/map.pgm"), "pgm of run 3");
  EXPECT_FALSE(fs::exists(dir / "previous/3/map.yaml"));  // run 3 had none: not run 2's
  EXPECT_FALSE(fs::exists(dir / "previous/4"));
  EXPECT_EQ(Read(dir / "notes.txt"), "the user's");
}

TEST(PreviousOutputs, BadNamesAndUnmovableFilesAreErrors) {
  const fs::path dir = omni::testing::TempDir();
  EXPECT_FALSE(KeepPreviousOutputs(dir.string(), {"../map.pgm"}).ok());
  EXPECT_FALSE(KeepPreviousOutputs(dir.string(), {"map.pgm"}, 0).ok());
  // previous/1 cannot be made: a plain file named 'previous' is in the way.
  Write(dir / "previous", "");
  Write(dir / "map.pgm", "x");
  const Result<int> moved = KeepPreviousOutputs(dir.string(), {"map.pgm"});
  ASSERT_FALSE(moved.ok());
  EXPECT_NE(moved.error().message.find("previous"), std::string::npos) << moved.error().message;
  EXPECT_EQ(Read(dir / "map.pgm"), "x");  // left where it was
}

// One folder, one process: a second claim is refused while the first holds it (naming the holder),
// the refused one moves nothing aside, and the folder is free again once the holder lets go.
TEST(OutputFolderLock, ASecondClaimIsRefusedUntilTheFirstLetsGo) {
  const fs::path dir = omni::testing::TempDir();
  Write(dir / "map.pgm", "the running mapper's");
  auto first = ClaimOutputFolder((dir / "new").string(), "rbpf_mapper", {"map.pgm"});
  ASSERT_TRUE(first.ok()) << first.error().message;  // the folder is made
  EXPECT_TRUE(fs::is_directory(dir / "new"));
  auto held = OutputFolderLock::Take(dir.string(), "rbpf_mapper");
  ASSERT_TRUE(held.ok()) << held.error().message;
  const auto second = ClaimOutputFolder(dir.string(), "pose_graph_mapper", {"map.pgm"});
  ASSERT_FALSE(second.ok());
  EXPECT_NE(second.error().message.find("is being written by rbpf_mapper (pid "), std::string::npos)
      << second.error().message;
  EXPECT_EQ(Read(dir / "map.pgm"), "the running mapper's");  // not moved aside
  EXPECT_FALSE(fs::exists(dir / "previous"));
  held->reset();  // the holder ends
  const auto third = ClaimOutputFolder(dir.string(), "pose_graph_mapper", {"map.pgm"});
  ASSERT_TRUE(third.ok()) << third.error().message;
  EXPECT_EQ(Read(dir / "previous/1/map.pgm"), "the running mapper's");
  EXPECT_NE(Read(dir / OutputFolderLock::kFileName).find("pose_graph_mapper (pid "),
            std::string::npos);
}

TEST(OutputFolderLock, AFolderThatCannotBeMadeIsAnError) {
  const fs::path dir = omni::testing::TempDir();
  Write(dir / "file", "");
  const auto r = ClaimOutputFolder((dir / "file/sub").string(), "odom_mapper", {"x"});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("cannot create output folder"), std::string::npos)
      << r.error().message;
}

}  // namespace
}  // namespace omni::io
