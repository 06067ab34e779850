// omni-bench-rplidar (`./omni bench rplidar`): throughput of the RPLidar measurement parser and
// revolution assembler on one core, on the real captures in ../shared/datasets/rplidar/derived,
// clean and with random garbage spliced in, beside the byte rate an RPLidar A3 produces
// (256000 baud, 8N1 = 25,600 bytes/s). The goal is >= 100x that rate.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "omni/rplidar/parser.h"
#include "omni/rplidar/scan.h"

namespace fs = std::filesystem;
using omni::rplidar::MeasurementParser;
using omni::rplidar::RevolutionAssembler;
using omni::rplidar::Sample;

namespace {

constexpr double kA3BytesPerSecond = 256000.0 / 10.0;  // 8 data bits + start + stop

struct Row {
  std::string input;
  double bytes = 0;
  double seconds = 0;
  int64_t samples = 0;
  int64_t revolutions = 0;
  int64_t resyncs = 0;
};

// Parses `data` (fed in 64-byte chunks, as a serial read delivers it) `repeat` times and bins
// every revolution into a planar scan, as the driver does.
Row Measure(const std::vector<uint8_t>& data, int repeat) {
  Row r;
  std::vector<Sample> samples, done;
  samples.reserve(4096);
  omni::rplidar::ScanOptions scan_options;
  volatile size_t sink = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < repeat; ++k) {
    MeasurementParser parser;
    RevolutionAssembler assembler;
    for (size_t at = 0; at < data.size(); at += 64) {
      const size_t n = std::min<size_t>(64, data.size() - at);
      samples.clear();
      parser.Feed(data.data() + at, n, static_cast<int64_t>(at), &samples);
      for (const Sample& s : samples) {
        if (assembler.Add(s, &done)) {
          sink = sink + omni::rplidar::RevolutionToScan(done, scan_options).ranges_m.size();
        }
      }
    }
    samples.clear();
    parser.Finish(0, &samples);
    r.samples += parser.counters().samples;
    r.resyncs += parser.counters().resyncs;
    r.revolutions += assembler.revolutions();
  }
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.bytes = static_cast<double>(data.size()) * repeat;
  return r;
}

// One random burst of 1-32 bytes every ~`every` bytes.
std::vector<uint8_t> Splice(const std::vector<uint8_t>& clean, size_t every, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> out;
  out.reserve(clean.size() + clean.size() / every * 32);
  std::uniform_int_distribution<size_t> gap(every / 2, every + every / 2);
  std::uniform_int_distribution<int> len(1, 32), byte(0, 255);
  size_t next = gap(rng);
  for (size_t i = 0; i < clean.size(); ++i) {
    if (i == next) {
      for (int n = len(rng); n > 0; --n) out.push_back(static_cast<uint8_t>(byte(rng)));
      next += gap(rng);
    }
    out.push_back(clean[i]);
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::string datasets = "../shared/datasets";
  if (const char* env = std::getenv("OMNI_DATASETS_DIR")) datasets = env;
  std::string out_dir = "out/bench";
  int min_mb = 64;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      std::printf(
          "usage: omni-bench-rplidar [--datasets DIR] [--out DIR] [--mb N]\n"
          "Parser + revolution assembly throughput on one core on the RPLidar captures in\n"
          "DIR/rplidar/derived (clean, and with garbage spliced in every ~2 KiB), beside an\n"
          "RPLidar A3's byte rate (25,600 B/s). Each input is parsed until N MB (default 64)\n"
          "went through. Writes OUT/rplidar.jsonl (default out/bench).\n");
      return 0;
    }
    if (i + 1 >= argc) {
      std::fprintf(stderr, "omni-bench-rplidar: unknown option or missing value '%s'\n", a.c_str());
      return 2;
    }
    if (a == "--datasets")
      datasets = argv[++i];
    else if (a == "--out")
      out_dir = argv[++i];
    else if (a == "--mb")
      min_mb = std::max(1, std::atoi(argv[++i]));
    else {
      std::fprintf(stderr, "omni-bench-rplidar: unknown option '%s'\n", a.c_str());
      return 2;
    }
  }
  const fs::path dir = fs::path(datasets) / "rplidar" / "derived";
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec))
    if (e.path().extension() == ".bin") files.push_back(e.path());
  if (files.empty()) {
    std::fprintf(stderr, "omni-bench-rplidar: no captures (*.bin) in %s: dataset absent\n",
                 dir.c_str());
    return 1;
  }
  std::sort(files.begin(), files.end());
  // All captures back to back, as one long stream (each starts at a node boundary).
  std::vector<uint8_t> clean;
  for (const auto& f : files) {
    std::ifstream in(f, std::ios::binary);
    clean.insert(clean.end(), std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  const std::vector<uint8_t> dirty = Splice(clean, 2048, 7);
  fs::create_directories(out_dir, ec);
  std::ofstream json(fs::path(out_dir) / "rplidar.jsonl");

  std::printf("RPLidar parser, one core, %zu captures (%zu bytes) from %s\n", files.size(),
              clean.size(), dir.c_str());
  std::printf("%-28s %12s %12s %12s %12s %10s\n", "input", "MB/s", "x A3 rate", "samples",
              "revolutions", "resyncs");
  std::printf("%-28s %12.4f %12s %12s %12s %10s\n", "RPLidar A3 at 256000 baud",
              kA3BytesPerSecond / 1e6, "1", "-", "-", "-");
  bool goal = true;
  for (int pass = 0; pass < 2; ++pass) {
    const auto& data = pass == 0 ? clean : dirty;
    const std::string name = pass == 0 ? "captures, clean" : "captures + garbage/2KiB";
    const int repeat =
        std::max(1, static_cast<int>(min_mb * 1e6 / static_cast<double>(data.size())));
    Measure(data, 1);  // warm-up
    const Row r = Measure(data, repeat);
    const double mbps = r.bytes / r.seconds / 1e6;
    const double times = r.bytes / r.seconds / kA3BytesPerSecond;
    goal = goal && times >= 100;
    std::printf("%-28s %12.2f %12.0f %12lld %12lld %10lld\n", name.c_str(), mbps, times,
                static_cast<long long>(r.samples / repeat),
                static_cast<long long>(r.revolutions / repeat),
                static_cast<long long>(r.resyncs / repeat));
    json << "{\"system\": \"omni\", \"dataset\": \"rplidar/derived\", \"input\": \"" << name
         << "\", \"bytes\": " << data.size() << ", \"mb_per_s\": " << mbps
         << ", \"times_a3_byte_rate\": " << times << ", \"samples\": " << r.samples / repeat
         << ", \"revolutions\": " << r.revolutions / repeat
         << ", \"resyncs\": " << r.resyncs / repeat << "}\n";
  }
  json << "{\"system\": \"rplidar_a3_device\", \"dataset\": \"-\", \"mb_per_s\": "
       << kA3BytesPerSecond / 1e6 << ", \"times_a3_byte_rate\": 1}\n";
  std::printf("goal >= 100x the A3 byte rate on one core: %s\n", goal ? "met" : "NOT met");
  return 0;
}
