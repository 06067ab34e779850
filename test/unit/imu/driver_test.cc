// The IMU driver's own logic: frame-cycle learning and drop counting, sample stamps, the config
// file, the message, the emulator's motion, the driver on a bare pty, and the driver writing
// its settings into the emulated device.
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "../common/test_paths.h"
#include "omni/bus/bus.h"
#include "omni/heartbeat_t.hpp"
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
  EXPECT_EQ(c.Add(0x53), 0);  // not a drop; joins once seen in the next period too
  EXPECT_EQ(c.last_type(), 0x52);
  EXPECT_EQ(c.Add(0x51), 0);
  EXPECT_EQ(c.Add(0x52), 0);
  EXPECT_EQ(c.Add(0x53), 0);  // joins the cycle
  EXPECT_EQ(c.last_type(), 0x53);
  EXPECT_EQ(c.Add(0x51), 0);
  EXPECT_EQ(c.Add(0x53), 1);
  c.Reset();
  EXPECT_FALSE(c.learned());
  EXPECT_TRUE(c.types().empty());
}

// One frame of a type the device does not send (noise that passed the parser) must not join a
// learned cycle: with trigger auto, 0x5A above the last type would close every sample from then
// on, and none would ever close.
TEST(FrameCycle, AStrayTypeNeedsTwoConsecutivePeriodsToJoin) {
  FrameCycle c;
  for (uint8_t t : {0x51, 0x52, 0x53, 0x51, 0x52, 0x53}) EXPECT_EQ(c.Add(t), 0);
  ASSERT_TRUE(c.learned());
  EXPECT_EQ(c.Add(0x5A), 0);
  EXPECT_EQ(c.last_type(), 0x53);
  for (int k = 0; k < 3; ++k) {
    for (uint8_t t : {0x51, 0x52, 0x53}) EXPECT_EQ(c.Add(t), 0);
  }
  EXPECT_EQ(c.Add(0x5A), 0);  // again, but not in the next period: still a stray
  for (uint8_t t : {0x51, 0x52, 0x53}) EXPECT_EQ(c.Add(t), 0);
  EXPECT_EQ(c.Add(0x54), 0);  // twice in one period is not a type of the cycle either
  EXPECT_EQ(c.Add(0x54), 0);
  for (uint8_t t : {0x51, 0x52, 0x53}) EXPECT_EQ(c.Add(t), 0);
  EXPECT_EQ(c.types(), (std::vector<uint8_t>{0x51, 0x52, 0x53}));
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
  EXPECT_EQ(s.steps_back(), 0);
}

// The wall clock set back by 2 s (an NTP step): the stamps follow it, counted, instead of every
// sample of the next 2 s being stamped 1 us after the previous one (GyroRateHistory and the
// other consumers detect the step from the older stamps and re-base).
TEST(SampleStamper, FollowsTheClockSetBackByMoreThanASecond) {
  SampleStamper s(100.0);
  const Utime t0 = 1'700'000'000'000'000;
  for (int k = 0; k < 10; ++k) EXPECT_EQ(s.Stamp(t0 + k * 10'000, 0, 1), t0 + k * 10'000);
  const Utime back = t0 + 90'000 - 2'000'000;
  EXPECT_EQ(s.Stamp(back + 10'000, 0, 1), back + 10'000);
  EXPECT_EQ(s.steps_back(), 1);
  for (int k = 2; k < 10; ++k) EXPECT_EQ(s.Stamp(back + k * 10'000, 0, 1), back + k * 10'000);
  // A small step back (within a second) keeps the stamps increasing, as before.
  EXPECT_EQ(s.Stamp(back + 85'000, 0, 1), back + 90'001);
  EXPECT_EQ(s.steps_back(), 1);
}

// A real-looking stream: the emulator's default cycle (0x51 0x52 0x53 0x54 0x59) of a sensor
// tilted 5 deg in roll, turning at 0.1 rad/s in yaw, with up to kNoiseLsb of noise on every
// value and the temperature as a real WT901 has (so periods differ and damaged windows meet
// many checksum values).
constexpr int kNoiseLsb = 4;
constexpr std::array<int16_t, 3> kAccelLsb = {0, 179, 2040};  // g (sin 5 deg, cos 5 deg)
constexpr std::array<int16_t, 3> kGyroLsb = {0, 8, 93};       // 0.1 rad/s about the tilted z

std::vector<uint8_t> NoisyPeriod(int k) {
  std::mt19937 rng(static_cast<uint32_t>(k));
  std::uniform_int_distribution<int> noise(-kNoiseLsb, kNoiseLsb);
  auto n = [&](int v) { return static_cast<int16_t>(v + noise(rng)); };
  const double yaw = std::remainder(0.1 * k / 100.0, 2 * M_PI);
  const auto q = EulerToQuaternion(5 * M_PI / 180, 0, yaw);
  std::vector<uint8_t> out;
  for (const auto& f :
       {EncodeFrame(kTypeAccel, {n(kAccelLsb[0]), n(kAccelLsb[1]), n(kAccelLsb[2]), n(2500)}),
        EncodeFrame(kTypeGyro, {n(kGyroLsb[0]), n(kGyroLsb[1]), n(kGyroLsb[2]), n(2500)}),
        EncodeFrame(kTypeAngle, {n(910), n(0), RadToAngle(yaw), n(2500)}),
        EncodeFrame(kTypeMag, {n(static_cast<int>(300 * std::sin(yaw))),
                               n(static_cast<int>(300 * std::cos(yaw))), n(-400), n(2500)}),
        EncodeFrame(kTypeQuaternion,
                    {static_cast<int16_t>(q[0] * 32767), static_cast<int16_t>(q[1] * 32767),
                     static_cast<int16_t>(q[2] * 32767), static_cast<int16_t>(q[3] * 32767)})}) {
    out.insert(out.end(), f.begin(), f.end());
  }
  return out;
}

// Whether `s` is the sensor's motion up to its noise (each value within kNoiseLsb of the truth).
bool WithinNoise(const ImuSample& s) {
  for (size_t i = 0; i < 3; ++i) {
    if (std::abs(s.accel_m_s2[i] - AccelToMs2(kAccelLsb[i])) > AccelToMs2(kNoiseLsb) + 1e-9 ||
        std::abs(s.gyro_rad_s[i] - GyroToRadS(kGyroLsb[i])) > GyroToRadS(kNoiseLsb) + 1e-9) {
      return false;
    }
  }
  return true;
}

// Bytes into samples the way the driver does it (parser, cycle, closing frame, assembler).
struct Pipeline {
  FrameParser parser;
  SampleBuilder builder;
  std::vector<ImuSample> samples;
  void Feed(const std::vector<uint8_t>& bytes) {
    std::vector<Frame> frames;
    parser.Feed(bytes.data(), bytes.size(), &frames);
    for (const Frame& f : frames) {
      ImuSample s;
      if (builder.Learn(f) && builder.Assemble(f, &s)) samples.push_back(s);
    }
  }
};

// Deletes each byte in turn of 1000 periods (one read per period, as the device sends them in
// bursts), each time in a fresh pipeline fed four clean periods before and two after: no sample
// published may be anything but the motion and its noise. Before the confirmation of frames by
// the bytes after them this published 44 phantom samples (1 in 1250 lost bytes), the largest an
// angular rate of 1000 deg/s.
TEST(ImuLostByte, NoPhantomSampleWhateverByteIsLost) {
  int64_t trials = 0, phantoms = 0, samples = 0;
  double worst_dps = 0;
  for (int k = 4; k < 1004; ++k) {
    const std::vector<uint8_t> period = NoisyPeriod(k);
    for (size_t off = 0; off < period.size(); ++off) {
      Pipeline p;
      for (int j = k - 4; j < k + 3; ++j) {
        std::vector<uint8_t> bytes = j == k ? period : NoisyPeriod(j);
        if (j == k) bytes.erase(bytes.begin() + static_cast<std::ptrdiff_t>(off));
        p.Feed(bytes);
      }
      ++trials;
      samples += static_cast<int64_t>(p.samples.size());
      for (const ImuSample& s : p.samples) {
        if (WithinNoise(s)) continue;
        ++phantoms;
        for (double w : s.gyro_rad_s) worst_dps = std::max(worst_dps, std::abs(w) * 180 / M_PI);
      }
    }
  }
  std::printf(
      "lost-byte sweep: %lld lost bytes, %lld samples, %lld phantom (worst |rate| %.1f "
      "deg/s)\n",
      static_cast<long long>(trials), static_cast<long long>(samples),
      static_cast<long long>(phantoms), worst_dps);
  EXPECT_EQ(phantoms, 0) << "worst |rate| " << worst_dps << " deg/s";
  // Learning takes the first period; the last closing frame waits for bytes that never come;
  // the damaged period costs its sample at most, and the one before it when the lost byte is
  // the header that confirms it: 4 of the 6 periods after learning, at least, every time.
  EXPECT_GE(samples, 4 * trials);
}

// phantom_type.py: a 14-byte noise burst holding a well-formed 0x5A frame, between two periods of
// a healthy 100 Hz stream. The burst as recorded is refused by the parser (the 0x5A frame is
// followed by 0xEE, not a frame); without its last byte, the next period's header confirms it and
// the stray frame reaches the frame cycle, which must not make it the closing frame.
TEST(ImuStrayFrame, ANoiseBurstWithAFrameOfAnotherTypeDoesNotStopTheSamples) {
  const auto stray = EncodeFrame(0x5A, {0x1234, -77, 5, 9});
  std::vector<uint8_t> burst = {0x13, 0xA7};
  burst.insert(burst.end(), stray.begin(), stray.end());
  for (const bool trimmed : {false, true}) {
    Pipeline p;
    for (int j = 0; j < 100; ++j) p.Feed(NoisyPeriod(j));
    const size_t before = p.samples.size();
    std::vector<uint8_t> noise = burst;
    if (!trimmed) noise.push_back(0xEE);
    p.Feed(noise);
    for (int j = 100; j < 1100; ++j) p.Feed(NoisyPeriod(j));  // 10 s more
    EXPECT_GE(p.samples.size() - before, 999u) << (trimmed ? "trimmed" : "as recorded");
    EXPECT_EQ(p.builder.cycle().types(),
              (std::vector<uint8_t>{kTypeAccel, kTypeGyro, kTypeAngle, kTypeMag, kTypeQuaternion}));
    EXPECT_EQ(p.parser.counters().unconfirmed, trimmed ? 0 : 1);
    EXPECT_EQ(p.builder.dropped_frames(), 0);
  }
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
  p.Feed(bytes.data(), 2, &frames);  // the next frame's header confirms the last one
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

// A stray frame type learned into the cycle while it was being learned (here 0x5A, confirmed
// by the next period's header) becomes the closing frame with trigger auto, and no sample
// closes although frames keep coming: after data_timeout_s the driver learns the cycle again,
// counts it and the heartbeat says DEGRADED with the reason, then OK once samples flow.
TEST_F(PtyDriver, NoSampleClosingWhileFramesComeRelearnsTheCycleAndDegrades) {
  DriverOptions o;
  o.port = pty_->slave_path();
  o.rate_hz = 100;
  o.data_timeout_s = 0.3;
  ImuDriver d(o, &clock_);
  auto bus = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus.ok());
  std::vector<omni::heartbeat_t> beats;
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { beats.push_back(m); });
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    for (int k = 0; !stop; ++k) {
      std::vector<uint8_t> b = NoisyPeriod(k);
      if (k == 0) {
        const auto stray = EncodeFrame(0x5A, {0x1234, -77, 5, 9});
        b.insert(b.end(), {0x13, 0xA7});
        b.insert(b.end(), stray.begin(), stray.end());
      }
      Write(b);
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  });
  ASSERT_TRUE(d.Connect().ok()) << d.status_text();
  ImuNode node(bus->get(), &d, NodeOptions{}, &clock_);
  bool degraded_seen = false;
  std::string reason;
  const int64_t end = MonotonicMicros() + 2'500'000;
  while (MonotonicMicros() < end) {
    node.RunOnce(10);
    while ((*bus)->HandleTimeout(0) > 0) {
    }
    for (const auto& hb : beats) {
      if (hb.state == omni::heartbeat_t::STATE_DEGRADED) {
        degraded_seen = true;
        reason = hb.status_text;
      }
    }
  }
  stop = true;
  writer.join();
  EXPECT_EQ(d.counters().cycle_relearns, 1);
  EXPECT_TRUE(degraded_seen);
  EXPECT_NE(reason.find("no complete sample"), std::string::npos) << reason;
  EXPECT_NE(reason.find("0x5a"), std::string::npos) << reason;
  EXPECT_EQ(d.cycle().last_type(), kTypeQuaternion);
  EXPECT_FALSE(d.degraded());
  EXPECT_GT(node.published(), 100);  // about 2 s of the 2.4 s after the re-learn, at 100 Hz
  EXPECT_EQ(d.state(), DriverState::kStreaming);
  ASSERT_FALSE(beats.empty());
  EXPECT_EQ(beats.back().state, omni::heartbeat_t::STATE_OK) << beats.back().status_text;
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

TEST(WitMotionWrites, EncodeTheDocumentedBytes) {
  using B = std::array<uint8_t, kWriteSize>;
  // WitMotion's register map: KEY 0x69 = 0xB588 (unlock), RSW 0x02, RRATE 0x03, BAUD 0x04,
  // SAVE 0x00 = 0; value low byte first.
  EXPECT_EQ(EncodeWrite(kRegKey, kUnlockKey), (B{0xFF, 0xAA, 0x69, 0x88, 0xB5}));
  EXPECT_EQ(EncodeWrite(kRegRate, RateCode(100)), (B{0xFF, 0xAA, 0x03, 0x09, 0x00}));
  EXPECT_EQ(EncodeWrite(kRegRate, RateCode(200)), (B{0xFF, 0xAA, 0x03, 0x0B, 0x00}));
  EXPECT_EQ(EncodeWrite(kRegRate, RateCode(10)), (B{0xFF, 0xAA, 0x03, 0x06, 0x00}));
  EXPECT_EQ(EncodeWrite(kRegBaud, BaudCode(115200)), (B{0xFF, 0xAA, 0x04, 0x06, 0x00}));
  EXPECT_EQ(EncodeWrite(kRegBaud, BaudCode(9600)), (B{0xFF, 0xAA, 0x04, 0x02, 0x00}));
  EXPECT_EQ(EncodeWrite(kRegSave, 0), (B{0xFF, 0xAA, 0x00, 0x00, 0x00}));
  const uint16_t imu = static_cast<uint16_t>(OutputBit(kTypeAccel) | OutputBit(kTypeGyro) |
                                             OutputBit(kTypeAngle) | OutputBit(kTypeQuaternion));
  EXPECT_EQ(EncodeWrite(kRegOutputs, imu), (B{0xFF, 0xAA, 0x02, 0x0E, 0x02}));
  EXPECT_EQ(RateCode(125), 0);  // the WT931's rate, not the WT901's
  EXPECT_EQ(RateCode(30), 0);
  EXPECT_EQ(BaudCode(2400), 0);
  for (double hz : {0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0})
    EXPECT_DOUBLE_EQ(RateOfCode(RateCode(hz)), hz);
  for (int b : {4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600})
    EXPECT_EQ(BaudOfCode(BaudCode(b)), b);
  EXPECT_EQ(OutputBit(0x42), 0);
}

TEST(WitMotionWrites, DeviceSideParserSkipsNoiseAndWaitsForWholeWrites) {
  WriteParser p;
  std::vector<RegisterWrite> w;
  const std::vector<uint8_t> bytes = {0x12, 0xFF, 0x00, 0xFF, 0xAA, 0x03, 0x09,
                                      0x00, 0xAA, 0xFF, 0xAA, 0x69, 0x88};
  p.Feed(bytes.data(), bytes.size(), &w);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0].reg, kRegRate);
  EXPECT_EQ(w[0].value, 0x0009);
  EXPECT_EQ(p.bytes_skipped(), 4);  // 0x12, 0xFF 0x00, 0xAA
  const uint8_t rest = 0xB5;
  p.Feed(&rest, 1, &w);
  ASSERT_EQ(w.size(), 2u);
  EXPECT_EQ(w[1].reg, kRegKey);
  EXPECT_EQ(w[1].value, kUnlockKey);
}

TEST(ImuConfig, ConfigureSectionIsCheckedAndRead) {
  const std::string path = ::omni::testing::TempDir() + "/imu_configure.yaml";
  std::ofstream(path) << "port: /dev/x\nrate_hz: 100\nconfigure:\n  enabled: true\n"
                         "  baud: 115200\n  outputs: [quaternion, gyro, accel, angle, gyro]\n"
                         "  save: true\n";
  DriverOptions d;
  NodeOptions n;
  const Status ok = LoadImuOptions(path, &d, &n);
  ASSERT_TRUE(ok.ok()) << ok.message();
  EXPECT_TRUE(d.configure.enabled);
  EXPECT_EQ(d.configure.baud, 115200);
  EXPECT_TRUE(d.configure.save);
  EXPECT_EQ(d.configure.outputs, (std::vector<uint8_t>{0x51, 0x52, 0x53, 0x59}));
  Status st =
      LoadText("port: /dev/x\nrate_hz: 30\ndata_timeout_s: 1\nconfigure:\n  enabled: true\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("rate_hz"), std::string::npos) << st.message();
  EXPECT_TRUE(LoadText("port: /dev/x\nrate_hz: 30\ndata_timeout_s: 1\n").ok());  // not written
  st = LoadText("port: /dev/x\nconfigure:\n  outputs: [accel, angle]\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("configure.outputs"), std::string::npos) << st.message();
  st = LoadText("port: /dev/x\nconfigure:\n  outputs: [accel, gyro, euler]\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("euler"), std::string::npos) << st.message();
  st = LoadText("port: /dev/x\nconfigure:\n  baud: 2400\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("configure.baud"), std::string::npos) << st.message();
  st = LoadText("port: /dev/x\ntrigger: mag\nconfigure:\n  outputs: [accel, gyro, angle]\n");
  ASSERT_FALSE(st.ok());  // the driver would switch off the frame that closes each sample
  EXPECT_NE(st.message().find("trigger"), std::string::npos) << st.message();
  st = LoadText(
      "port: /dev/x\nrate_hz: 100\ndata_timeout_s: 0.5\nconfigure:\n"
      "  enabled: true\n");  // 100 Hz of three frames at the factory's 9600 baud
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("more than 9600 baud carries with 3 frames per period (29 Hz)"),
            std::string::npos)
      << st.message();
  EXPECT_TRUE(LoadText("port: /dev/x\nrate_hz: 20\ndata_timeout_s: 0.5\nconfigure:\n"
                       "  enabled: true\n")
                  .ok());
  st = LoadText("port: /dev/x\nconfigure:\n  command_gap_ms: 0\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("configure.command_gap_ms"), std::string::npos) << st.message();
  st = LoadText("port: /dev/x\nconfigure:\n  enable: true\n");  // misspelled
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("configure.enable"), std::string::npos) << st.message();
}

// The emulator on its own thread, stepping every millisecond; stopped before the test reads or
// changes its state.
class EmulatedImu {
 public:
  explicit EmulatedImu(EmulatorOptions o) {
    auto e = ImuEmulator::Create(std::move(o));
    EXPECT_TRUE(e.ok()) << e.error().message;
    if (e.ok()) emu_ = std::move(*e);
  }
  ~EmulatedImu() { Stop(); }
  void Start() {
    run_ = true;
    thread_ = std::thread([this] {
      while (run_) {
        emu_->Step(MonotonicMicros());
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      }
    });
  }
  void Stop() {
    run_ = false;
    if (thread_.joinable()) {
      thread_.join();
      emu_->Step(MonotonicMicros());  // takes what the driver wrote since the last step
    }
  }
  ImuEmulator* operator->() { return emu_.get(); }

 private:
  std::unique_ptr<ImuEmulator> emu_;
  std::atomic<bool> run_{false};
  std::thread thread_;
};

// Steps the driver for `seconds` (or until `done` holds), collecting samples.
template <typename Done>
std::vector<StampedSample> PumpFor(ImuDriver* d, double seconds, Done done) {
  std::vector<StampedSample> out;
  const int64_t end = MonotonicMicros() + SecondsToUtime(seconds);
  while (MonotonicMicros() < end && !done()) d->Step(10, &out);
  return out;
}

DriverOptions ConfiguringDriver(const std::string& port) {
  DriverOptions o;
  o.port = port;
  o.baud = 9600;  // where the factory left it
  o.rate_hz = 100;
  o.data_timeout_s = 0.4;
  o.reconnect_interval_s = 0.05;
  o.configure.enabled = true;
  o.configure.baud = 115200;
  o.configure.outputs = {kTypeAccel, kTypeGyro, kTypeAngle, kTypeQuaternion};
  o.configure.command_gap_ms = 50;
  return o;
}

EmulatorOptions FactoryImu(const std::string& link) {
  EmulatorOptions e;
  e.link_path = link;
  e.rate_hz = 10;
  e.baud = 9600;  // a reader at another rate gets garbage
  return e;
}

TEST(ImuConfigure, SetsRateFramesAndBaudAndWritesThemAgainAfterAnUnplug) {
  const std::string link = ::omni::testing::TempDir() + "/imu_cfg_a";
  EmulatedImu imu(FactoryImu(link));
  imu.Start();
  SystemClock clock;
  ImuDriver d(ConfiguringDriver(link), &clock);
  // The driver tries 115200 first (nothing readable), then 9600, writes the settings there,
  // and follows the device to 115200.
  ASSERT_TRUE(d.Connect().ok()) << d.status_text();
  EXPECT_EQ(d.baud(), 115200);
  auto samples = PumpFor(&d, 1.0, [] { return false; });
  EXPECT_EQ(d.cycle().types(), (std::vector<uint8_t>{0x51, 0x52, 0x53, 0x59}));
  EXPECT_GT(samples.size(), 60u);  // 100 Hz now, not 10
  EXPECT_LT(samples.size(), 140u);
  EXPECT_EQ(d.counters().configurations, 1);
  EXPECT_EQ(d.counters().config_failures, 0);
  EXPECT_EQ(d.counters().reconnects, 0);
  imu.Stop();
  EXPECT_DOUBLE_EQ(imu->options().rate_hz, 100.0);
  EXPECT_EQ(imu->options().baud, 115200);
  EXPECT_FALSE(imu->options().send_mag);
  EXPECT_EQ(imu->saved().baud, 9600);  // not saved
  EXPECT_EQ(imu->counters().saves, 0);

  // Unplugged and back: the device is at its saved 9600 baud and 10 Hz again; the driver finds
  // it and writes the settings again without a restart.
  imu->Vanish();
  imu.Start();
  PumpFor(&d, 0.3, [&] { return d.state() == DriverState::kDisconnected; });
  EXPECT_NE(d.state(), DriverState::kStreaming);
  imu.Stop();
  ASSERT_TRUE(imu->Restore().ok());
  EXPECT_EQ(imu->options().baud, 9600);
  imu.Start();
  PumpFor(&d, 5.0, [&] { return d.counters().configurations == 2; });
  EXPECT_EQ(d.counters().configurations, 2) << d.status_text();
  EXPECT_EQ(d.counters().reconnects, 1);
  EXPECT_EQ(d.state(), DriverState::kStreaming);
  EXPECT_EQ(d.baud(), 115200);
  samples = PumpFor(&d, 0.5, [] { return false; });
  EXPECT_GT(samples.size(), 30u);
  imu.Stop();
  EXPECT_DOUBLE_EQ(imu->options().rate_hz, 100.0);
  EXPECT_GT(imu->counters().bytes_garbled, 0);  // the tries at the wrong rate
}

TEST(ImuConfigure, SavedSettingsAreWrittenAtTheNewBaudAndSurviveAnUnplug) {
  const std::string link = ::omni::testing::TempDir() + "/imu_cfg_b";
  EmulatorOptions e = FactoryImu(link);
  e.rate_hz = 50;  // frames often enough for the short timeout below
  EmulatedImu imu(e);
  imu.Start();
  SystemClock clock;
  DriverOptions o = ConfiguringDriver(link);
  o.configure.save = true;
  // The KEY + SAVE written once the stream is back take 2 x 70 ms, longer than the data
  // timeout: the writes must not count as the device falling silent.
  o.data_timeout_s = 0.12;
  o.configure.command_gap_ms = 70;
  ImuDriver d(o, &clock);
  ASSERT_TRUE(d.Connect().ok()) << d.status_text();
  PumpFor(&d, 2.0, [&] { return d.counters().configurations == 1; });
  ASSERT_EQ(d.counters().configurations, 1);
  PumpFor(&d, 0.3, [] { return false; });
  EXPECT_EQ(d.counters().timeouts, 0);
  EXPECT_EQ(d.counters().reconnects, 0);
  imu.Stop();
  EXPECT_EQ(imu->counters().saves, 1);  // after the switch, at 115200
  EXPECT_EQ(imu->saved().baud, 115200);
  EXPECT_DOUBLE_EQ(imu->saved().rate_hz, 100.0);
  imu->Vanish();
  ASSERT_TRUE(imu->Restore().ok());
  EXPECT_EQ(imu->options().baud, 115200);  // powered up with the saved settings
  imu.Start();
  PumpFor(&d, 5.0, [&] { return d.counters().configurations == 2; });
  EXPECT_EQ(d.counters().configurations, 2) << d.status_text();
  EXPECT_EQ(d.counters().config_failures, 0);
  EXPECT_EQ(d.baud(), 115200);
  imu.Stop();
  EXPECT_EQ(imu->counters().saves, 1) << "the flash is written once per run, not per connection";
}

TEST(ImuConfigure, APowerCycledDeviceIsFoundAtTheFactoryRateWhenBaudIsTheTarget) {
  // baud: 115200 and configure.baud: 115200 (the settings were never saved): the device came
  // back at 9600 and is still found, and set again.
  const std::string link = ::omni::testing::TempDir() + "/imu_cfg_d";
  EmulatedImu imu(FactoryImu(link));
  imu.Start();
  SystemClock clock;
  DriverOptions o = ConfiguringDriver(link);
  o.baud = 115200;
  ImuDriver d(o, &clock);
  ASSERT_TRUE(d.Connect().ok()) << d.status_text();
  EXPECT_EQ(d.baud(), 115200);
  PumpFor(&d, 2.0, [&] { return d.counters().configurations == 1; });
  EXPECT_EQ(d.counters().configurations, 1);
}

TEST(ImuConfigure, DeviceIgnoringWritesIsReportedAndStreamsAsItIsSet) {
  const std::string link = ::omni::testing::TempDir() + "/imu_cfg_c";
  EmulatorOptions e;
  e.link_path = link;
  e.rate_hz = 50;
  e.accept_writes = false;
  EmulatedImu imu(e);
  imu.Start();
  SystemClock clock;
  DriverOptions o = ConfiguringDriver(link);
  o.rate_hz = 10;
  o.configure.baud = 0;  // stay at 9600
  o.configure.max_attempts = 2;
  ImuDriver d(o, &clock);
  ASSERT_TRUE(d.Connect().ok()) << d.status_text();
  const auto samples = PumpFor(&d, 2.8, [] { return false; });
  EXPECT_EQ(d.counters().configurations, 0);
  EXPECT_EQ(d.counters().config_failures, 2);  // mag frames still sent, twice, then given up
  EXPECT_EQ(d.state(), DriverState::kStreaming);
  EXPECT_GT(samples.size(), 80u);
  // The stream's rate is measured: 50 samples/s against the configured 10.
  EXPECT_NEAR(d.measured_rate_hz(), 50.0, 10.0);
  EXPECT_EQ(d.counters().rate_mismatches, 1);
  imu.Stop();
  EXPECT_GT(imu->counters().writes_ignored, 0);
}

}  // namespace
}  // namespace omni::imu
