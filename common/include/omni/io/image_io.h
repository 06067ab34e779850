// Small image files: binary PGM (8- and 16-bit) read/write and PNG write (gray or RGB, 8-bit),
// enough for map_server maps, rendered views and plots without an imaging library.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "omni/common/result.h"

namespace omni::io {

struct Image {
  int width = 0;
  int height = 0;
  int channels = 1;              // 1 gray, 3 RGB
  int max_value = 255;           // PGM maxval: 255 (8-bit) or up to 65535 (16-bit samples)
  std::vector<uint16_t> pixels;  // row-major, row 0 at the top, channels interleaved
  uint16_t at(int x, int y, int c = 0) const {
    return pixels[(static_cast<size_t>(y) * width + x) * channels + c];
  }
  uint16_t& at(int x, int y, int c = 0) {
    return pixels[(static_cast<size_t>(y) * width + x) * channels + c];
  }
  static Image Make(int w, int h, int channels, uint16_t fill = 0) {
    Image im;
    im.width = w;
    im.height = h;
    im.channels = channels;
    im.pixels.assign(static_cast<size_t>(w) * h * channels, fill);
    return im;
  }
};

// P5 (gray) and P6 (RGB) binary forms; 16-bit samples are big-endian (Netpbm). Width and
// height must be 1 to `max_side`; memory follows the bytes the file holds, not its header.
constexpr int kMaxPnmSide = 100000;

// Refuses a path that exists but is not a regular file: a FIFO or a device (a map YAML's
// `image: /dev/stdin`) would block or never end.
Status CheckRegularFile(const std::string& path);
// Deflate packs at most ~1032:1: a compressed image file too small to decode to `raw_bytes`
// (what its header claims) is refused before that much is allocated.
Status CheckCompressedSize(const std::string& path, double raw_bytes, int64_t width,
                           int64_t height);
Result<Image> ReadPnm(const std::string& path, int max_side = kMaxPnmSide);
Status WritePgm(const std::string& path, const Image& image);
// 8-bit PNG (values above 255 are clamped). Written atomically (temp file + rename).
Status WritePng(const std::string& path, const Image& image);

}  // namespace omni::io
