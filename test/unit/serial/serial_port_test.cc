#include <unistd.h>

#include <cstdlib>
#include <string>

#include <gtest/gtest.h>

#include "omni/common/time.h"
#include "omni/serial/pty.h"
#include "omni/serial/serial_port.h"

namespace omni::serial {
namespace {

std::string TempLink(const char* name) {
  return std::string("/tmp/omni_serial_test_") + std::to_string(getpid()) + "_" + name;
}

// Reads up to `n` bytes from the pty master within about 100 ms; returns how many came.
ssize_t ReadMaster(int fd, uint8_t* buf, size_t n) {
  size_t m = 0;
  for (int tries = 0; tries < 100 && m < n; ++tries) {
    const ssize_t k = read(fd, buf + m, n - m);
    if (k > 0) {
      m += static_cast<size_t>(k);
    } else {
      usleep(1000);
    }
  }
  return static_cast<ssize_t>(m);
}

TEST(SerialPort, MissingDeviceIsNotFoundNamingThePath) {
  auto port = SerialPort::Open("/dev/does-not-exist-omni", 115200);
  ASSERT_FALSE(port.ok());
  EXPECT_EQ(port.error().code, ErrorCode::kNotFound);
  EXPECT_NE(port.error().message.find("/dev/does-not-exist-omni"), std::string::npos);
}

TEST(SerialPort, RegularFileIsNotATerminal) {
  auto port = SerialPort::Open("/proc/self/status", 115200);
  ASSERT_FALSE(port.ok());
  EXPECT_NE(port.error().message.find("/proc/self/status"), std::string::npos);
}

TEST(SerialPort, BytesPassBothWaysUnchangedAtCustomBaud) {
  auto pty = Pty::Create(TempLink("a"));
  ASSERT_TRUE(pty.ok()) << pty.error().message;
  // 256000 is not a POSIX Bxxx constant: it needs termios2/BOTHER.
  auto port = SerialPort::Open((*pty)->path(), 256000);
  ASSERT_TRUE(port.ok()) << port.error().message;
  // Every byte value, including CR, LF, XON/XOFF and ^C, must pass through raw.
  uint8_t all[256];
  for (int i = 0; i < 256; ++i) all[i] = static_cast<uint8_t>(i);
  ASSERT_EQ(write((*pty)->master_fd(), all, sizeof(all)), 256);
  uint8_t got[256];
  size_t n = 0;
  while (n < sizeof(got)) {
    auto r = (*port)->Read(got + n, sizeof(got) - n, 1000);
    ASSERT_TRUE(r.ok()) << r.error().message;
    ASSERT_GT(*r, 0u) << "timeout after " << n << " bytes";
    n += *r;
  }
  for (int i = 0; i < 256; ++i) EXPECT_EQ(got[i], i);
  const uint8_t cmd[2] = {0xA5, 0x20};
  ASSERT_TRUE((*port)->Write(cmd, 2).ok());
  uint8_t back[2] = {0, 0};
  EXPECT_EQ(ReadMaster((*pty)->master_fd(), back, 2), 2);
  EXPECT_EQ(back[0], 0xA5);
  EXPECT_EQ(back[1], 0x20);
}

TEST(SerialPort, DtrOnAPtyFailsWithoutHarm) {
  auto pty = Pty::Create();
  ASSERT_TRUE(pty.ok());
  auto port = SerialPort::Open((*pty)->path(), 115200);
  ASSERT_TRUE(port.ok());
  const Status st = (*port)->SetDtr(true);
  // A pty has no modem lines (ENOTTY); the error names the port and the port still works.
  if (!st.ok()) {
    EXPECT_NE(st.message().find((*pty)->path()), std::string::npos);
  }
  auto r = (*port)->Read(nullptr, 0, 1);
  EXPECT_TRUE(r.ok());
}

TEST(SerialPort, VanishedDeviceIsUnavailable) {
  const std::string link = TempLink("b");
  auto pty = Pty::Create(link);
  ASSERT_TRUE(pty.ok());
  auto port = SerialPort::Open(link, 115200);
  ASSERT_TRUE(port.ok());
  pty->reset();  // the emulator closes the master: the device is unplugged
  uint8_t b[16];
  auto r = (*port)->Read(b, sizeof(b), 500);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kUnavailable);
  EXPECT_NE(access(link.c_str(), F_OK), 0) << "the symlink goes with the device";
  auto again = SerialPort::Open(link, 115200);
  EXPECT_FALSE(again.ok());
  EXPECT_EQ(again.error().code, ErrorCode::kNotFound);
}

// Two readers of one port would split its bytes between them: a second open, through the same
// path or another (the symlink and the pty itself), fails with a message saying so and leaves
// the first one working; once the first is closed the port opens again.
TEST(SerialPort, ASecondOpenOfAPortInUseFails) {
  const std::string link = TempLink("excl");
  auto pty = Pty::Create(link);
  ASSERT_TRUE(pty.ok()) << pty.error().message;
  auto first = SerialPort::Open(link, 115200);
  ASSERT_TRUE(first.ok()) << first.error().message;
  for (const std::string& path : {link, (*pty)->slave_path()}) {
    auto second = SerialPort::Open(path, 9600);
    ASSERT_FALSE(second.ok()) << path;
    EXPECT_EQ(second.error().code, ErrorCode::kUnavailable);
    EXPECT_NE(second.error().message.find(path + " is in use by another process"),
              std::string::npos)
        << second.error().message;
  }
  EXPECT_EQ(LineBaud((*pty)->master_fd()), 115200) << "the refused open changed the line";
  const uint8_t b = 0x42;
  ASSERT_EQ(write((*pty)->master_fd(), &b, 1), 1);
  uint8_t got = 0;
  auto r = (*first)->Read(&got, 1, 1000);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(*r, 1u);
  EXPECT_EQ(got, 0x42);
  first->reset();
  auto again = SerialPort::Open(link, 115200);
  EXPECT_TRUE(again.ok()) << again.error().message;
}

// Drain's wait: a queue that empties returns as soon as it does; one that never does (a wedged
// USB adapter) is an error after the timeout, never a hang; the queue's own error is passed on.
TEST(SerialPort, DrainWaitsForTheQueueButNotForever) {
  int left = 5;
  int polls = 0;
  const Status emptied = WaitForEmptyQueue(
      [&]() -> Result<int> {
        ++polls;
        return left > 0 ? left-- : 0;
      },
      1000, "serial port /dev/ttyTEST");
  EXPECT_TRUE(emptied.ok()) << emptied.message();
  EXPECT_EQ(polls, 6);

  const int64_t t0 = MonotonicMicros();
  const Status stuck =
      WaitForEmptyQueue([]() -> Result<int> { return 37; }, 50, "serial port /dev/ttyTEST");
  const int64_t waited_us = MonotonicMicros() - t0;
  ASSERT_FALSE(stuck.ok());
  EXPECT_EQ(stuck.error().code, ErrorCode::kUnavailable);
  EXPECT_NE(stuck.message().find("/dev/ttyTEST: 37 bytes still unsent after 50 ms"),
            std::string::npos)
      << stuck.message();
  EXPECT_GE(waited_us, 50000);
  EXPECT_LT(waited_us, 5000000);

  const Status gone = WaitForEmptyQueue(
      []() -> Result<int> { return MakeError(ErrorCode::kUnavailable, "device disconnected"); },
      1000, "serial port /dev/ttyTEST");
  ASSERT_FALSE(gone.ok());
  EXPECT_EQ(gone.error().code, ErrorCode::kUnavailable);
}

// On a pty the kernel keeps no output queue of its own: Drain returns at once even with the
// written bytes still unread on the master side, and they all arrive.
TEST(SerialPort, DrainOnAPtyReturnsAndTheBytesArrive) {
  auto pty = Pty::Create();
  ASSERT_TRUE(pty.ok());
  auto port = SerialPort::Open((*pty)->path(), 9600);
  ASSERT_TRUE(port.ok());
  const uint8_t cmd[3] = {0xFF, 0xAA, 0x00};
  ASSERT_TRUE((*port)->Write(cmd, sizeof(cmd)).ok());
  const Status st = (*port)->Drain(200);
  EXPECT_TRUE(st.ok()) << st.message();
  uint8_t back[3] = {0, 0, 0};
  EXPECT_EQ(ReadMaster((*pty)->master_fd(), back, 3), 3);
  EXPECT_EQ(back[1], 0xAA);
}

}  // namespace
}  // namespace omni::serial
