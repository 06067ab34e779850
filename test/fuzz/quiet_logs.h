// For the fuzz targets that drive whole nodes: they log every refused message, so a run of a
// million inputs would print nothing else. Errors still show.
#pragma once

#include "omni/common/log.h"

namespace omni::fuzz {

inline void QuietLogs() {
  static const bool once = [] {
    omni::SetLogLevel(omni::LogLevel::kError);
    return true;
  }();
  (void)once;
}

}  // namespace omni::fuzz
