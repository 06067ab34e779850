#include "omni/io/previous_outputs.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
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

OutputFolderLock::~OutputFolderLock() {
  if (fd_ >= 0) ::close(fd_);  // closing the last descriptor lets the flock go
}

Result<std::unique_ptr<OutputFolderLock>> OutputFolderLock::Take(const std::string& dir,
                                                                 const std::string& process) {
  const std::string path = (fs::path(dir) / kFileName).string();
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0)
    return MakeError(ErrorCode::kIo, "cannot open '" + path + "': " + std::strerror(errno));
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    std::string holder;
    if (err == EWOULDBLOCK) {
      char buf[256];
      const ssize_t n = ::pread(fd, buf, sizeof(buf) - 1, 0);
      if (n > 0) holder.assign(buf, static_cast<size_t>(n));
      while (!holder.empty() && (holder.back() == '\n' || holder.back() == '\0')) holder.pop_back();
    }
    if (err == ENOLCK || err == EOPNOTSUPP || err == ENOSYS || err == EINVAL) {
      // A file system without locks (NFS without lockd, some FUSE mounts): mapping matters more
      // than the lock; it says so, and runs unguarded.
      LOG_WARN << "cannot lock '" << path << "' (" << std::strerror(err)
               << "): this file system has no locks, so nothing keeps another process from "
                  "writing to "
               << dir << " too";
      return std::unique_ptr<OutputFolderLock>(new OutputFolderLock(fd));
    }
    ::close(fd);
    if (err != EWOULDBLOCK)
      return MakeError(ErrorCode::kIo, "cannot lock '" + path + "': " + std::strerror(err));
    return MakeError(ErrorCode::kUnavailable,
                     "'" + dir + "' is being written by " +
                         (holder.empty() ? std::string("another process") : holder) +
                         "; give each process its own --out folder");
  }
  // Ours now: say who holds it (for the next one refused). Failing to write only loses the name.
  const std::string who = process + " (pid " + std::to_string(::getpid()) + ")\n";
  if (::ftruncate(fd, 0) == 0) {
    const ssize_t n = ::pwrite(fd, who.data(), who.size(), 0);
    (void)n;
  }
  return std::unique_ptr<OutputFolderLock>(new OutputFolderLock(fd));
}

Result<std::unique_ptr<OutputFolderLock>> ClaimOutputFolder(const std::string& dir,
                                                            const std::string& process,
                                                            const std::vector<std::string>& names) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec)
    return MakeError(ErrorCode::kIo, "cannot create output folder '" + dir + "': " + ec.message());
  auto lock = OutputFolderLock::Take(dir, process);
  if (!lock.ok()) return lock;
  MovePreviousRunAside(dir, names);
  return lock;
}

}  // namespace omni::io
