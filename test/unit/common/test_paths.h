#pragma once

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace omni::testing {

// Path of a file in ../shared/datasets; empty when the dataset is absent.
inline std::string Dataset(const std::string& relative) {
  const std::string p = std::string(OMNI_DATASETS_DIR) + "/" + relative;
  return std::filesystem::exists(p) ? p : std::string();
}

// A fresh folder for the current test: under TEST_TMPDIR (set by omni_add_gtest to a folder of
// the test executable in its build tree, so two build trees running the same test at once do
// not wipe each other's files), else under the system's temporary folder.
inline std::string TempDir() {
  const char* base = std::getenv("TEST_TMPDIR");
  const std::filesystem::path root = base != nullptr && base[0] != '\0'
                                         ? std::filesystem::path(base)
                                         : std::filesystem::temp_directory_path();
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string name = std::string(info->test_suite_name()) + "_" + info->name();
  for (auto& c : name)
    if (c == '/') c = '_';
  const auto dir = root / ("omni_test_" + name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

// Every file a process wrote in `dir` is one of `names` (its list of outputs, which a restart
// moves aside as a set: a file left off the list would be overwritten by the next run).
inline void ExpectOnlyListedFiles(const std::string& dir, const std::vector<std::string>& names) {
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (!e.is_regular_file()) continue;
    const std::string n = e.path().filename().string();
    EXPECT_NE(std::find(names.begin(), names.end(), n), names.end())
        << n << " was written in " << dir << " but is not in the process's list of outputs";
  }
}

}  // namespace omni::testing

#define OMNI_REQUIRE_DATASET(var, rel)                          \
  const std::string var = ::omni::testing::Dataset(rel);        \
  if (var.empty())                                              \
  GTEST_SKIP() << "dataset " << OMNI_DATASETS_DIR << "/" << rel \
               << " is absent (tests read ../shared/datasets in place)"
