#include <random>

#include <gtest/gtest.h>

#include "omni/rplidar/parser.h"
#include "omni/rplidar/protocol.h"
#include "omni/rplidar/scan.h"

namespace omni::rplidar {
namespace {

TEST(RplidarProtocol, RequestWithPayloadCarriesXorChecksum) {
  // SET_MOTOR_PWM 660 as rplidar_sdk sends it: A5 F0 02 94 02 checksum.
  const auto r = MakeMotorPwmRequest(660);
  ASSERT_EQ(r.size(), 6u);
  EXPECT_EQ(r[0], 0xA5);
  EXPECT_EQ(r[1], 0xF0);
  EXPECT_EQ(r[2], 0x02);
  EXPECT_EQ(r[3], 0x94);
  EXPECT_EQ(r[4], 0x02);
  EXPECT_EQ(r[5], 0xA5 ^ 0xF0 ^ 0x02 ^ 0x94 ^ 0x02);
  EXPECT_EQ(MakeRequest(kCmdGetHealth), (std::vector<uint8_t>{0xA5, 0x52}));
}

TEST(RplidarProtocol, DescriptorRoundTrip) {
  // The SCAN answer of every RPLidar: A5 5A 05 00 00 40 81.
  const auto b = EncodeDescriptor({5, kModeMulti, kAnsMeasurement});
  EXPECT_EQ(b, (std::array<uint8_t, 7>{0xA5, 0x5A, 0x05, 0x00, 0x00, 0x40, 0x81}));
  Descriptor d;
  ASSERT_TRUE(DecodeDescriptor(b.data(), &d));
  EXPECT_EQ(d.size, 5u);
  EXPECT_EQ(d.mode, kModeMulti);
  EXPECT_EQ(d.type, kAnsMeasurement);
  const uint8_t bad[7] = {0xA5, 0x00, 0, 0, 0, 0, 0};
  EXPECT_FALSE(DecodeDescriptor(bad, &d));
}

TEST(RplidarProtocol, StandardSampleRoundTripAndChecks) {
  const auto b = EncodeStandardSample(351.296875, 2240.0, 15, true);
  EXPECT_TRUE(StandardSampleChecksPass(b.data()));
  const Sample s = DecodeStandardSample(b.data());
  EXPECT_DOUBLE_EQ(s.angle_deg, 351.296875);
  EXPECT_DOUBLE_EQ(s.distance_mm, 2240.0);
  EXPECT_EQ(s.quality, 15);
  EXPECT_TRUE(s.start);
  auto broken = b;
  broken[1] &= 0xFE;  // C bit cleared
  EXPECT_FALSE(StandardSampleChecksPass(broken.data()));
  broken = b;
  broken[0] |= 0x3;  // S == !S
  EXPECT_FALSE(StandardSampleChecksPass(broken.data()));
}

TEST(RplidarProtocol, InfoHealthRateRoundTrip) {
  DeviceInfo info;
  info.model = 0x31;
  info.firmware_version = 0x011A;
  info.hardware_version = 6;
  info.serial_number[0] = 0xAB;
  const auto ib = EncodeDeviceInfo(info);
  ASSERT_EQ(ib.size(), kDevInfoSize);
  const DeviceInfo back = DecodeDeviceInfo(ib.data());
  EXPECT_EQ(back.MajorModel(), 3);
  EXPECT_EQ(back.firmware_version, 0x011A);
  EXPECT_EQ(back.SerialHex().substr(0, 2), "AB");
  const auto hb = EncodeHealth({kHealthError, 0x1234});
  EXPECT_EQ(DecodeHealth(hb.data()).status, kHealthError);
  EXPECT_EQ(DecodeHealth(hb.data()).error_code, 0x1234);
  const auto rb = EncodeSampleRate({250, 125});
  EXPECT_EQ(DecodeSampleRate(rb.data()).standard_us, 250);
  EXPECT_EQ(DecodeSampleRate(rb.data()).express_us, 125);
}

// Capsules built like a real A2 stream: 32 samples per capsule, angles evenly spaced.
std::vector<uint8_t> MakeExpressStream(int capsules, double deg_per_capsule,
                                       std::vector<double>* expected_dist) {
  std::vector<uint8_t> bytes;
  for (int c = 0; c < capsules; ++c) {
    Capsule cap;
    const double start = std::fmod(c * deg_per_capsule, 360.0);
    cap.start_angle_q6 = static_cast<uint16_t>(std::lround(start * 64.0)) & 0x7FFF;
    cap.start = (c == 0);
    for (int i = 0; i < 16; ++i) {
      const int d1 = 1000 + c * 32 + 2 * i;
      const int d2 = d1 + 1;
      cap.cabins[static_cast<size_t>(i)].distance_angle_1 = static_cast<uint16_t>(d1 * 4);
      cap.cabins[static_cast<size_t>(i)].distance_angle_2 = static_cast<uint16_t>(d2 * 4);
      if (c + 1 < capsules) {  // the last capsule's samples are never emitted
        expected_dist->push_back(d1);
        expected_dist->push_back(d2);
      }
    }
    const auto b = EncodeCapsule(cap);
    bytes.insert(bytes.end(), b.begin(), b.end());
  }
  return bytes;
}

TEST(RplidarExpress, DecodesAcrossConsecutiveCapsules) {
  std::vector<double> expected;
  const auto bytes = MakeExpressStream(30, 32 * 0.5, &expected);  // 0.5 deg per sample
  MeasurementParser parser(StreamMode::kExpressLegacy);
  std::vector<Sample> out;
  parser.Feed(bytes.data(), bytes.size(), 7, &out);
  ASSERT_EQ(out.size(), expected.size());
  int starts = 0;
  for (size_t i = 0; i < out.size(); ++i) {
    EXPECT_DOUBLE_EQ(out[i].distance_mm, expected[i]) << i;
    EXPECT_NEAR(out[i].angle_deg, std::fmod(i * 0.5, 360.0), 1.0 / 64) << i;
    starts += out[i].start ? 1 : 0;
  }
  EXPECT_EQ(starts, 1);  // 29 capsules * 16 deg = 464 deg: one wrap through 0
  EXPECT_EQ(parser.counters().checksum_errors, 0);
  EXPECT_EQ(parser.counters().capsules, 30);
}

// A capsule that passes the sync and XOR checks by chance (once in 4096 windows) with a start
// angle of 360 degrees or more, or one far from its neighbours', does not spread 32 ranges over
// a wrong arc: it and its predecessor lose their samples, and the rest decode.
TEST(RplidarExpress, ACapsuleWithAnImpossibleStartAngleIsDropped) {
  for (const double bad_start : {400.0, std::fmod(5 * 16.0 + 180.0, 360.0)}) {
    std::vector<double> expected;
    auto bytes = MakeExpressStream(10, 16.0, &expected);
    Capsule c = DecodeCapsule(&bytes[5 * kCapsuleSize]);
    c.start_angle_q6 = static_cast<uint16_t>(std::lround(bad_start * 64.0)) & 0x7FFF;
    const auto b = EncodeCapsule(c);  // with a checksum that matches
    std::copy(b.begin(), b.end(), bytes.begin() + 5 * static_cast<long>(kCapsuleSize));
    MeasurementParser parser(StreamMode::kExpressLegacy);
    std::vector<Sample> out;
    parser.Feed(bytes.data(), bytes.size(), 0, &out);
    EXPECT_EQ(parser.counters().checksum_errors, 0);
    if (bad_start >= 360) {
      EXPECT_EQ(parser.counters().bad_angles, 1);
    } else {
      EXPECT_EQ(parser.counters().angle_jumps, 2);  // into capsule 5 and out of it
    }
    // Capsules 0-3 and 6-8 decode (9 has no successor); 4 and 5 lose their samples.
    ASSERT_EQ(out.size(), 7u * 32u) << bad_start;
    for (const Sample& s : out) {
      // On its own capsule's arc: capsule k spans 16 k .. 16 (k + 1) degrees.
      const long k = (std::lround(s.distance_mm) - 1000) / 32;
      EXPECT_NE(k, 4);
      EXPECT_NE(k, 5);
      EXPECT_GE(s.angle_deg, 16.0 * k - 1e-9) << k;
      EXPECT_LT(s.angle_deg, 16.0 * (k + 1)) << k;
    }
  }
}

TEST(RplidarExpress, CorruptedCapsuleIsCountedAndSkipped) {
  std::vector<double> expected;
  auto bytes = MakeExpressStream(10, 16.0, &expected);
  bytes[5 * kCapsuleSize + 40] ^= 0x5A;  // damage capsule 5
  MeasurementParser parser(StreamMode::kExpressLegacy);
  std::vector<Sample> out;
  // Byte-by-byte feeding must give the same answer as one block.
  for (uint8_t b : bytes) parser.Feed(&b, 1, 0, &out);
  EXPECT_EQ(parser.counters().checksum_errors, 1);
  EXPECT_EQ(parser.counters().capsules, 9);
  // Capsules 4 and 5 lose their samples (4 has no valid successor); the rest decode.
  EXPECT_EQ(out.size(), (9u - 1u - 1u) * 32u);
}

TEST(RplidarScan, ClockwiseSamplesBecomeCounterClockwiseBeams) {
  std::vector<Sample> rev;
  Sample s;
  s.angle_deg = 90;  // clockwise 90 = the sensor's right = -90 deg CCW
  s.distance_mm = 1000;
  s.quality = 40;
  s.utime = 100;
  rev.push_back(s);
  s.angle_deg = 0;
  s.distance_mm = 2000;
  s.utime = 200;
  rev.push_back(s);
  s.angle_deg = 10;
  s.distance_mm = 50;  // closer than range_min: dropped
  rev.push_back(s);
  ScanOptions opt;
  opt.beams = 360;
  const PlanarScan scan = RevolutionToScan(rev, opt);
  ASSERT_EQ(scan.ranges_m.size(), 360u);
  EXPECT_LT(scan.angle_increment_rad, 0);  // clockwise, as measured
  auto beam_of = [&](double ccw_deg) {
    const long i =
        std::lround((ccw_deg * M_PI / 180 - scan.angle_min_rad) / scan.angle_increment_rad);
    return static_cast<size_t>(((i % 360) + 360) % 360);
  };
  EXPECT_EQ(beam_of(-90), 0u);  // the first sample
  EXPECT_FLOAT_EQ(scan.ranges_m[beam_of(-90)], 1.0f);
  EXPECT_FLOAT_EQ(scan.intensities[beam_of(-90)], 40.0f);
  EXPECT_FLOAT_EQ(scan.ranges_m[beam_of(0)], 2.0f);
  EXPECT_TRUE(std::isnan(scan.ranges_m[beam_of(90)]));
  EXPECT_EQ(scan.samples_used, 2);
  EXPECT_EQ(scan.utime, 100);
  EXPECT_DOUBLE_EQ(scan.scan_time_s, 100e-6);
}

// The mappers place beam i of a scan at utime + i / (n - 1) * scan_time_s to undo the base's
// motion during the sweep, so the beams must be in the order the lidar measured them, wherever
// the revolution began and whatever the mount's angle offset. Binned counter-clockwise from
// -pi (as before 2026-12-07), a revolution starting straight ahead put its first sample in
// the middle beam and ran time backwards from there.
TEST(RplidarScan, BeamsAreInTheOrderTheLidarMeasuredThem) {
  for (double start_deg : {0.0, 0.2, 123.4, 359.9})
    for (double offset : {0.0, 0.05, -3.0}) {
      std::vector<Sample> rev;
      constexpr int kSamples = 1000;
      for (int k = 0; k < kSamples; ++k) {
        Sample s;
        s.angle_deg = std::fmod(start_deg + k * 360.0 / kSamples, 360.0);  // clockwise
        s.distance_mm = 1000 + k;  // tells the samples apart
        s.quality = 30;
        s.utime = 1000000 + k * 100;
        s.start = k == 0;
        rev.push_back(s);
      }
      ScanOptions opt;
      opt.beams = 720;
      opt.angle_offset_rad = offset;
      const PlanarScan scan = RevolutionToScan(rev, opt);
      ASSERT_EQ(scan.ranges_m.size(), 720u);
      EXPECT_EQ(scan.utime, 1000000);
      EXPECT_NEAR(scan.scan_time_s, (kSamples - 1) * 100e-6, 1e-12);
      EXPECT_NEAR(scan.angle_increment_rad, -2 * M_PI / 720, 1e-12);
      EXPECT_GE(scan.angle_min_rad, -M_PI - 1e-9);
      EXPECT_LE(scan.angle_min_rad, M_PI + 1e-9);
      int filled = 0;
      for (size_t i = 0; i < scan.ranges_m.size(); ++i) {
        if (std::isnan(scan.ranges_m[i])) continue;
        ++filled;
        const int k = static_cast<int>(std::lround(scan.ranges_m[i] * 1000)) - 1000;
        ASSERT_GE(k, 0);
        ASSERT_LT(k, kSamples);
        // Its time in the sweep, as the mappers reckon it, within a beam of the truth.
        const double beam_time = static_cast<double>(i) / 719.0 * scan.scan_time_s;
        const double true_time = (rev[static_cast<size_t>(k)].utime - scan.utime) * 1e-6;
        EXPECT_NEAR(beam_time, true_time, 1.5 * scan.scan_time_s / 720)
            << "start " << start_deg << ", offset " << offset << ", beam " << i;
        // And its angle, within half a bin.
        const double a = scan.angle_min_rad + static_cast<double>(i) * scan.angle_increment_rad;
        const double want = -rev[static_cast<size_t>(k)].angle_deg * M_PI / 180 + offset;
        EXPECT_NEAR(std::remainder(a - want, 2 * M_PI), 0.0, M_PI / 720 + 1e-9);
      }
      EXPECT_GT(filled, 700);
    }
}

// The turn's last samples reach the first one's angle again: they go in the last beam, not
// beam 0 (where the nearer range would replace the first sample's, stamped at the scan's start).
TEST(RplidarScan, TheTurnsLastSampleGoesInTheLastBeam) {
  std::vector<Sample> rev;
  for (int k = 0; k <= 720; ++k) {
    Sample s;
    // The first 0.1 degrees past its bin's centre, the last 359.9 degrees after it.
    s.angle_deg = k == 720 ? 0.0 : std::fmod(0.1 + k * 0.5, 360.0);
    s.distance_mm = k == 720 ? 500 : 1000;
    s.utime = 1000 + k * 139;
    s.start = k == 0;
    rev.push_back(s);
  }
  ScanOptions opt;
  opt.beams = 720;
  const PlanarScan scan = RevolutionToScan(rev, opt);
  EXPECT_FLOAT_EQ(scan.ranges_m[0], 1.0f);
  EXPECT_FLOAT_EQ(scan.ranges_m[719], 0.5f);
}

TEST(RplidarAssembler, RevolutionsEndAtStartFlags) {
  RevolutionAssembler a;
  std::vector<Sample> done;
  int completed = 0;
  for (int rev = 0; rev < 4; ++rev) {
    for (int i = 0; i < 10; ++i) {
      Sample s;
      s.start = (i == 0);
      if (a.Add(s, &done)) {
        ++completed;
        EXPECT_EQ(done.size(), 10u);
      }
    }
  }
  EXPECT_EQ(completed, 3);  // the 4th is still open
  EXPECT_EQ(a.revolutions(), 3);
}

// A motor that does not turn under a forced scan: samples at one angle and no start flag, about
// 4000 a second. The open revolution stays bounded (it grew without limit) and what is dropped
// is counted; once the motor turns, revolutions come again.
TEST(RplidarAssembler, SamplesWithoutATurnStayBoundedAndAreCounted) {
  RevolutionAssembler a;
  std::vector<Sample> done;
  Sample stuck;
  stuck.angle_deg = 42.0;
  stuck.distance_mm = 1000;
  constexpr int kStuck = 40000;  // 10 s
  for (int i = 0; i < kStuck; ++i) {
    EXPECT_FALSE(a.Add(stuck, &done));
    ASSERT_LE(a.pending(), RevolutionAssembler::kMaxSamples);
  }
  EXPECT_GE(a.samples_without_turn(),
            kStuck - static_cast<int64_t>(RevolutionAssembler::kMaxSamples));
  int completed = 0;
  for (int rev = 0; rev < 3; ++rev)
    for (int i = 0; i < 360; ++i) {
      Sample s;
      s.angle_deg = i;
      s.start = i == 0;
      if (a.Add(s, &done)) {
        ++completed;
        EXPECT_EQ(done.size(), 360u);
      }
    }
  EXPECT_EQ(completed, 2);
}

}  // namespace
}  // namespace omni::rplidar
