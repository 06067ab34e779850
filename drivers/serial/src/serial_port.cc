#include "omni/serial/serial_port.h"

#include <fcntl.h>
#include <poll.h>
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

}  // namespace

Result<std::unique_ptr<SerialPort>> SerialPort::Open(const std::string& path, int baud) {
  const int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    const int e = errno;
    const ErrorCode code =
        (e == ENOENT || e == ENXIO || e == ENODEV) ? ErrorCode::kNotFound : ErrorCode::kIo;
    return MakeError(code, "serial port " + path + ": cannot open: " + std::strerror(e));
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
  if (fd_ >= 0) ::close(fd_);
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

void SerialPort::Drain() { tcdrain(fd_); }

}  // namespace omni::serial
