// The IMU driver's own logic: frame-cycle learning and drop counting, sample stamps, the config
// file, the message, the emulator's motion, and the driver on a bare pty.
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "../common/test_paths.h"
#include "omni/imu/driver.h"
#include "omni/imu/emulator.h"
#include "omni/imu/imu_node.h"
#include "omni/serial/pty.h"

namespace omni::imu {
namespace {

TEST(FrameCycle, LearnsTheCycleFromAMidPeriodStartAndCountsMissingFrames) {
  FrameCycle c;
  // Joined in the middle of a period: 0x53, 0x59, then 0x51, 0x52, 0x53 (repeat: learned).
  for (uint8_t t : {0x53, 0x59, 0x51, 0x52}) EXPECT_EQ(c.Add(t), 0);
  EXPECT_FALSE(c.learned());
  EXPECT_EQ(c.Add(0x53), 0);
  ASSERT_TRUE(c.learned());
  EXPECT_EQ(c.types(), (std::vector<uint8_t>{0x51, 0x52, 0x53, 0x59}));
  EXPECT_EQ(c.last_type(), 0x59);
  EXPECT_EQ(c.Add(0x59), 0);
  EXPECT_EQ(c.Add(0x51), 0);
  EXPECT_EQ(c.Add(0x53), 1);  // 0x52 lost
  EXPECT_EQ(c.Add(0x52), 2);  // 0x59 and 0x51 lost
  EXPECT_EQ(c.Add(0x53), 0);
}

TEST(FrameCycle, ATypeLostWhileLearningJoinsLater) {
  FrameCycle c;
  for (uint8_t t : {0x51, 0x52, 0x51}) c.Add(t);  // 0x53 of the first period was lost
  ASSERT_TRUE(c.learned());
  EXPECT_EQ(c.last_type(), 0x52);
  EXPECT_EQ(c.Add(0x52), 0);
  EXPECT_EQ(c.Add(0x53), 0);  // joins the cycle, not a drop
  EXPECT_EQ(c.last_type(), 0x53);
  EXPECT_EQ(c.Add(0x51), 0);
  EXPECT_EQ(c.Add(0x53), 1);
  c.Reset();
  EXPECT_FALSE(c.learned());
  EXPECT_TRUE(c.types().empty());
}

TEST(SampleStamper, SpreadsSamplesReadTogetherAndNeverGoesBack) {
  SampleStamper s(100.0);
  EXPECT_EQ(s.Stamp(1'000'000, 0, 3), 980'000);
  EXPECT_EQ(s.Stamp(1'000'000, 1, 3), 990'000);
  EXPECT_EQ(s.Stamp(1'000'000, 2, 3), 1'000'000);
  // A read stamped earlier than the last sample (clock step): strictly after it anyway.
  EXPECT_EQ(s.Stamp(995'000, 0, 1), 1'000'001);
  EXPECT_EQ(s.Stamp(1'010'000, 0, 1), 1'010'000);
  // Four samples 20 ms after the last one: the device is faster than rate_hz says; they fill
  // the 20 ms evenly instead of reaching back 30 ms.
  EXPECT_EQ(s.Stamp(1'030'000, 0, 4), 1'015'000);
  EXPECT_EQ(s.Stamp(1'030'000, 1, 4), 1'020'000);
  EXPECT_EQ(s.Stamp(1'030'000, 2, 4), 1'025'000);
  EXPECT_EQ(s.Stamp(1'030'000, 3, 4), 1'030'000);
}

TEST(ImuConfig, ShippedFileLoads) {
  DriverOptions d;
  NodeOptions n;
  const Status st =
      LoadImuOptions(std::string(OMNI_SOURCE_DIR) + "/config/imu_driver.yaml", &d, &n);
  ASSERT_TRUE(st.ok()) << st.message();
  EXPECT_EQ(d.port, "/dev/imu");
  EXPECT_EQ(d.baud, 9600);
  EXPECT_EQ(d.trigger, "auto");
  EXPECT_DOUBLE_EQ(d.rate_hz, 10.0);
  EXPECT_EQ(n.channel, "IMU");
  EXPECT_DOUBLE_EQ(n.orientation_var[2], 1.2e-3);
  EXPECT_DOUBLE_EQ(n.linear_acceleration_var[0], 4e-4);
}

Status LoadText(const std::string& text) {
  const std::string path = ::omni::testing::TempDir() + "/imu.yaml";
  std::ofstream(path) << text;
  DriverOptions d;
  NodeOptions n;
  return LoadImuOptions(path, &d, &n);
}

TEST(ImuConfig, BadValuesAreErrorsNamingTheKey) {
  Status st = LoadText("port: /dev/x\nbaud: 12345\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("baud"), std::string::npos) << st.message();
  st = LoadText("port: /dev/x\ndata_timout_s: 1\n");  // misspelled
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("data_timout_s"), std::string::npos) << st.message();
  st = LoadText("port: /dev/x\ncovariance:\n  orientation: [1, 2]\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("covariance.orientation"), std::string::npos) << st.message();
  st = LoadText("baud: 115200\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("port"), std::string::npos) << st.message();
  st = LoadText("port: /dev/x\nrate_hz: 1\ndata_timeout_s: 1.5\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("data_timeout_s"), std::string::npos) << st.message();
  EXPECT_TRUE(LoadText("port: /dev/x\nbaud: 0\ntrigger: quaternion\n").ok());
}

TEST(ImuMessage, CopiesUnitsAndCovariances) {
  StampedSample s;
  s.utime = 42;
  s.sample.accel_m_s2 = {0.1, 0.2, 9.8};
  s.sample.gyro_rad_s = {0.01, 0.02, 0.2};
  s.sample.orientation_wxyz = {0.5, 0.5, 0.5, 0.5};
  s.sample.has_orientation = true;
  s.sample.mag_raw = {100, 200, 300};
  s.sample.has_mag = true;
  s.sample.temperature_c = 25.5;
  s.sample.has_temperature = true;
  NodeOptions n;
  n.frame = "imu_link";
  omni::imu_t m = MakeImuMessage(s, 7, n);
  EXPECT_EQ(m.utime, 42);
  EXPECT_EQ(m.seq, 7);
  EXPECT_EQ(m.frame, "imu_link");
  EXPECT_DOUBLE_EQ(m.linear_acceleration_m_s2[2], 9.8);
  EXPECT_DOUBLE_EQ(m.angular_velocity_rad_s[2], 0.2);
  EXPECT_DOUBLE_EQ(m.orientation_wxyz[3], 0.5);
  EXPECT_DOUBLE_EQ(m.orientation_covariance[0], n.orientation_var[0]);
  EXPECT_DOUBLE_EQ(m.orientation_covariance[8], n.orientation_var[2]);
  EXPECT_DOUBLE_EQ(m.orientation_covariance[1], 0.0);
  EXPECT_DOUBLE_EQ(m.angular_velocity_covariance[4], n.angular_velocity_var[1]);
  EXPECT_DOUBLE_EQ(m.linear_acceleration_covariance[8], n.linear_acceleration_var[2]);
  EXPECT_TRUE(std::isnan(m.magnetic_field_t[0]));  // no scale configured
  EXPECT_FLOAT_EQ(m.temperature_c, 25.5f);
  n.mag_tesla_per_lsb = 1e-7;
  s.sample.has_orientation = false;
  m = MakeImuMessage(s, 8, n);
  EXPECT_DOUBLE_EQ(m.magnetic_field_t[1], 2e-5);
  EXPECT_DOUBLE_EQ(m.orientation_covariance[0], -1.0);
}

// Decodes one encoded period the way the driver does (closing frame: the last one).
ImuSample Decode(const std::vector<uint8_t>& bytes, uint8_t trigger) {
  FrameParser p;
  std::vector<Frame> frames;
  p.Feed(bytes.data(), bytes.size(), &frames);
  SampleAssembler a(trigger);
  ImuSample s, out;
  bool got = false;
  for (const Frame& f : frames) got |= a.Add(f, &s) && (out = s, true);
  EXPECT_TRUE(got);
  return out;
}

TEST(ImuEmulatorMotion, TiltedYawingSensorEncodesAndDecodesBack) {
  EmulatorOptions o;
  o.roll_rad = 0.1;
  o.pitch_rad = -0.2;
  o.yaw_rate_rad_s = 0.3;
  const MotionState m = SimulatedMotion(o, 2.0);
  // Specific force: gravity only, magnitude g whatever the tilt; level in z when untilted.
  EXPECT_NEAR(std::hypot(m.accel_m_s2[0], m.accel_m_s2[1], m.accel_m_s2[2]), kGravity, 1e-9);
  EXPECT_NEAR(m.accel_m_s2[0], kGravity * std::sin(0.2), 1e-9);  // nose down: +x
  EXPECT_NEAR(std::hypot(m.gyro_rad_s[0], m.gyro_rad_s[1], m.gyro_rad_s[2]), 0.3, 1e-9);
  EXPECT_NEAR(m.euler_rad[2], 0.6, 1e-9);
  const ImuSample s = Decode(EncodePeriod(o, m), kTypeQuaternion);
  for (size_t i = 0; i < 3; ++i) {
    EXPECT_NEAR(s.accel_m_s2[i], m.accel_m_s2[i], 0.005) << i;
    EXPECT_NEAR(s.gyro_rad_s[i], m.gyro_rad_s[i], 0.001) << i;
    EXPECT_NEAR(s.euler_rad[i], m.euler_rad[i], 1e-4) << i;
    EXPECT_NEAR(s.mag_raw[i], m.mag_raw[i], 0.5) << i;
  }
  for (size_t i = 0; i < 4; ++i) EXPECT_NEAR(s.orientation_wxyz[i], m.orientation_wxyz[i], 1e-4);
  // Without quaternion frames the orientation comes from the angles: the same rotation.
  o.send_quaternion = false;
  const ImuSample e = Decode(EncodePeriod(o, m), kTypeMag);
  for (size_t i = 0; i < 4; ++i) EXPECT_NEAR(e.orientation_wxyz[i], m.orientation_wxyz[i], 1e-4);
}

TEST(ImuEmulatorMotion, YawWrapsAndTheQuaternionKeepsWPositive) {
  EmulatorOptions o;
  o.yaw_rate_rad_s = 1.0;
  const MotionState m = SimulatedMotion(o, 4.0);  // 4 rad: wraps to 4 - 2 pi
  EXPECT_NEAR(m.euler_rad[2], 4.0 - 2 * M_PI, 1e-9);
  const ImuSample s = Decode(EncodePeriod(o, m), kTypeQuaternion);
  EXPECT_GE(s.orientation_wxyz[0], 0.0);
  // Same rotation up to sign: |<q, q_true>| = 1.
  double dot = 0;
  for (size_t i = 0; i < 4; ++i) dot += s.orientation_wxyz[i] * m.orientation_wxyz[i];
  EXPECT_NEAR(std::abs(dot), 1.0, 1e-6);
}

// The driver on a bare pty, bytes written by hand.
class PtyDriver : public ::testing::Test {
 protected:
  void SetUp() override {
    auto p = serial::Pty::Create();
    ASSERT_TRUE(p.ok()) << p.error().message;
    pty_ = std::move(*p);
  }
  void Write(const std::vector<uint8_t>& b) {
    ASSERT_EQ(::write(pty_->master_fd(), b.data(), b.size()), static_cast<ssize_t>(b.size()));
  }
  std::vector<StampedSample> Pump(ImuDriver* d, int steps) {
    std::vector<StampedSample> out;
    for (int i = 0; i < steps; ++i) d->Step(10, &out);
    return out;
  }
  std::unique_ptr<serial::Pty> pty_;
  SystemClock clock_;
};

TEST_F(PtyDriver, AnglesOnlyDeviceGivesOrientationFromAngles) {
  DriverOptions o;
  o.port = pty_->slave_path();
  o.data_timeout_s = 2.0;
  ImuDriver d(o, &clock_);
  EmulatorOptions e;
  e.send_mag = false;
  e.send_quaternion = false;
  e.yaw0_rad = 0.5;
  e.yaw_rate_rad_s = 0;
  const auto period = EncodePeriod(e, SimulatedMotion(e, 0));
  // Connect() waits for the first frame: send it from another writer after the open.
  std::thread writer([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    Write(period);
  });
  ASSERT_TRUE(d.Connect().ok()) << d.status_text();
  writer.join();
  for (int k = 0; k < 5; ++k) Write(period);
  const auto samples = Pump(&d, 5);
  EXPECT_EQ(d.state(), DriverState::kStreaming);
  EXPECT_EQ(d.cycle().last_type(), kTypeAngle);
  ASSERT_GE(samples.size(), 4u);
  EXPECT_NEAR(samples.back().sample.orientation_wxyz[0], std::cos(0.25), 1e-4);
  EXPECT_NEAR(samples.back().sample.orientation_wxyz[3], std::sin(0.25), 1e-4);
  EXPECT_NEAR(samples.back().sample.accel_m_s2[2], kGravity, 0.005);
  EXPECT_EQ(d.counters().dropped_frames, 0);
  EXPECT_EQ(d.counters().incomplete_samples, 0);
  for (size_t i = 1; i < samples.size(); ++i) EXPECT_GT(samples[i].utime, samples[i - 1].utime);
}

TEST_F(PtyDriver, SilentPortAtStartIsAnErrorNamingPortAndBaud) {
  DriverOptions o;
  o.port = pty_->slave_path();
  o.baud = 0;  // tries 9600 and 115200
  o.data_timeout_s = 0.1;
  ImuDriver d(o, &clock_);
  const Status st = d.Connect();
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find(pty_->slave_path()), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("9600"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("115200"), std::string::npos) << st.message();
  EXPECT_EQ(d.counters().connect_failures, 2);
}

TEST(ImuDriverStart, MissingPortIsAnErrorNamingIt) {
  DriverOptions o;
  o.port = "/tmp/omni-no-such-imu-unit";
  SystemClock clock;
  ImuDriver d(o, &clock);
  const Status st = d.Connect();
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().code, ErrorCode::kNotFound);
  EXPECT_NE(st.message().find(o.port), std::string::npos) << st.message();
}

}  // namespace
}  // namespace omni::imu
