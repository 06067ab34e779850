// RPLidar measurement bytes, as a serial port delivers them (any chunking), into the parser and
// the revolution assembler. Seeds: the real A3 captures of ../shared/datasets/rplidar, and
// express capsules made by our encoder.
#include <cmath>

#include "fuzz.h"
#include "omni/rplidar/parser.h"
#include "omni/rplidar/protocol.h"

namespace {

void CheckSample(const omni::rplidar::Sample& s) {
  OMNI_FUZZ_CHECK(std::isfinite(s.angle_deg) && s.angle_deg >= 0 && s.angle_deg < 360);
  OMNI_FUZZ_CHECK(std::isfinite(s.distance_mm) && s.distance_mm >= 0);
  OMNI_FUZZ_CHECK(s.quality <= 63);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace omni::rplidar;
  omni::fuzz::Reader in(data, size);
  const uint8_t flags = in.U8();
  const StreamMode mode = (flags & 1) ? StreamMode::kExpressLegacy : StreamMode::kStandard;
  const int lookahead = 1 + (flags >> 1) % 8;
  const size_t chunk_unit = 1 + in.U8();  // the serial read size varies
  const std::string bytes = in.Rest();

  MeasurementParser parser(mode, lookahead);
  RevolutionAssembler assembler;
  std::vector<Sample> samples, revolution;
  size_t at = 0;
  int64_t utime = 0;
  size_t total = 0;
  while (at < bytes.size()) {
    const size_t n = std::min(chunk_unit + at % 3, bytes.size() - at);
    samples.clear();
    parser.Feed(reinterpret_cast<const uint8_t*>(bytes.data()) + at, n, utime += 1000, &samples);
    for (const Sample& s : samples) {
      CheckSample(s);
      if (assembler.Add(s, &revolution)) {
        OMNI_FUZZ_CHECK(!revolution.empty());
        for (const Sample& r : revolution) CheckSample(r);
      }
    }
    total += samples.size();
    at += n;
  }
  samples.clear();
  parser.Finish(utime, &samples);
  for (const Sample& s : samples) CheckSample(s);
  total += samples.size();
  const ParserCounters& c = parser.counters();
  OMNI_FUZZ_CHECK(c.samples == static_cast<int64_t>(total));
  OMNI_FUZZ_CHECK(c.bytes_skipped >= 0 && c.bytes_skipped <= static_cast<int64_t>(bytes.size()));
  // A standard node is 5 bytes: no more samples than the bytes could carry. An express capsule
  // (84 bytes) gives 32.
  if (mode == StreamMode::kStandard) {
    OMNI_FUZZ_CHECK(total <= bytes.size() / kSampleSize);
  } else {
    OMNI_FUZZ_CHECK(total <= 32 * (bytes.size() / kCapsuleSize));
  }
  return 0;
}

void omni::fuzz::Seeds(SeedList* seeds) {
  using namespace omni::rplidar;
  for (const char* file : {"rplidar/derived/rplidar_data_1.bin", "rplidar/derived/valid_data_1.bin",
                           "rplidar/derived/longvalues_at_60.bin"}) {
    SeedList one;
    if (!one.AddDataset(file, 4000)) {
      seeds->missing.insert(seeds->missing.end(), one.missing.begin(), one.missing.end());
      continue;
    }
    seeds->Add(std::string("\x00\x10", 2) + one.inputs[0]);  // standard mode, 17-byte reads
  }
  // Express mode: a few capsules of a turning lidar.
  std::string express("\x01\x54", 2);
  for (int k = 0; k < 6; ++k) {
    Capsule c;
    c.start_angle_q6 = static_cast<uint16_t>(((k * 40) % 360) * 64);
    c.start = (k == 0);
    for (int i = 0; i < 16; ++i) {
      c.cabins[i].distance_angle_1 = static_cast<uint16_t>((1000 + 10 * i) << 2);
      c.cabins[i].distance_angle_2 = static_cast<uint16_t>((2000 + 10 * i) << 2);
      c.cabins[i].offset_angles_q3 = static_cast<uint8_t>(i);
    }
    const auto bytes = EncodeCapsule(c);
    express.append(reinterpret_cast<const char*>(bytes.data()), bytes.size());
  }
  seeds->Add(express);
}
