// A process restarted on the same output folder (by the supervisor after a crash, or by hand)
// would write its new, younger maps over the previous run's. Before it writes anything, the
// previous run's files are moved aside: `<dir>/previous/1` holds the run before, `2` the one
// before that, up to `keep` runs (older ones are deleted; ten by default, more than the
// supervisor's five restarts before it gives up on a process, so a crash loop cannot push the
// run before it out).
#pragma once

#include <string>
#include <vector>

#include "omni/common/result.h"

namespace omni::io {

// Moves those of `names` (plain file names) found in `dir` into `<dir>/previous/1`, shifting the
// runs kept there one number up first. Returns how many files moved (0: nothing from a previous
// run, and nothing changes). An error names the file or folder that could not be moved.
Result<int> KeepPreviousOutputs(const std::string& dir, const std::vector<std::string>& names,
                                int keep = 10);

// The same for a process starting up: says in the log where the previous run's files went, and
// when they could not be moved, warns that they will be overwritten (the process goes on: a
// robot's mapping matters more than an old map).
void MovePreviousRunAside(const std::string& dir, const std::vector<std::string>& names);

}  // namespace omni::io
