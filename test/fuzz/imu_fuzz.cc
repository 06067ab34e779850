// WitMotion WT901 serial bytes into the frame parser and the sample assembler (the driver's
// path), and the same bytes into the emulator's register-write parser. No real capture of this
// IMU is in the datasets: the seeds are frame sequences made by our encoder.
#include <cmath>

#include "fuzz.h"
#include "omni/imu/witmotion.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace omni::imu;
  omni::fuzz::Reader in(data, size);
  const uint8_t trigger = static_cast<uint8_t>(kTypeAccel + in.U8() % 9);
  const size_t chunk = 1 + in.U8() % 32;
  const std::string bytes = in.Rest();
  const auto* p = reinterpret_cast<const uint8_t*>(bytes.data());

  FrameParser parser;
  SampleAssembler assembler(trigger);
  WriteParser writes;
  std::vector<Frame> frames;
  std::vector<RegisterWrite> regs;
  size_t total = 0;
  for (size_t at = 0; at < bytes.size(); at += chunk) {
    const size_t n = std::min(chunk, bytes.size() - at);
    frames.clear();
    parser.Feed(p + at, n, &frames);
    writes.Feed(p + at, n, &regs);
    total += frames.size();
    for (const Frame& f : frames) {
      OMNI_FUZZ_CHECK(IsKnownType(f.type));
      ImuSample s;
      if (!assembler.Add(f, &s)) continue;
      for (double v : s.accel_m_s2) OMNI_FUZZ_CHECK(std::isfinite(v));
      for (double v : s.gyro_rad_s) OMNI_FUZZ_CHECK(std::isfinite(v));
      for (double v : s.euler_rad) OMNI_FUZZ_CHECK(std::isfinite(v) && std::fabs(v) <= M_PI + 1e-9);
      double norm = 0;
      for (double v : s.orientation_wxyz) {
        OMNI_FUZZ_CHECK(std::isfinite(v));
        norm += v * v;
      }
      // A quaternion frame may carry any four numbers; what the sample holds must be a rotation.
      OMNI_FUZZ_CHECK(std::fabs(norm - 1.0) < 1e-6);
      if (s.has_temperature) OMNI_FUZZ_CHECK(std::isfinite(s.temperature_c));
    }
  }
  OMNI_FUZZ_CHECK(total <= bytes.size() / kFrameSize);
  const FrameCounters& c = parser.counters();
  OMNI_FUZZ_CHECK(c.frames == static_cast<int64_t>(total));
  OMNI_FUZZ_CHECK(regs.size() <= bytes.size() / kWriteSize);
  return 0;
}

void omni::fuzz::Seeds(SeedList* seeds) {
  using namespace omni::imu;
  auto frame = [](uint8_t type, std::array<int16_t, 4> v) {
    const auto f = EncodeFrame(type, v);
    return std::string(reinterpret_cast<const char*>(f.data()), f.size());
  };
  std::string periods("\x02\x0b", 2);  // trigger on the angle frame, 12-byte reads
  for (int k = 0; k < 5; ++k) {
    const int16_t yaw = static_cast<int16_t>(k * 900);
    periods += frame(kTypeTime, {0x0a14, 0x0c1e, 0x0203, 0x0100});
    periods += frame(kTypeAccel, {Ms2ToAccel(0.1), Ms2ToAccel(-0.2), Ms2ToAccel(kGravity), 2500});
    periods += frame(kTypeGyro, {RadSToGyro(0.01), 0, RadSToGyro(0.2), 2500});
    periods += frame(kTypeMag, {120, -40, 300, 2500});
    periods += frame(kTypeQuaternion, {32767, 0, 0, 0});
    periods += frame(kTypeAngle, {RadToAngle(0.02), RadToAngle(-0.01), yaw, 2500});
  }
  seeds->Add(periods);
  // The configuration writes the driver sends (unlock, rate, outputs, baud, save).
  std::string writes("\x03\x05", 2);
  for (auto [reg, value] :
       std::initializer_list<std::pair<uint8_t, uint16_t>>{{kRegKey, kUnlockKey},
                                                           {kRegRate, 0x09},
                                                           {kRegOutputs, 0x021e},
                                                           {kRegBaud, 0x06},
                                                           {kRegSave, 0}}) {
    const auto w = EncodeWrite(reg, value);
    writes.append(reinterpret_cast<const char*>(w.data()), w.size());
  }
  seeds->Add(writes);
}
