// Map and image files as users hand them to `omni eval map`, `map_fusion --fuse` and
// `omni octomap build`: a ROS map_server YAML with its PGM, a PGM/PPM alone, and 16-bit depth
// images (PGM, PNG) and colour PNGs. The readers take paths, so each input is written to a private
// temporary folder first. The first byte picks the reader; for map_server the next two give the
// YAML's length and the rest is the image. What must hold: a reader that accepts a file returns an
// image whose size matches its pixels (and a map whose cells are -1, 0 or 100 on a finite grid with
// a positive cell size); one that refuses says why. A header that claims more than the bytes hold
// is refused without allocating what it claims (ReadPnm reads in chunks; found by review
// 2026-12-06, not by this target). Seeds: map_server files as the mappers write them, a 16-bit PGM,
// and the RGB-D datasets' first depth frames.
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "fuzz.h"
#include "omni/io/grid.h"
#include "omni/io/image_io.h"
#include "omni/octomap_builder/color_image.h"
#include "omni/octomap_builder/depth_io.h"

namespace {

namespace fs = std::filesystem;

// A folder of this process's own, removed at exit.
struct TempDir {
  std::string path;
  TempDir() {
    path =
        (fs::temp_directory_path() / ("omni-fuzz-map-files-" + std::to_string(getpid()))).string();
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

const std::string& Dir() {
  static TempDir dir;
  return dir.path;
}

void Write(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

void CheckImage(const omni::io::Image& im) {
  OMNI_FUZZ_CHECK(im.width > 0 && im.height > 0);
  OMNI_FUZZ_CHECK(im.channels == 1 || im.channels == 3);
  OMNI_FUZZ_CHECK(im.max_value > 0 && im.max_value <= 65535);
  OMNI_FUZZ_CHECK(im.pixels.size() == static_cast<size_t>(im.width) * im.height * im.channels);
  for (uint16_t v : im.pixels) OMNI_FUZZ_CHECK(v <= im.max_value);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  omni::fuzz::Reader r(data, size);
  const uint8_t which = r.U8() % 5;
  const std::string dir = Dir();
  if (which == 0) {
    const std::string yaml = r.Bytes(r.U16());
    Write(dir + "/map.yaml", yaml);
    Write(dir + "/map.pgm", r.Rest());
    auto map = omni::io::ReadMapServer(dir + "/map.yaml");
    if (!map.ok()) {
      OMNI_FUZZ_CHECK(!map.error().message.empty());
      return 0;
    }
    OMNI_FUZZ_CHECK(map->width > 0 && map->height > 0);
    OMNI_FUZZ_CHECK(map->cells.size() == static_cast<size_t>(map->width) * map->height);
    OMNI_FUZZ_CHECK(std::isfinite(map->resolution_m) && map->resolution_m > 0);
    OMNI_FUZZ_CHECK(std::isfinite(map->origin_x_m) && std::isfinite(map->origin_y_m));
    for (int8_t c : map->cells) OMNI_FUZZ_CHECK(c == -1 || c == 0 || c == 100);
  } else if (which == 1) {
    Write(dir + "/image.pgm", r.Rest());
    auto im = omni::io::ReadPnm(dir + "/image.pgm");
    if (!im.ok()) {
      OMNI_FUZZ_CHECK(!im.error().message.empty());
      return 0;
    }
    CheckImage(*im);
  } else if (which == 4) {
    Write(dir + "/color.png", r.Rest());
    omni::octo::ColorImage color;
    const omni::Status s = omni::octo::ReadColorPng(dir + "/color.png", &color);
    if (!s.ok()) {
      OMNI_FUZZ_CHECK(!s.message().empty());
      return 0;
    }
    OMNI_FUZZ_CHECK(color.width > 0 && color.height > 0);
    OMNI_FUZZ_CHECK(color.rgb.size() == static_cast<size_t>(color.width) * color.height * 3);
  } else {
    const std::string path = dir + (which == 2 ? "/depth.pgm" : "/depth.png");
    Write(path, r.Rest());
    omni::octo::DepthImage depth;
    const omni::Status s = omni::octo::ReadDepthFile(path, &depth);
    if (!s.ok()) {
      OMNI_FUZZ_CHECK(!s.message().empty());
      return 0;
    }
    OMNI_FUZZ_CHECK(depth.width > 0 && depth.height > 0 && depth.width <= 16384 &&
                    depth.height <= 16384);
    OMNI_FUZZ_CHECK(depth.data.size() == static_cast<size_t>(depth.width) * depth.height);
  }
  return 0;
}

void omni::fuzz::Seeds(SeedList* seeds) {
  // map_server files as WriteMapServer writes them: a small grid with every kind of cell.
  omni::io::GridMap m;
  m.resolution_m = 0.05;
  m.origin_x_m = -1.5;
  m.origin_y_m = 2.25;
  m.width = 6;
  m.height = 4;
  for (int i = 0; i < m.width * m.height; ++i)
    m.cells.push_back(i % 3 == 0 ? -1 : i % 3 == 1 ? 0 : 100);
  const std::string dir = Dir();
  if (omni::io::WriteMapServer(m, dir + "/seed").ok()) {
    std::ifstream y(dir + "/seed.yaml"), p(dir + "/seed.pgm", std::ios::binary);
    std::string yaml((std::istreambuf_iterator<char>(y)), {}),
        pgm((std::istreambuf_iterator<char>(p)), {});
    // The YAML names its image; the target writes it as map.pgm.
    const auto at = yaml.find("seed.pgm");
    if (at != std::string::npos) yaml.replace(at, 8, "map.pgm");
    std::string in(1, '\0');
    omni::fuzz::AppendU16(&in, static_cast<int>(yaml.size()));
    seeds->Add(in + yaml + pgm);
    seeds->Add(std::string(1, '\1') + pgm);
    // Thresholds and negate given (WriteMapServer writes the defaults).
    const std::string turned = yaml + "occupied_thresh: 0.6\nfree_thresh: 0.1\nnegate: 1\n";
    std::string in2(1, '\0');
    omni::fuzz::AppendU16(&in2, static_cast<int>(turned.size()));
    seeds->Add(in2 + turned + pgm);
  }
  // A 16-bit grey PGM with a comment, and a PPM.
  seeds->Add(std::string("\1P5 # hand made\n3 2\n65535\n") + std::string(12, '\x7f'));
  seeds->Add(std::string("\1P6\n2 2\n255\n") + std::string(12, '\x40'));
  seeds->Add(std::string("\2P5\n4 2\n65535\n") + std::string(16, '\x01'));
  // A whole small grey PNG, as our writer makes it.
  std::vector<uint8_t> px(8 * 6);
  for (size_t i = 0; i < px.size(); ++i) px[i] = static_cast<uint8_t>(i * 5);
  if (omni::octo::WritePng8(dir + "/seed.png", 8, 6, 1, px).ok()) {
    std::ifstream f(dir + "/seed.png", std::ios::binary);
    const std::string png((std::istreambuf_iterator<char>(f)), {});
    seeds->Add(std::string(1, '\3') + png);
    seeds->Add(std::string(1, '\4') + png);
  }
  // Depth frames of the RGB-D sets (PNG and big-endian PGM), a prefix: enough for the headers
  // and the first rows, so most mutations are truncated frames.
  for (const char* file : {"rgbd/iclnuim-5frames/depth/1.png", "rgbd/kinect-5frames/depth/1.pgm"}) {
    SeedList one;
    if (!one.AddDataset(file, 64 << 10)) {
      seeds->missing.insert(seeds->missing.end(), one.missing.begin(), one.missing.end());
      continue;
    }
    const bool png = std::string(file).find(".png") != std::string::npos;
    seeds->Add(std::string(1, png ? '\3' : '\2') + one.inputs[0]);
  }
}
