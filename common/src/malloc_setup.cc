#include "omni/common/malloc_setup.h"

#include <malloc.h>

#include <cstdlib>

namespace omni {

bool FixMallocThresholds() {
#if defined(__GLIBC__)
  if (std::getenv("MALLOC_MMAP_THRESHOLD_") != nullptr) return false;
  constexpr int kThreshold = 128 * 1024;  // glibc's initial value
  return mallopt(M_MMAP_THRESHOLD, kThreshold) == 1;
#else
  return false;
#endif
}

}  // namespace omni
