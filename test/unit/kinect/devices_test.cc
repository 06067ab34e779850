// omni-devices without USB hardware: the id table, the sysfs tty lookup on a fake tree, the
// Kinect v1 motor requests against a recording transfer function, and the program itself.
#include <sys/stat.h>
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "../common/test_paths.h"
#include "usb_devices.h"

namespace omni::devices {
namespace {

TEST(DevicesClassify, TableOfIds) {
  struct Case {
    uint16_t vid, pid;
    DeviceKind kind;
    const char* text;
  };
  const Case cases[] = {
      {0x10c4, 0xea60, DeviceKind::kSerialBridge, "USB-serial bridge (RPLidar or IMU)"},
      {0x1a86, 0x7523, DeviceKind::kSerialBridge, "CH340"},
      {0x0403, 0x6001, DeviceKind::kSerialBridge, "FTDI"},
      {0x045e, 0x02ae, DeviceKind::kKinectCamera, "camera"},
      {0x045e, 0x02b0, DeviceKind::kKinectMotor, "motor"},
      {0x045e, 0x02ad, DeviceKind::kKinectAudio, "audio"},
      {0x045e, 0x07a5, DeviceKind::kUnknown, ""},  // a Microsoft mouse receiver
      {0x1d6b, 0x0002, DeviceKind::kUnknown, ""},  // a root hub
      {0x10c4, 0xea61, DeviceKind::kUnknown, ""},
  };
  for (const Case& c : cases) {
    const Classification k = Classify({c.vid, c.pid});
    EXPECT_EQ(k.kind, c.kind) << std::hex << c.vid << ":" << c.pid;
    EXPECT_NE(k.what.find(c.text), std::string::npos) << k.what;
  }
  EXPECT_STREQ(DeviceKindName(DeviceKind::kKinectMotor), "kinect-motor");
}

TEST(DevicesSysfs, PortNamesAndTtyNodes) {
  EXPECT_EQ(SysfsPortName(1, {1, 2}), "1-1.2");
  EXPECT_EQ(SysfsPortName(3, {4}), "3-4");
  EXPECT_EQ(SysfsPortName(2, {}), "usb2");
  const std::string root = testing::TempDir() + "/usb";
  for (const std::string d :
       {"", "/1-1.2", "/1-1.2:1.0", "/1-1.2:1.0/ttyUSB3", "/1-1.3", "/1-1.3:1.0", "/1-1.3:1.0/tty",
        "/1-1.3:1.0/tty/ttyACM0", "/1-1.20:1.0", "/1-1.20:1.0/ttyUSB9"}) {
    ::mkdir((root + d).c_str(), 0755);
  }
  EXPECT_EQ(TtyNodes(root, "1-1.2"), std::vector<std::string>{"/dev/ttyUSB3"});
  EXPECT_EQ(TtyNodes(root, "1-1.3"), std::vector<std::string>{"/dev/ttyACM0"});
  EXPECT_TRUE(TtyNodes(root, "1-1.4").empty());
  EXPECT_TRUE(TtyNodes(root + "/absent", "1-1.2").empty());
}

struct Recorder {
  std::vector<ControlRequest> sent;
  int result = 0;
  std::vector<uint8_t> reply;
  TransferFn Fn() {
    return [this](const ControlRequest& r, uint8_t* data) {
      sent.push_back(r);
      if (result < 0) return result;
      if (data != nullptr) {
        for (size_t i = 0; i < reply.size() && i < r.length; ++i) data[i] = reply[i];
        return static_cast<int>(std::min<size_t>(reply.size(), r.length));
      }
      return 0;
    };
  }
};

TEST(DevicesKinectMotor, TiltRequestEncoding) {
  Recorder rec;
  ASSERT_TRUE(SetTilt(rec.Fn(), 10).ok());
  ASSERT_TRUE(SetTilt(rec.Fn(), -15.5).ok());
  ASSERT_TRUE(SetTilt(rec.Fn(), 31).ok());
  ASSERT_EQ(rec.sent.size(), 3u);
  EXPECT_EQ(rec.sent[0].request_type, 0x40);
  EXPECT_EQ(rec.sent[0].request, 0x31);
  EXPECT_EQ(rec.sent[0].value, 20);
  EXPECT_EQ(rec.sent[0].index, 0);
  EXPECT_EQ(rec.sent[0].length, 0);
  EXPECT_EQ(rec.sent[1].value, 0xffe1);  // -31 half degrees, two's complement
  EXPECT_EQ(rec.sent[2].value, 62);
  EXPECT_FALSE(SetTilt(rec.Fn(), 31.5).ok());
  EXPECT_FALSE(SetTilt(rec.Fn(), -40).ok());
  EXPECT_FALSE(TiltRequest(std::nan("")).ok());
  EXPECT_EQ(rec.sent.size(), 3u);  // out-of-range values never reach the device
}

TEST(DevicesKinectMotor, LedRequestEncoding) {
  Recorder rec;
  for (int mode = 0; mode <= 6; ++mode) ASSERT_TRUE(SetLed(rec.Fn(), mode).ok());
  ASSERT_EQ(rec.sent.size(), 7u);
  for (int mode = 0; mode <= 6; ++mode) {
    const ControlRequest& r = rec.sent[static_cast<size_t>(mode)];
    EXPECT_EQ(r.request_type, 0x40);
    EXPECT_EQ(r.request, 0x06);
    EXPECT_EQ(r.value, mode);
    EXPECT_EQ(r.index, 0);
    EXPECT_EQ(r.length, 0);
  }
  EXPECT_FALSE(SetLed(rec.Fn(), 7).ok());
  EXPECT_FALSE(SetLed(rec.Fn(), -1).ok());
  EXPECT_STREQ(LedModeName(2), "red");
}

TEST(DevicesKinectMotor, ReadStateRequestAndParse) {
  Recorder rec;
  // ax = +819 (1 g), ay = -2, az = 0x0100; tilt -20 half degrees; moving.
  rec.reply = {0x00, 0x00, 0x03, 0x33, 0xff, 0xfe, 0x01, 0x00, 0xec, 0x04};
  auto s = ReadMotorState(rec.Fn());
  ASSERT_TRUE(s.ok()) << s.error().ToString();
  ASSERT_EQ(rec.sent.size(), 1u);
  EXPECT_EQ(rec.sent[0].request_type, 0xc0);
  EXPECT_EQ(rec.sent[0].request, 0x32);
  EXPECT_EQ(rec.sent[0].value, 0);
  EXPECT_EQ(rec.sent[0].index, 0);
  EXPECT_EQ(rec.sent[0].length, 10);
  EXPECT_EQ(s->accel_counts[0], 819);
  EXPECT_EQ(s->accel_counts[1], -2);
  EXPECT_EQ(s->accel_counts[2], 256);
  EXPECT_NEAR(s->accel_m_s2[0], 9.80665, 1e-9);
  EXPECT_TRUE(s->tilt_known);
  EXPECT_DOUBLE_EQ(s->tilt_deg, -10.0);
  EXPECT_EQ(s->status, 4);
  EXPECT_STREQ(MotorStatusName(s->status), "moving");
  // Tilt unknown (0x80) and a short reply.
  rec.reply[8] = 0x80;
  auto u = ReadMotorState(rec.Fn());
  ASSERT_TRUE(u.ok());
  EXPECT_FALSE(u->tilt_known);
  rec.reply.resize(6);
  EXPECT_FALSE(ReadMotorState(rec.Fn()).ok());
  rec.result = -4;  // LIBUSB_ERROR_NO_DEVICE
  auto e = ReadMotorState(rec.Fn());
  ASSERT_FALSE(e.ok());
  EXPECT_NE(e.error().message.find("045e:02b0"), std::string::npos);
  EXPECT_FALSE(SetTilt(rec.Fn(), 0).ok());
}

struct Out {
  int code;
  std::string text;
};

Out RunTool(const std::string& args) {
  const std::string cmd = std::string(OMNI_BINARY_DIR) + "/bin/omni-devices " + args + " 2>&1";
  Out o{-1, ""};
  FILE* p = ::popen(cmd.c_str(), "r");
  if (p == nullptr) return o;
  char buf[512];
  while (std::fgets(buf, sizeof(buf), p) != nullptr) o.text += buf;
  const int st = ::pclose(p);
  o.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return o;
}

TEST(DevicesProgram, ListsOrSaysNoKnownDevices) {
  const Out o = RunTool("");
  EXPECT_EQ(RunTool("--help").code, 0);
  EXPECT_NE(RunTool("frobnicate").code, 0);
  if (o.text.find("libusb could not start") != std::string::npos) {
    // No USB access here (a container): said, and exit 1 rather than "no devices".
    EXPECT_EQ(o.code, 1) << o.text;
    EXPECT_EQ(RunTool("--json").code, 1);
    GTEST_SKIP() << "libusb cannot start on this machine: " << o.text;
  }
  EXPECT_EQ(o.code, 0) << o.text;
  EXPECT_TRUE(o.text.find("no known devices") != std::string::npos ||
              o.text.find("what") != std::string::npos)
      << o.text;
  const Out j = RunTool("--json");
  EXPECT_EQ(j.code, 0) << j.text;
  EXPECT_EQ(j.text.rfind("[", 0), 0u) << j.text;
}

TEST(DevicesProgram, KinectCommandsWithoutAKinect) {
  const Out probe = RunTool("--json");
  if (probe.text.find("kinect-motor") != std::string::npos) {
    GTEST_SKIP() << "a Kinect motor is connected: not moving it from a test";
  }
  for (const char* cmd : {"kinect-tilt 5", "kinect-led 1", "kinect-accel"}) {
    const Out o = RunTool(cmd);
    EXPECT_EQ(o.code, 1) << cmd << ": " << o.text;
    EXPECT_NE(o.text.find("no Kinect motor (045e:02b0) found"), std::string::npos) << o.text;
  }
  EXPECT_EQ(RunTool("kinect-tilt 45").code, 2);
  EXPECT_EQ(RunTool("kinect-led 9").code, 2);
  EXPECT_EQ(RunTool("kinect-tilt").code, 2);
}

}  // namespace
}  // namespace omni::devices
