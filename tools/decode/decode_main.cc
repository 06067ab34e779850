// ./omni decode rplidar [--express] FILE | ./omni decode imu FILE
// Decodes a raw byte capture of a device (what a logic analyser or `cat /dev/ttyUSB0 > f`
// records) and prints one sample per line, tab-separated, then a summary on lines starting with
// '#': samples, revolutions and every error counter. Exit status 1 on usage or file errors.
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "omni/imu/witmotion.h"
#include "omni/rplidar/parser.h"

namespace {

void Usage(FILE* f) {
  std::fprintf(f,
               "usage: omni decode rplidar [--express] FILE\n"
               "       omni decode imu FILE\n"
               "  Decodes a raw serial capture and prints one sample per line:\n"
               "    rplidar: angle_deg distance_mm quality start_flag  (lidar convention: "
               "clockwise)\n"
               "    imu:     frame type and values in SI units\n"
               "  then a summary ('#' lines): samples, revolutions, check-bit/checksum errors,\n"
               "  resyncs and skipped bytes. A capture may start with the A5 5A response\n"
               "  descriptor (its type chooses standard or express) or directly with samples.\n");
}

int DecodeRplidar(const std::vector<uint8_t>& bytes, bool express) {
  using namespace omni::rplidar;
  size_t start = 0;
  Descriptor d;
  if (bytes.size() >= kDescriptorSize && DecodeDescriptor(bytes.data(), &d)) {
    if (d.type == kAnsMeasurementCapsuled) express = true;
    if (d.type == kAnsMeasurement) express = false;
    start = kDescriptorSize;
    std::printf("# descriptor: size %u mode %u type 0x%02X\n", d.size, d.mode, d.type);
  }
  MeasurementParser parser(express ? StreamMode::kExpressLegacy : StreamMode::kStandard);
  RevolutionAssembler revs;
  std::vector<Sample> samples, done;
  parser.Feed(bytes.data() + start, bytes.size() - start, 0, &samples);
  parser.Finish(0, &samples);
  std::printf("# angle_deg\tdistance_mm\tquality\tstart_flag\n");
  for (const Sample& s : samples) {
    std::printf("%.6f\t%.2f\t%u\t%d\n", s.angle_deg, s.distance_mm, s.quality, s.start ? 1 : 0);
    revs.Add(s, &done);
  }
  const ParserCounters& c = parser.counters();
  std::printf(
      "# samples %lld\n# revolutions %lld (complete; samples before the first start "
      "flag: %lld)\n",
      static_cast<long long>(c.samples), static_cast<long long>(revs.revolutions()),
      static_cast<long long>(revs.partial_samples_dropped()));
  std::printf(
      "# checkbit_errors %lld\n# checksum_errors %lld\n# bad_angles %lld\n"
      "# angle_jumps %lld\n# unconfirmed %lld\n# resyncs %lld\n# bytes_skipped %lld\n"
      "# implied_starts %lld\n",
      static_cast<long long>(c.checkbit_errors), static_cast<long long>(c.checksum_errors),
      static_cast<long long>(c.bad_angles), static_cast<long long>(c.angle_jumps),
      static_cast<long long>(c.unconfirmed), static_cast<long long>(c.resyncs),
      static_cast<long long>(c.bytes_skipped), static_cast<long long>(revs.implied_starts()));
  if (express) std::printf("# capsules %lld\n", static_cast<long long>(c.capsules));
  return 0;
}

int DecodeImu(const std::vector<uint8_t>& bytes) {
  using namespace omni::imu;
  FrameParser parser;
  std::vector<Frame> frames;
  parser.Feed(bytes.data(), bytes.size(), &frames);
  SampleAssembler assembler;
  int64_t samples = 0;
  std::printf("# type\tvalues (SI units)\n");
  for (const Frame& f : frames) {
    switch (f.type) {
      case kTypeTime:
        std::printf("time\t20%02u-%02u-%02u\t%02u:%02u:%02u.%03u\n", f.raw[0], f.raw[1], f.raw[2],
                    f.raw[3], f.raw[4], f.raw[5], f.raw[6] | (f.raw[7] << 8));
        break;
      case kTypeAccel:
        std::printf("accel_m_s2\t%.4f\t%.4f\t%.4f\ttemp_c\t%.2f\n", AccelToMs2(f.v[0]),
                    AccelToMs2(f.v[1]), AccelToMs2(f.v[2]), f.v[3] / 100.0);
        break;
      case kTypeGyro:
        std::printf("gyro_rad_s\t%.5f\t%.5f\t%.5f\n", GyroToRadS(f.v[0]), GyroToRadS(f.v[1]),
                    GyroToRadS(f.v[2]));
        break;
      case kTypeAngle:
        std::printf("rpy_rad\t%.5f\t%.5f\t%.5f\n", AngleToRad(f.v[0]), AngleToRad(f.v[1]),
                    AngleToRad(f.v[2]));
        break;
      case kTypeMag:
        std::printf("mag_raw\t%d\t%d\t%d\n", f.v[0], f.v[1], f.v[2]);
        break;
      case kTypeQuaternion:
        std::printf("quat_wxyz\t%.5f\t%.5f\t%.5f\t%.5f\n", f.v[0] / 32768.0, f.v[1] / 32768.0,
                    f.v[2] / 32768.0, f.v[3] / 32768.0);
        break;
      default:
        std::printf("type_0x%02X\t%d\t%d\t%d\t%d\n", f.type, f.v[0], f.v[1], f.v[2], f.v[3]);
    }
    ImuSample s;
    if (assembler.Add(f, &s)) ++samples;
  }
  const FrameCounters& c = parser.counters();
  std::printf(
      "# frames %lld\n# samples %lld (complete accel+gyro+angle groups)\n"
      "# checksum_errors %lld\n# resyncs %lld\n# bytes_skipped %lld\n",
      static_cast<long long>(c.frames), static_cast<long long>(samples),
      static_cast<long long>(c.checksum_errors), static_cast<long long>(c.resyncs),
      static_cast<long long>(c.bytes_skipped));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  for (const auto& a : args) {
    if (a == "-h" || a == "--help") {
      Usage(stdout);
      return 0;
    }
  }
  if (args.size() < 2) {
    Usage(stderr);
    return 1;
  }
  const std::string device = args[0];
  bool express = false;
  std::string path;
  for (size_t i = 1; i < args.size(); ++i) {
    if (args[i] == "--express" && device == "rplidar") {
      express = true;
    } else if (path.empty() && args[i].rfind("--", 0) != 0) {
      path = args[i];
    } else {
      std::fprintf(stderr, "omni decode: unexpected argument '%s'\n", args[i].c_str());
      return 1;
    }
  }
  if (path.empty()) {
    Usage(stderr);
    return 1;
  }
  // A capture is a file or a pipe (`<(xz -dc capture.xz)`, /dev/stdin from a pipe), read whole
  // up to 1 GiB: a folder threw, a serial device or /dev/zero never ended.
  constexpr size_t kMaxBytes = size_t{1} << 30;
  std::error_code ec;
  const auto type = std::filesystem::status(path, ec).type();
  if (!ec && type != std::filesystem::file_type::regular &&
      type != std::filesystem::file_type::fifo) {
    std::fprintf(stderr,
                 "omni decode: %s is not a file or a pipe (decode a capture; record a port with "
                 "e.g. `cat /dev/ttyUSB0 > capture.bin`)\n",
                 path.c_str());
    return 1;
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    std::fprintf(stderr, "omni decode: cannot open %s: %s\n", path.c_str(), std::strerror(errno));
    return 1;
  }
  std::vector<uint8_t> bytes;
  std::vector<char> chunk(1 << 16);
  while (in.read(chunk.data(), static_cast<std::streamsize>(chunk.size())) || in.gcount() > 0) {
    bytes.insert(bytes.end(), chunk.begin(), chunk.begin() + in.gcount());
    if (bytes.size() > kMaxBytes) {
      std::fprintf(stderr, "omni decode: %s is over 1 GiB; cut it first (head -c)\n", path.c_str());
      return 1;
    }
  }
  if (device == "rplidar") return DecodeRplidar(bytes, express);
  if (device == "imu") return DecodeImu(bytes);
  std::fprintf(stderr, "omni decode: unknown device '%s' (rplidar or imu)\n", device.c_str());
  return 1;
}
