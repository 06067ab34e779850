#include "omni/serial/serial_port.h"

#include <fcntl.h>
#include <poll.h>
#include <sys/file.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "omni/common/time.h"

namespace omni::serial {
namespace {

std::string Errno() { return std::strerror(errno); }

bool IsGoneErrno(int e) { return e == EIO || e == ENXIO || e == ENODEV || e == EBADF; }

Error InUse(const std::string& path) {
  return MakeError(ErrorCode::kUnavailable,
                   "serial port " + path + " is in use by another process");
}

}  // namespace

Result<std::unique_ptr<SerialPort>> SerialPort::Open(const std::string& path, int baud) {
  const int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    const int e = errno;
    const ErrorCode code =
        (e == ENOENT || e == ENXIO || e == ENODEV) ? ErrorCode::kNotFound : ErrorCode::kIo;
    if (e == EBUSY) return InUse(path);  // another process holds it exclusively (TIOCEXCL)
    return MakeError(code, "serial port " + path + ": cannot open: " + std::strerror(e));
  }
  // Two readers of one port would each get part of the bytes and both see damaged frames, and
  // the second open would reset the first one's line settings; so the port is locked before it
  // is configured. flock() holds between any two opens (root, or one process, included);
  // TIOCEXCL also keeps out programs that do not flock (their open fails with EBUSY) unless they
  // run with CAP_SYS_ADMIN. A file that is not a terminal (ENOTTY) is left to ConfigureRaw.
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int e = errno;
    ::close(fd);
    if (e == EWOULDBLOCK) return InUse(path);
    return MakeError(ErrorCode::kIo, "serial port " + path + ": cannot lock: " + std::strerror(e));
  }
  if (::ioctl(fd, TIOCEXCL) != 0 && errno != ENOTTY) {
    const int e = errno;
    ::close(fd);
    return MakeError(ErrorCode::kIo,
                     "serial port " + path + ": cannot open exclusively: " + std::strerror(e));
  }
  Status st = ConfigureRaw(fd, baud, "serial port " + path);
  if (!st.ok()) {
    ::close(fd);
    return st.error();
  }
  tcflush(fd, TCIOFLUSH);
  return std::unique_ptr<SerialPort>(new SerialPort(fd, path, baud));
}

SerialPort::~SerialPort() {
  if (fd_ < 0) return;
  // The exclusive flag belongs to the tty, not to this descriptor: it outlives the close while
  // another descriptor keeps the tty open (a pty whose emulator holds the slave), and would
  // refuse the next open of the port, ours included.
  ::ioctl(fd_, TIOCNXCL);
  ::close(fd_);
}

Result<size_t> SerialPort::Read(uint8_t* data, size_t size, int timeout_ms) {
  pollfd p{fd_, POLLIN, 0};
  int r;
  do {
    r = ::poll(&p, 1, timeout_ms);
  } while (r < 0 && errno == EINTR);
  if (r < 0) return MakeError(ErrorCode::kIo, "serial port " + path_ + ": poll: " + Errno());
  if (r == 0) return size_t{0};
  if ((p.revents & POLLIN) == 0 && (p.revents & (POLLHUP | POLLERR | POLLNVAL)) != 0) {
    return MakeError(ErrorCode::kUnavailable, "serial port " + path_ + ": device disconnected");
  }
  const ssize_t n = ::read(fd_, data, size);
  if (n < 0) {
    if (errno == EAGAIN || errno == EINTR) return size_t{0};
    if (IsGoneErrno(errno)) {
      return MakeError(ErrorCode::kUnavailable,
                       "serial port " + path_ + ": device disconnected (" + Errno() + ")");
    }
    return MakeError(ErrorCode::kIo, "serial port " + path_ + ": read: " + Errno());
  }
  if (n == 0) {
    // Readable but end of file: the line was hung up.
    return MakeError(ErrorCode::kUnavailable, "serial port " + path_ + ": device disconnected");
  }
  return static_cast<size_t>(n);
}

Status SerialPort::Write(const uint8_t* data, size_t size, int timeout_ms) {
  const int64_t deadline = MonotonicMicros() + int64_t{timeout_ms} * 1000;
  size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(fd_, data + done, size - done);
    if (n > 0) {
      done += static_cast<size_t>(n);
      continue;
    }
    if (n < 0 && errno != EAGAIN && errno != EINTR) {
      if (IsGoneErrno(errno)) {
        return MakeError(ErrorCode::kUnavailable,
                         "serial port " + path_ + ": device disconnected (" + Errno() + ")");
      }
      return MakeError(ErrorCode::kIo, "serial port " + path_ + ": write: " + Errno());
    }
    const int64_t left_us = deadline - MonotonicMicros();
    if (left_us <= 0) {
      return MakeError(ErrorCode::kIo, "serial port " + path_ + ": write timed out after " +
                                           std::to_string(done) + " of " + std::to_string(size) +
                                           " bytes");
    }
    pollfd p{fd_, POLLOUT, 0};
    ::poll(&p, 1, static_cast<int>(left_us / 1000) + 1);
  }
  return Status::Ok();
}

Status SerialPort::SetDtr(bool on) {
  int bits = TIOCM_DTR;
  if (ioctl(fd_, on ? TIOCMBIS : TIOCMBIC, &bits) != 0) {
    return MakeError(ErrorCode::kIo, "serial port " + path_ + ": cannot " +
                                         (on ? std::string("set") : std::string("clear")) +
                                         " DTR: " + Errno());
  }
  return Status::Ok();
}

Status SerialPort::SetBaud(int baud) {
  Status st = ConfigureRaw(fd_, baud, "serial port " + path_);
  if (st.ok()) baud_ = baud;
  return st;
}

void SerialPort::FlushInput() { tcflush(fd_, TCIOFLUSH); }

Status SerialPort::Drain(int timeout_ms) {
  const std::string name = "serial port " + path_;
  Status st = WaitForEmptyQueue(
      [&]() -> Result<int> {
        int n = 0;
        if (ioctl(fd_, TIOCOUTQ, &n) == 0) return n;
        if (IsGoneErrno(errno))
          return MakeError(ErrorCode::kUnavailable,
                           name + ": device disconnected (" + Errno() + ")");
        return MakeError(ErrorCode::kIo, name + ": TIOCOUTQ: " + Errno());
      },
      timeout_ms, name);
  if (!st.ok()) return st;
  // The queue is empty: what is left is the UART's FIFO, a wait the kernel bounds.
  if (tcdrain(fd_) != 0 && IsGoneErrno(errno))
    return MakeError(ErrorCode::kUnavailable, name + ": device disconnected (" + Errno() + ")");
  return Status::Ok();
}

Status WaitForEmptyQueue(const std::function<Result<int>()>& queued, int timeout_ms,
                         const std::string& name) {
  const int64_t deadline = MonotonicMicros() + int64_t{timeout_ms} * 1000;
  int last = 0;
  for (;;) {
    Result<int> n = queued();
    if (!n.ok()) return n.error();
    if (*n <= 0) return Status::Ok();
    last = *n;
    if (MonotonicMicros() >= deadline) break;
    ::usleep(1000);
  }
  return MakeError(ErrorCode::kUnavailable, name + ": " + std::to_string(last) +
                                                " bytes still unsent after " +
                                                std::to_string(timeout_ms) + " ms");
}

}  // namespace omni::serial
