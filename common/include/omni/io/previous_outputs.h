// A process restarted on the same output folder (by the supervisor after a crash, or by hand)
// would write its new, younger maps over the previous run's. Before it writes anything, the
// previous run's files are moved aside: `<dir>/previous/1` holds the run before, `2` the one
// before that, up to `keep` runs (older ones are deleted; ten by default, more than the
// supervisor's five restarts before it gives up on a process, so a crash loop cannot push the
// run before it out).
#pragma once

#include <memory>
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

// An output folder belongs to one process while it runs: a second mapper started on the same
// `--out` (a copy started by hand beside the supervisor's, or two mappers left on one default
// folder) would move the first one's files aside and then write its own over them. The lock is an
// flock on `<dir>/.omni-out.lock`, which the system lets go when the process ends however it ends
// (a crashed process restarted by the supervisor finds it free). The file keeps the holder's name
// and pid, to say who has the folder.
class OutputFolderLock {
 public:
  ~OutputFolderLock();
  OutputFolderLock(const OutputFolderLock&) = delete;
  OutputFolderLock& operator=(const OutputFolderLock&) = delete;

  // Takes `dir`'s lock for `process` (created if absent; `dir` must exist). An error when another
  // open lock holds it ("'DIR' is being written by rbpf_mapper (pid 123)") or the file cannot be
  // opened. On a file system without locks (NFS without lockd: ENOLCK) it warns and returns an
  // object that guards nothing. (NFS mounted with local locks guards only this machine.)
  static Result<std::unique_ptr<OutputFolderLock>> Take(const std::string& dir,
                                                        const std::string& process);
  static constexpr const char* kFileName = ".omni-out.lock";

 private:
  explicit OutputFolderLock(int fd) : fd_(fd) {}
  int fd_;
};

// What a mapper does with its `--out` at start-up, before it writes anything: creates the folder,
// takes its lock (held until the returned object goes), then moves the previous run's `names`
// aside (MovePreviousRunAside). An error (folder cannot be made, or another process has it)
// means the process must not start.
Result<std::unique_ptr<OutputFolderLock>> ClaimOutputFolder(const std::string& dir,
                                                            const std::string& process,
                                                            const std::vector<std::string>& names);

}  // namespace omni::io
