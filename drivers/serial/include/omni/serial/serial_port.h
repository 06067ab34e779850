// A raw serial port (8N1, no flow control) opened by path, with any baud rate the driver
// accepts (custom rates through termios2/BOTHER) and DTR control.
//
// Errors name the port. A port whose device vanished (USB unplugged, pty master closed) reports
// ErrorCode::kUnavailable from Read/Write so the caller can close it and retry the path.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "omni/common/result.h"

namespace omni::serial {

class SerialPort {
 public:
  // Opens `path` raw at `baud`, for this process alone (flock, and TIOCEXCL until closed).
  // kNotFound when the path does not exist; kUnavailable with "<path> is in use by another
  // process" when another open holds it; kIo otherwise.
  static Result<std::unique_ptr<SerialPort>> Open(const std::string& path, int baud);
  ~SerialPort();
  SerialPort(const SerialPort&) = delete;
  SerialPort& operator=(const SerialPort&) = delete;

  // Reads up to `size` bytes, waiting at most `timeout_ms` for the first. Returns the number of
  // bytes read (0 on timeout); kUnavailable when the device is gone.
  Result<size_t> Read(uint8_t* data, size_t size, int timeout_ms);
  // Writes all bytes (waits up to `timeout_ms` in total); kUnavailable when the device is gone.
  Status Write(const uint8_t* data, size_t size, int timeout_ms = 1000);
  // Sets or clears DTR. Fails with kIo on ports without modem lines (a pty: ENOTTY); callers
  // that use DTR for motor control treat that as a warning, never as fatal.
  Status SetDtr(bool on);
  // Changes the baud rate of the open port.
  Status SetBaud(int baud);
  // Discards unread input and unsent output.
  void FlushInput();
  // Waits until the bytes written have left the port, e.g. before a baud change, which takes
  // effect at once: until the kernel's output queue (TIOCOUTQ) is empty, then for the UART's own
  // FIFO (tcdrain, which the kernel bounds once the queue is empty). kUnavailable when the
  // device is gone or its queue has not emptied within `timeout_ms` (a wedged USB adapter): the
  // caller reopens the port instead of blocking on it.
  Status Drain(int timeout_ms = 1000);

  const std::string& path() const { return path_; }
  int baud() const { return baud_; }
  int fd() const { return fd_; }

 private:
  SerialPort(int fd, std::string path, int baud) : fd_(fd), path_(std::move(path)), baud_(baud) {}
  int fd_;
  std::string path_;
  int baud_;
};

// The output baud rate a tty is set to (for a pty master: the rate its slave was opened at); 0
// when `fd` is not a terminal.
int LineBaud(int fd);

// Polls `queued` (bytes still waiting to go out, or an error) every millisecond until it reports
// 0; kUnavailable naming `name` when it still reports bytes after `timeout_ms`. Drain's wait,
// apart from the port, so that it can be tested with a queue that never empties.
Status WaitForEmptyQueue(const std::function<Result<int>()>& queued, int timeout_ms,
                         const std::string& name);

// Applies raw 8N1 settings and `baud` (standard or custom) to an open tty fd.
Status ConfigureRaw(int fd, int baud, const std::string& name);

}  // namespace omni::serial
