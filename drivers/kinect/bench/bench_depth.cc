// omni-bench-depth (./omni bench depth): the bus depth codec beside plain zlib on the same
// frames in the same run. For every rgbd sequence under DATASETS/rgbd (each with a depth/
// folder of 16-bit PNG or PGM frames) it encodes and decodes ~100 frames (cycling through the
// sequence's frames when it has fewer), checks every decode is bit-exact, and prints ratio,
// encode/decode ms per frame and the bus load at 30 Hz. Writes one JSON row per system and
// dataset to out/bench/depth.jsonl.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <string>
#include <vector>

#include "omni/kinect/depth_codec.h"
#include "omni/octomap_builder/depth_io.h"

namespace fs = std::filesystem;
using omni::kinect::DepthEncodeOptions;
using omni::kinect::DepthEncoding;
using omni::kinect::DepthPredictor;

namespace {

struct Sequence {
  std::string name;
  int width = 0;
  int height = 0;
  std::vector<std::vector<uint16_t>> frames;
};

struct System {
  std::string name;
  DepthEncoding encoding;
  DepthEncodeOptions options;
};

struct Row {
  double ratio = 0, bytes_per_frame = 0, encode_ms = 0, decode_ms = 0, mb_per_s = 0;
  bool lossless = true;
};

double NowMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// Numeric order of "1.png", "2.png", ... (names that are not numbers sort after, by name).
bool FrameLess(const fs::path& a, const fs::path& b) {
  const std::string sa = a.stem().string(), sb = b.stem().string();
  const bool na = !sa.empty() && std::all_of(sa.begin(), sa.end(), ::isdigit);
  const bool nb = !sb.empty() && std::all_of(sb.begin(), sb.end(), ::isdigit);
  if (na && nb) return std::stoll(sa) < std::stoll(sb);
  if (na != nb) return na;
  return sa < sb;
}

bool LoadSequence(const fs::path& dir, Sequence* seq, std::string* err) {
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(dir / "depth")) {
    const std::string ext = e.path().extension().string();
    if (ext == ".png" || ext == ".pgm") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end(), FrameLess);
  if (files.empty()) {
    *err = "no .png/.pgm frames in " + (dir / "depth").string();
    return false;
  }
  seq->name = dir.filename().string();
  for (const auto& f : files) {
    omni::octo::DepthImage im;
    omni::Status s = omni::octo::ReadDepthFile(f.string(), &im);
    if (!s.ok()) {
      *err = s.message();
      return false;
    }
    if (seq->frames.empty()) {
      seq->width = im.width;
      seq->height = im.height;
    } else if (im.width != seq->width || im.height != seq->height) {
      *err = f.string() + ": size differs from the first frame";
      return false;
    }
    seq->frames.push_back(std::move(im.data));
  }
  return true;
}

Row Measure(const Sequence& seq, const System& sys, int frames) {
  Row row;
  const size_t raw_bytes = static_cast<size_t>(seq.width) * seq.height * 2;
  std::vector<std::vector<uint8_t>> encoded(frames);
  std::vector<uint16_t> decoded;
  // Warm-up (page faults, zlib tables) outside the timed loops.
  {
    std::vector<uint8_t> tmp;
    if (!omni::kinect::EncodeDepth(sys.encoding, seq.frames[0].data(), seq.width, seq.height,
                                   sys.options, &tmp)
             .ok() ||
        !omni::kinect::DecodeDepth(static_cast<int8_t>(sys.encoding), tmp.data(), tmp.size(),
                                   seq.width, seq.height, &decoded)
             .ok()) {
      row.lossless = false;
      return row;
    }
  }
  double total_bytes = 0;
  const double t0 = NowMs();
  for (int i = 0; i < frames; ++i) {
    const auto& px = seq.frames[i % seq.frames.size()];
    if (!omni::kinect::EncodeDepth(sys.encoding, px.data(), seq.width, seq.height, sys.options,
                                   &encoded[i])
             .ok())
      row.lossless = false;
  }
  const double t1 = NowMs();
  int mismatches = 0;
  double decode_total = 0;
  for (int i = 0; i < frames; ++i) {
    total_bytes += static_cast<double>(encoded[i].size());
    const double d0 = NowMs();
    const omni::Status s =
        omni::kinect::DecodeDepth(static_cast<int8_t>(sys.encoding), encoded[i].data(),
                                  encoded[i].size(), seq.width, seq.height, &decoded);
    decode_total += NowMs() - d0;
    if (!s.ok() || decoded != seq.frames[i % seq.frames.size()]) ++mismatches;
  }
  row.lossless = row.lossless && mismatches == 0;
  row.bytes_per_frame = total_bytes / frames;
  row.ratio = static_cast<double>(raw_bytes) / row.bytes_per_frame;
  row.encode_ms = (t1 - t0) / frames;
  row.decode_ms = decode_total / frames;
  row.mb_per_s = row.bytes_per_frame * 30.0 / 1e6;
  return row;
}

void Usage() {
  std::cout
      << "usage: omni-bench-depth [--datasets DIR] [--out FILE] [--frames N] [--only NAME]\n"
         "                        [--alternatives]\n"
         "Encodes and decodes N frames (default 100; a sequence with fewer frames is cycled)\n"
         "of every DIR/rgbd/*/depth sequence (default DIR: $OMNI_DATASETS_DIR, else\n"
         "../shared/datasets) with: raw, plain zlib level 1 and 6 of the little-endian bytes\n"
         "(the peer), and omni's DELTA_ZLIB\n"
         "(MED predictor, zig-zag residuals in two byte planes, zlib Z_RLE). Every decode is\n"
         "checked bit-exact. --alternatives adds the other predictors, levels and strategies\n"
         "that were measured to choose the default. Prints a table and writes one JSON row per\n"
         "system and dataset (default out/bench/depth.jsonl).\n";
}

}  // namespace

int main(int argc, char** argv) {
  std::string datasets = "../shared/datasets";
  if (const char* env = std::getenv("OMNI_DATASETS_DIR"); env != nullptr && *env != '\0')
    datasets = env;
  std::string out_path = "out/bench/depth.jsonl";
  std::string only;
  int frames = 100;
  bool alternatives = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << a << " needs a value\n";
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--help" || a == "-h") {
      Usage();
      return 0;
    } else if (a == "--datasets") {
      datasets = next();
    } else if (a == "--out") {
      out_path = next();
    } else if (a == "--only") {
      only = next();
    } else if (a == "--alternatives") {
      alternatives = true;
    } else if (a == "--frames") {
      const std::string v = next();
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (end == v.c_str() || *end != '\0' || n < 1 || n > 100000) {
        std::cerr << "--frames wants an integer 1..100000, got '" << v << "'\n";
        return 2;
      }
      frames = static_cast<int>(n);
    } else {
      std::cerr << "unknown option " << a << "\n";
      Usage();
      return 2;
    }
  }

  std::vector<Sequence> seqs;
  const fs::path rgbd = fs::path(datasets) / "rgbd";
  std::error_code ec;
  if (fs::is_directory(rgbd, ec)) {
    std::vector<fs::path> dirs;
    for (const auto& e : fs::directory_iterator(rgbd))
      if (fs::is_directory(e.path() / "depth")) dirs.push_back(e.path());
    std::sort(dirs.begin(), dirs.end());
    for (const auto& d : dirs) {
      if (!only.empty() && d.filename() != only) continue;
      Sequence s;
      std::string err;
      if (!LoadSequence(d, &s, &err)) {
        std::cerr << "skipping " << d.filename().string() << ": " << err << "\n";
        continue;
      }
      seqs.push_back(std::move(s));
    }
  }
  if (seqs.empty()) {
    std::cerr << "omni-bench-depth: no depth sequence found under " << rgbd.string() << "\n";
    return 1;
  }

  auto sys = [](const std::string& name, DepthEncoding enc, int level, DepthPredictor p,
                int strategy) {
    DepthEncodeOptions o;
    o.zlib_level = level;
    o.predictor = p;
    o.zlib_strategy = strategy;
    return System{name, enc, o};
  };
  const DepthPredictor med = DepthPredictor::kMed;
  std::vector<System> systems = {
      sys("raw", DepthEncoding::kRaw, 0, med, 0),
      sys("zlib-1", DepthEncoding::kZlib, 1, med, 0),
      sys("zlib-6", DepthEncoding::kZlib, 6, med, 0),
      sys("omni-delta-zlib", DepthEncoding::kDeltaZlib, 1, med, 3),
  };
  if (alternatives) {
    for (DepthPredictor p :
         {DepthPredictor::kLeft, DepthPredictor::kUp, DepthPredictor::kMed, DepthPredictor::kAvg}) {
      for (int level : {1, 3, 6}) {
        for (int strategy : {0, 1, 2, 3}) {
          if (p == med && level == 1 && strategy == 3) continue;  // the default, above
          const char* sname = strategy == 0   ? ""
                              : strategy == 1 ? "-filtered"
                              : strategy == 2 ? "-huffman"
                                              : "-rle";
          systems.push_back(sys(std::string("alt-") + omni::kinect::DepthPredictorName(p) + "-" +
                                    std::to_string(level) + sname,
                                DepthEncoding::kDeltaZlib, level, p, strategy));
        }
      }
    }
  }

  if (fs::path(out_path).has_parent_path())
    fs::create_directories(fs::path(out_path).parent_path(), ec);
  std::ofstream jsonl(out_path);
  if (!jsonl) {
    std::cerr << "omni-bench-depth: cannot write " << out_path << "\n";
    return 1;
  }
  std::printf("%-18s %-22s %6s %7s %10s %10s %10s %10s %8s\n", "dataset", "system", "frames",
              "ratio", "bytes/fr", "enc ms/fr", "dec ms/fr", "MB/s@30Hz", "lossless");
  bool all_lossless = true;
  for (const auto& s : seqs) {
    for (const auto& y : systems) {
      const Row r = Measure(s, y, frames);
      all_lossless = all_lossless && r.lossless;
      std::printf("%-18s %-22s %6d %7.2f %10.0f %10.3f %10.3f %10.2f %8s\n", s.name.c_str(),
                  y.name.c_str(), frames, r.ratio, r.bytes_per_frame, r.encode_ms, r.decode_ms,
                  r.mb_per_s, r.lossless ? "yes" : "NO");
      jsonl << std::setprecision(6) << "{\"system\":\"" << y.name << "\",\"dataset\":\"" << s.name
            << "\",\"frames\":" << frames << ",\"unique_frames\":" << s.frames.size()
            << ",\"width\":" << s.width << ",\"height\":" << s.height << ",\"encoding\":\""
            << omni::kinect::DepthEncodingName(static_cast<int8_t>(y.encoding))
            << "\",\"zlib_level\":" << y.options.zlib_level << ",\"ratio\":" << r.ratio
            << ",\"bytes_per_frame\":" << r.bytes_per_frame << ",\"encode_ms\":" << r.encode_ms
            << ",\"decode_ms\":" << r.decode_ms << ",\"mb_per_s_at_30hz\":" << r.mb_per_s
            << ",\"lossless\":" << (r.lossless ? "true" : "false") << "}\n";
    }
    std::printf("%-18s (%zu distinct %dx%d frames, cycled to %d)\n", s.name.c_str(),
                s.frames.size(), s.width, s.height, frames);
  }
  std::printf("wrote %s\n", out_path.c_str());
  if (!all_lossless) {
    std::cerr << "omni-bench-depth: a round trip was not bit-exact\n";
    return 1;
  }
  return 0;
}
