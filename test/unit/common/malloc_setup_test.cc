#include "omni/common/malloc_setup.h"

#include <malloc.h>

#include <cstdlib>
#include <cstring>

#include <gtest/gtest.h>

namespace {

// Keeps the compiler from dropping a malloc/free pair whose block is never read.
void* volatile g_sink = nullptr;

void* Touch(size_t n) {
  void* p = std::malloc(n);
  std::memset(p, 1, n);
  g_sink = p;
  return g_sink;
}

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kSanitizedAllocator = true;
#else
constexpr bool kSanitizedAllocator = false;
#endif

TEST(MallocSetup, LargeBlocksStayMappedAfterALargerOneWasFreed) {
  if (kSanitizedAllocator) GTEST_SKIP() << "AddressSanitizer's allocator ignores mallopt";
  if (std::getenv("MALLOC_MMAP_THRESHOLD_") != nullptr)
    GTEST_SKIP() << "MALLOC_MMAP_THRESHOLD_ is set in the environment";
  ASSERT_TRUE(omni::FixMallocThresholds());
  // glibc's own rule would now raise its threshold to 4 MiB and take the next 1 MiB block from
  // the heap, where its space, once freed, stays with the process.
  std::free(Touch(4 << 20));
  const size_t mapped_before = mallinfo2().hblkhd;
  void* block = Touch(1 << 20);
  const size_t mapped_after = mallinfo2().hblkhd;
  std::free(block);
  EXPECT_GE(mapped_after, mapped_before + (1u << 20));
  EXPECT_EQ(mallinfo2().hblkhd, mapped_before);  // and unmapped again when freed
}

TEST(MallocSetup, AThresholdFromTheEnvironmentIsLeftAlone) {
  if (std::getenv("MALLOC_MMAP_THRESHOLD_") != nullptr) GTEST_SKIP() << "set outside the test";
  ASSERT_EQ(setenv("MALLOC_MMAP_THRESHOLD_", "262144", 1), 0);
  EXPECT_FALSE(omni::FixMallocThresholds());
  unsetenv("MALLOC_MMAP_THRESHOLD_");
}

}  // namespace
