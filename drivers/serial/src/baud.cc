// Raw mode and baud rate through the Linux termios2 ioctls, so non-standard rates such as the
// RPLidar A3's 256000 work (BOTHER). Kept apart from <termios.h>, whose struct termios clashes
// with <asm/termbits.h>.
#include <asm/termbits.h>
#include <sys/ioctl.h>

#include <cerrno>
#include <cstring>
#include <string>

#include "omni/serial/serial_port.h"

namespace omni::serial {

int LineBaud(int fd) {
  struct termios2 tio;
  if (ioctl(fd, TCGETS2, &tio) != 0) return 0;
  return static_cast<int>(tio.c_ospeed);
}

Status ConfigureRaw(int fd, int baud, const std::string& name) {
  if (baud <= 0) {
    return MakeError(ErrorCode::kInvalidArgument,
                     name + ": baud rate " + std::to_string(baud) + " must be > 0");
  }
  struct termios2 tio;
  if (ioctl(fd, TCGETS2, &tio) != 0) {
    return MakeError(ErrorCode::kIo, name + ": not a terminal (TCGETS2: " +
                                         std::string(std::strerror(errno)) + ")");
  }
  // cfmakeraw(), spelled out for termios2.
  tio.c_iflag &= ~static_cast<tcflag_t>(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL |
                                        IXON | IXOFF | IXANY);
  tio.c_oflag &= ~static_cast<tcflag_t>(OPOST);
  tio.c_lflag &= ~static_cast<tcflag_t>(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
  tio.c_cflag &= ~static_cast<tcflag_t>(CSIZE | PARENB | CSTOPB | CRTSCTS | CBAUD);
  tio.c_cflag |= CS8 | CREAD | CLOCAL | BOTHER;
  tio.c_cflag &= ~static_cast<tcflag_t>(CBAUD << IBSHIFT);
  tio.c_cflag |= BOTHER << IBSHIFT;
  tio.c_ispeed = static_cast<speed_t>(baud);
  tio.c_ospeed = static_cast<speed_t>(baud);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  if (ioctl(fd, TCSETS2, &tio) != 0) {
    return MakeError(ErrorCode::kIo, name + ": cannot set raw mode at " + std::to_string(baud) +
                                         " baud: " + std::strerror(errno));
  }
  return Status::Ok();
}

}  // namespace omni::serial
