#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "omni/imu/witmotion.h"

namespace omni::imu {
namespace {

TEST(WitMotion, KnownFrameFromTheManual) {
  // An acceleration frame at rest, z = 1 g: Az = 2048 (0x0800), T = 25.00 C (2500 = 0x09C4).
  const auto b = EncodeFrame(kTypeAccel, {0, 0, 2048, 2500});
  const std::array<uint8_t, 11> expected = {0x55, 0x51, 0x00, 0x00, 0x00, 0x00,
                                            0x00, 0x08, 0xC4, 0x09, 0x00};
  for (size_t i = 0; i < 10; ++i) EXPECT_EQ(b[i], expected[i]) << i;
  EXPECT_EQ(b[10], static_cast<uint8_t>(0x55 + 0x51 + 0x08 + 0xC4 + 0x09));
  FrameParser p;
  std::vector<Frame> out;
  p.Feed(b.data(), b.size(), &out);
  // Held back until the bytes after it show where the next frame starts.
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(p.held_type(), kTypeAccel);
  const auto next = EncodeFrame(kTypeGyro, {0, 0, 0, 2500});
  p.Feed(next.data(), 2, &out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_TRUE(out[0].held);
  EXPECT_NEAR(AccelToMs2(out[0].v[2]), kGravity, 1e-9);
  EXPECT_EQ(out[0].v[3], 2500);
}

TEST(WitMotion, SerialLineDelay) {
  EXPECT_EQ(SerialLineDelayUs(4, 9600), 45833);  // 4 x 11 bytes x 10 bits / 9600 baud
  EXPECT_EQ(SerialLineDelayUs(3, 115200), 2864);
  EXPECT_EQ(SerialLineDelayUs(4, 0), 0);  // unknown baud rate
}

TEST(WitMotion, UnitConversionsRoundTrip) {
  EXPECT_EQ(Ms2ToAccel(AccelToMs2(1234)), 1234);
  EXPECT_EQ(RadSToGyro(GyroToRadS(-321)), -321);
  EXPECT_EQ(RadToAngle(AngleToRad(16384)), 16384);
  EXPECT_NEAR(AngleToRad(16384), M_PI / 2, 1e-12);
  EXPECT_NEAR(GyroToRadS(32767), 2000 * M_PI / 180 * 32767 / 32768, 1e-9);
}

std::vector<uint8_t> Stream(int periods) {
  std::vector<uint8_t> s;
  for (int k = 0; k < periods; ++k) {
    for (const auto& f : {EncodeFrame(kTypeAccel, {static_cast<int16_t>(k), 0, 2048, 2500}),
                          EncodeFrame(kTypeGyro, {0, 0, static_cast<int16_t>(100 + k), 2500}),
                          EncodeFrame(kTypeAngle, {0, 0, 8192, 2500}),
                          EncodeFrame(kTypeMag, {100, -200, 300, 2500})}) {
      s.insert(s.end(), f.begin(), f.end());
    }
  }
  return s;
}

TEST(WitMotion, AssemblesSamplesAndOrientation) {
  const auto bytes = Stream(5);
  FrameParser p;
  std::vector<Frame> frames;
  p.Feed(bytes.data(), bytes.size(), &frames);
  ASSERT_EQ(frames.size(), 19u);  // the last one is held back for the bytes after it
  SampleAssembler a;
  std::vector<ImuSample> samples;
  for (const Frame& f : frames) {
    ImuSample s;
    if (a.Add(f, &s)) samples.push_back(s);
  }
  ASSERT_EQ(samples.size(), 5u);
  EXPECT_NEAR(samples[3].gyro_rad_s[2], GyroToRadS(103), 1e-12);
  // yaw = 8192/32768 * 180 = 45 deg about z: q = (cos 22.5, 0, 0, sin 22.5).
  EXPECT_NEAR(samples[0].orientation_wxyz[0], std::cos(M_PI / 8), 1e-9);
  EXPECT_NEAR(samples[0].orientation_wxyz[3], std::sin(M_PI / 8), 1e-9);
  EXPECT_NEAR(samples[0].temperature_c, 25.0, 1e-9);
}

// A period whose angle frame was lost (a bad checksum drops it in the parser) closes a sample
// without an orientation: not the one of the period before, which is stale by a period.
TEST(WitMotion, ASampleWhoseAngleFrameWasLostHasNoOrientation) {
  SampleAssembler a(kTypeMag);
  auto frame = [](uint8_t type, std::array<int16_t, 4> v) {
    Frame f;
    f.type = type;
    f.v = v;
    return f;
  };
  ImuSample s;
  EXPECT_FALSE(a.Add(frame(kTypeAccel, {0, 0, 2048, 2500}), &s));
  EXPECT_FALSE(a.Add(frame(kTypeGyro, {0, 0, 100, 2500}), &s));
  EXPECT_FALSE(a.Add(frame(kTypeAngle, {0, 0, 8192, 2500}), &s));
  ASSERT_TRUE(a.Add(frame(kTypeMag, {1, 2, 3, 2500}), &s));
  EXPECT_TRUE(s.has_orientation);
  EXPECT_TRUE(s.has_mag);
  EXPECT_FALSE(a.Add(frame(kTypeAccel, {0, 0, 2048, 2500}), &s));
  EXPECT_FALSE(a.Add(frame(kTypeGyro, {0, 0, 100, 2500}), &s));
  ASSERT_TRUE(a.Add(frame(kTypeMag, {1, 2, 3, 2500}), &s));  // the angle frame lost
  EXPECT_FALSE(s.has_orientation);
  EXPECT_TRUE(s.has_mag);
  EXPECT_TRUE(s.has_temperature);  // from this period's accel frame
}

TEST(WitMotion, GarbageCostsOnlyCorruptedFrames) {
  const auto clean = Stream(200);
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255);
  std::vector<uint8_t> dirty;
  int damaged = 0;
  for (size_t i = 0; i < clean.size(); i += kFrameSize) {
    if (i % (kFrameSize * 37) == kFrameSize * 5) {
      for (int k = 0; k < 23; ++k) dirty.push_back(static_cast<uint8_t>(byte(rng)));
    }
    dirty.insert(dirty.end(), clean.begin() + static_cast<long>(i),
                 clean.begin() + static_cast<long>(i + kFrameSize));
    if (i % (kFrameSize * 53) == kFrameSize * 9) {
      dirty.back() ^= 0x01;  // flip one bit of a checksum
      ++damaged;
    }
  }
  FrameParser p;
  std::vector<Frame> frames;
  for (size_t i = 0; i < dirty.size(); i += 13) {
    p.Feed(dirty.data() + i, std::min<size_t>(13, dirty.size() - i), &frames);
  }
  // The last frame is held back for the bytes after it, which never come. The frames followed
  // by garbage are kept: no frame starts inside them.
  EXPECT_EQ(frames.size(), 800u - static_cast<size_t>(damaged) - 1);
  EXPECT_EQ(p.counters().checksum_errors, damaged);
  EXPECT_GT(p.counters().resyncs, 0);
  EXPECT_EQ(p.counters().unconfirmed, 0);
}

// A byte lost in transit: the frame's other 10 bytes and the next frame's 0x55 can pass the
// additive checksum (the repro's period 31: angular rate frame, byte 6 lost, read as a gyro z of
// -937.5 deg/s). The bytes after that window are the next frame's type and payload, not a header,
// and a whole frame starts inside it: dropped and counted, never decoded.
TEST(WitMotion, AWindowThatPassesTheChecksumAfterALostByteIsNotAFrame) {
  const std::vector<uint8_t> period31 = {
      0x55, 0x51, 0x01, 0x00, 0xb2, 0x00, 0xf4, 0x07, 0xc6, 0x09, 0x23, 0x55, 0x52, 0x01,
      0x00, 0x07, 0x00, 0x5d, 0x00, 0xc4, 0x09, 0xd9, 0x55, 0x53, 0x91, 0x03, 0x02, 0x00,
      0x87, 0x02, 0xc4, 0x09, 0x94, 0x55, 0x54, 0x17, 0x00, 0x2a, 0x01, 0x6e, 0xfe, 0xc4,
      0x09, 0x24, 0x55, 0x59, 0xf0, 0x7f, 0x00, 0x00, 0x00, 0x00, 0xf8, 0x03, 0x18};
  std::vector<uint8_t> received = period31;
  received.erase(received.begin() + 11 + 6);                          // 0x5d
  received.insert(received.end(), period31.begin(), period31.end());  // the next period
  FrameParser p;
  std::vector<Frame> frames;
  p.Feed(received.data(), received.size(), &frames);
  for (const Frame& f : frames) {
    if (f.type == kTypeGyro) {
      EXPECT_LT(std::abs(f.v[2]), 1000) << "phantom rate " << f.v[2];
    }
  }
  EXPECT_EQ(p.counters().unconfirmed, 1);
  // Accel, angles, mag, quaternion of the damaged period, and the next period but for its last
  // frame (held back).
  EXPECT_EQ(frames.size(), 4u + 4u);
}

}  // namespace
}  // namespace omni::imu
