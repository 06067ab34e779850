#pragma once

#include <filesystem>
#include <string>

#include <gtest/gtest.h>

namespace omni::testing {

// Path of a file in ../shared/datasets; empty when the dataset is absent.
inline std::string Dataset(const std::string& relative) {
  const std::string p = std::string(OMNI_DATASETS_DIR) + "/" + relative;
  return std::filesystem::exists(p) ? p : std::string();
}

inline std::string TempDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string name = std::string(info->test_suite_name()) + "_" + info->name();
  for (auto& c : name)
    if (c == '/') c = '_';
  const auto dir = std::filesystem::temp_directory_path() / ("omni_test_" + name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

}  // namespace omni::testing

#define OMNI_REQUIRE_DATASET(var, rel)                          \
  const std::string var = ::omni::testing::Dataset(rel);        \
  if (var.empty())                                              \
  GTEST_SKIP() << "dataset " << OMNI_DATASETS_DIR << "/" << rel \
               << " is absent (tests read ../shared/datasets in place)"
