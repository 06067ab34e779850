#include "omni/io/previous_outputs.h"

#include <filesystem>

#include "omni/common/log.h"

namespace omni::io {

namespace fs = std::filesystem;

Result<int> KeepPreviousOutputs(const std::string& dir, const std::vector<std::string>& names,
                                int keep) {
  if (keep < 1) return MakeError(ErrorCode::kInvalidArgument, "keep must be at least 1");
  std::error_code ec;
  std::vector<fs::path> found;
  for (const std::string& n : names) {
    if (n.empty() || n.find('/') != std::string::npos)
      return MakeError(ErrorCode::kInvalidArgument, "output name '" + n + "' is not a file name");
    const fs::path p = fs::path(dir) / n;
    if (fs::is_regular_file(p, ec)) found.push_back(p);
  }
  if (found.empty()) return 0;
  const fs::path runs = fs::path(dir) / "previous";
  const auto run = [&runs](int i) { return runs / std::to_string(i); };
  // The oldest kept run goes; the others move one number up.
  fs::remove_all(run(keep), ec);
  if (ec)
    return MakeError(ErrorCode::kIo, "cannot remove '" + run(keep).string() + "': " + ec.message());
  for (int i = keep - 1; i >= 1; --i) {
    if (!fs::exists(run(i), ec)) continue;
    fs::rename(run(i), run(i + 1), ec);
    if (ec)
      return MakeError(ErrorCode::kIo, "cannot move '" + run(i).string() + "' to '" +
                                           run(i + 1).string() + "': " + ec.message());
  }
  fs::create_directories(run(1), ec);
  if (ec)
    return MakeError(ErrorCode::kIo, "cannot create '" + run(1).string() + "': " + ec.message());
  int moved = 0;
  for (const fs::path& p : found) {
    fs::rename(p, run(1) / p.filename(), ec);
    if (ec)
      return MakeError(ErrorCode::kIo, "cannot move '" + p.string() + "' to '" + run(1).string() +
                                           "': " + ec.message());
    ++moved;
  }
  return moved;
}

void MovePreviousRunAside(const std::string& dir, const std::vector<std::string>& names) {
  const Result<int> moved = KeepPreviousOutputs(dir, names);
  if (!moved.ok()) {
    LOG_WARN << "cannot keep the previous run's outputs in " << dir << "/previous ("
             << moved.error().message << "); this run will write over them";
  } else if (*moved > 0) {
    LOG_INFO << "the previous run's outputs (" << *moved << " files) moved to " << dir
             << "/previous/1";
  }
}

}  // namespace omni::io
