// omni-depth-stream: a two-process check that compressed depth survives the bus.
//   send: publishes depth_image_t frames at a fixed rate (seq 0..N-1) for some seconds.
//   recv: decodes every frame, checks it bit-exact against the same source frames, counts
//         frames lost (gaps in seq), decode errors and mismatches; exits 0 only if none.
// The frames come from an rgbd sequence folder (DIR/depth/*.png|*.pgm, cycled) or, without
// --sequence, from a deterministic synthetic scene both sides can regenerate.
#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/depth_image_t.hpp"
#include "omni/kinect/depth_message.h"
#include "omni/octomap_builder/depth_io.h"

namespace fs = std::filesystem;

namespace {

volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

struct Options {
  std::string mode;
  std::string url;
  std::string channel = "DEPTH";
  std::string sequence;
  std::string encoding = "delta";
  double rate_hz = 30;
  double seconds = 5;
  double timeout_s = 5;
  int64_t frames = -1;  // default rate * seconds
};

struct Source {
  int width = 0;
  int height = 0;
  std::vector<std::vector<uint16_t>> frames;
};

void Usage() {
  std::cout
      << "usage: omni-depth-stream send|recv [options]\n"
         "  --url URL         LCM URL (default: LCM_DEFAULT_URL or LCM's multicast default)\n"
         "  --channel NAME    channel (default DEPTH)\n"
         "  --sequence DIR    frames from DIR/depth/*.png|*.pgm (e.g. ../shared/datasets/rgbd/\n"
         "                    kinect-5frames), cycled; default: a synthetic 640x480 scene\n"
         "  --rate HZ         frames per second (default 30)\n"
         "  --seconds S       stream length (default 5; use 60 for the long check)\n"
         "  --frames N        number of frames instead of rate*seconds\n"
         "  --encoding E      send: raw, zlib or delta (default delta)\n"
         "  --timeout S       recv: give up S seconds after the last frame, or before the\n"
         "                    first one (default 5)\n"
         "Run recv first, then send with the same --sequence and --frames/--rate/--seconds.\n"
         "recv prints 'received R of N frames: lost L, decode errors E, mismatches M' and\n"
         "exits 0 only when every frame arrived and decoded bit-exact.\n";
}

bool LoadSource(const std::string& dir, Source* src, std::string* err) {
  if (dir.empty()) {
    src->width = 640;
    src->height = 480;
    for (int f = 0; f < 8; ++f) {
      std::vector<uint16_t> px(static_cast<size_t>(src->width) * src->height);
      for (int y = 0; y < src->height; ++y)
        for (int x = 0; x < src->width; ++x) {
          uint32_t v = 1200 + 2 * x + 3 * y + 17 * f;
          if (x > 300 + 5 * f && y > 200) v = 900 + x / 2;
          if (((x * 7 + y * 13 + f) % 97) == 0) v = 0;  // scattered holes
          px[static_cast<size_t>(y) * src->width + x] = static_cast<uint16_t>(v);
        }
      src->frames.push_back(std::move(px));
    }
    return true;
  }
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(fs::path(dir) / "depth", ec)) {
    const std::string ext = e.path().extension().string();
    if (ext == ".png" || ext == ".pgm") files.push_back(e.path());
  }
  if (ec || files.empty()) {
    *err = "no .png/.pgm depth frames in " + dir + "/depth";
    return false;
  }
  std::sort(files.begin(), files.end());
  for (const auto& f : files) {
    omni::octo::DepthImage im;
    const omni::Status s = omni::octo::ReadDepthFile(f.string(), &im);
    if (!s.ok()) {
      *err = s.message();
      return false;
    }
    if (src->frames.empty()) {
      src->width = im.width;
      src->height = im.height;
    } else if (im.width != src->width || im.height != src->height) {
      *err = f.string() + ": size differs from the first frame";
      return false;
    }
    src->frames.push_back(std::move(im.data));
  }
  return true;
}

int64_t WallUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

int Send(const Options& o, const Source& src, omni::bus::Bus* bus) {
  omni::kinect::DepthEncoding enc;
  if (o.encoding == "raw") {
    enc = omni::kinect::DepthEncoding::kRaw;
  } else if (o.encoding == "zlib") {
    enc = omni::kinect::DepthEncoding::kZlib;
  } else if (o.encoding == "delta") {
    enc = omni::kinect::DepthEncoding::kDeltaZlib;
  } else {
    std::cerr << "omni-depth-stream: --encoding must be raw, zlib or delta, got '" << o.encoding
              << "'\n";
    return 2;
  }
  // Encode every distinct frame once; the stream then measures the bus, not the encoder.
  std::vector<omni::depth_image_t> msgs(src.frames.size());
  for (size_t i = 0; i < src.frames.size(); ++i) {
    omni::depth_image_t& m = msgs[i];
    m.frame = "depth_optical";
    m.depth_scale = 1000;
    const omni::Status s =
        omni::kinect::FillDepthMessage(src.frames[i].data(), src.width, src.height, enc, {}, &m);
    if (!s.ok()) {
      std::cerr << "omni-depth-stream: encode: " << s.message() << "\n";
      return 1;
    }
  }
  const auto period = std::chrono::duration<double>(1.0 / o.rate_hz);
  const auto start = std::chrono::steady_clock::now();
  double bytes = 0;
  int64_t sent = 0, failed = 0;
  for (int64_t seq = 0; seq < o.frames && !g_stop; ++seq) {
    std::this_thread::sleep_until(start + std::chrono::duration_cast<std::chrono::nanoseconds>(
                                              period * static_cast<double>(seq)));
    omni::depth_image_t& m = msgs[static_cast<size_t>(seq) % msgs.size()];
    m.seq = seq;
    m.utime = WallUs();
    if (bus->Publish(o.channel, m)) {
      ++sent;
      bytes += m.size;
    } else {
      ++failed;
    }
  }
  const double secs =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("sent %lld of %lld frames (%s, %.0f bytes/frame, %.2f MB/s over %.1f s)\n",
              static_cast<long long>(sent), static_cast<long long>(o.frames), o.encoding.c_str(),
              sent ? bytes / sent : 0.0, secs > 0 ? bytes / secs / 1e6 : 0.0, secs);
  return failed == 0 && sent == o.frames ? 0 : 1;
}

int Recv(const Options& o, const Source& src, omni::bus::Bus* bus) {
  int64_t received = 0, mismatches = 0, decode_errors = 0, last_seq = -1, out_of_order = 0;
  std::vector<uint16_t> px;
  bus->Subscribe<omni::depth_image_t>(o.channel, [&](const omni::depth_image_t& m, int64_t) {
    ++received;
    if (m.seq <= last_seq) ++out_of_order;
    last_seq = std::max(last_seq, m.seq);
    const omni::Status s = omni::kinect::ReadDepthMessage(m, &px);
    if (!s.ok()) {
      ++decode_errors;
      std::cerr << "seq " << m.seq << ": " << s.message() << "\n";
      return;
    }
    const auto& want = src.frames[static_cast<size_t>(m.seq < 0 ? 0 : m.seq) % src.frames.size()];
    if (m.width != src.width || m.height != src.height || px != want) ++mismatches;
  });
  std::printf("ready: waiting for %lld frames on %s\n", static_cast<long long>(o.frames),
              o.channel.c_str());
  std::fflush(stdout);
  auto last = std::chrono::steady_clock::now();
  while (!g_stop && last_seq + 1 < o.frames) {
    const int rc = bus->HandleTimeout(100);
    if (rc < 0) {
      std::cerr << "omni-depth-stream: LCM failed while receiving\n";
      break;
    }
    if (rc > 0) {
      last = std::chrono::steady_clock::now();
    } else if (std::chrono::duration<double>(std::chrono::steady_clock::now() - last).count() >
               o.timeout_s) {
      std::cerr << "omni-depth-stream: no frame for " << o.timeout_s << " s, stopping\n";
      break;
    }
  }
  const int64_t bus_errors = bus->counters().decode_errors.load();
  const int64_t lost = o.frames - received;
  std::printf(
      "received %lld of %lld frames: lost %lld, decode errors %lld, mismatches %lld, "
      "out of order %lld\n",
      static_cast<long long>(received), static_cast<long long>(o.frames),
      static_cast<long long>(lost), static_cast<long long>(decode_errors + bus_errors),
      static_cast<long long>(mismatches), static_cast<long long>(out_of_order));
  return lost == 0 && decode_errors == 0 && bus_errors == 0 && mismatches == 0 && out_of_order == 0
             ? 0
             : 1;
}

bool ParseDouble(const std::string& s, double lo, double hi, double* out) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0' || !(v >= lo && v <= hi)) return false;
  *out = v;
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << "omni-depth-stream: " << a << " needs a value\n";
        std::exit(2);
      }
      return argv[++i];
    };
    auto number = [&](double lo, double hi, double* out) {
      const std::string v = next();
      if (!ParseDouble(v, lo, hi, out)) {
        std::cerr << "omni-depth-stream: " << a << " wants a number in [" << lo << ", " << hi
                  << "], got '" << v << "'\n";
        std::exit(2);
      }
    };
    double v = 0;
    if (a == "--help" || a == "-h") {
      Usage();
      return 0;
    } else if (a == "send" || a == "recv") {
      o.mode = a;
    } else if (a == "--url" || a == "--lcm-url") {
      o.url = next();
    } else if (a == "--channel") {
      o.channel = next();
    } else if (a == "--sequence") {
      o.sequence = next();
    } else if (a == "--encoding") {
      o.encoding = next();
    } else if (a == "--rate") {
      number(0.1, 1000, &o.rate_hz);
    } else if (a == "--seconds") {
      number(0.1, 86400, &o.seconds);
    } else if (a == "--timeout") {
      number(0.1, 3600, &o.timeout_s);
    } else if (a == "--frames") {
      number(1, 1e8, &v);
      o.frames = static_cast<int64_t>(v);
    } else {
      std::cerr << "omni-depth-stream: unknown argument '" << a << "'\n";
      Usage();
      return 2;
    }
  }
  if (o.mode.empty()) {
    std::cerr << "omni-depth-stream: say send or recv\n";
    Usage();
    return 2;
  }
  if (o.frames < 0) o.frames = std::max<int64_t>(1, static_cast<int64_t>(o.rate_hz * o.seconds));
  Source src;
  std::string err;
  if (!LoadSource(o.sequence, &src, &err)) {
    std::cerr << "omni-depth-stream: " << err << "\n";
    return 1;
  }
  auto bus = omni::bus::Bus::Create(o.url);
  if (!bus.ok()) {
    std::cerr << "omni-depth-stream: " << bus.error().message << "\n";
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  return o.mode == "send" ? Send(o, src, bus->get()) : Recv(o, src, bus->get());
}
