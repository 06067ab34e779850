#include "omni/serial/pty.h"

#include <fcntl.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "omni/serial/serial_port.h"

namespace omni::serial {

Result<std::unique_ptr<Pty>> Pty::Create(const std::string& link_path) {
  std::unique_ptr<Pty> pty(new Pty());
  pty->master_ = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (pty->master_ < 0) {
    return MakeError(ErrorCode::kIo, std::string("posix_openpt: ") + std::strerror(errno));
  }
  if (grantpt(pty->master_) != 0 || unlockpt(pty->master_) != 0) {
    return MakeError(ErrorCode::kIo, std::string("grantpt/unlockpt: ") + std::strerror(errno));
  }
  char name[128];
  if (ptsname_r(pty->master_, name, sizeof(name)) != 0) {
    return MakeError(ErrorCode::kIo, std::string("ptsname: ") + std::strerror(errno));
  }
  pty->slave_path_ = name;
  pty->slave_keepalive_ = ::open(name, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (pty->slave_keepalive_ < 0) {
    return MakeError(ErrorCode::kIo,
                     "pty " + pty->slave_path_ + ": cannot open: " + std::strerror(errno));
  }
  Status st = ConfigureRaw(pty->slave_keepalive_, 115200, "pty " + pty->slave_path_);
  if (!st.ok()) return st.error();
  const int flags = fcntl(pty->master_, F_GETFL);
  fcntl(pty->master_, F_SETFL, flags | O_NONBLOCK);
  if (!link_path.empty()) {
    struct stat sb;
    if (lstat(link_path.c_str(), &sb) == 0) {
      if (!S_ISLNK(sb.st_mode)) {
        return MakeError(
            ErrorCode::kInvalidArgument,
            "pty link " + link_path + " exists and is not a symlink; not replacing it");
      }
      ::unlink(link_path.c_str());
    }
    if (::symlink(name, link_path.c_str()) != 0) {
      return MakeError(ErrorCode::kIo,
                       "pty link " + link_path + " -> " + name + ": " + std::strerror(errno));
    }
    pty->link_path_ = link_path;
  }
  return pty;
}

Pty::~Pty() {
  if (!link_path_.empty()) ::unlink(link_path_.c_str());
  if (slave_keepalive_ >= 0) ::close(slave_keepalive_);
  if (master_ >= 0) ::close(master_);
}

}  // namespace omni::serial
