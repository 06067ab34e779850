// Lossless codec for 16-bit depth images on the bus (omni.depth_image_t `data`).
//
// Encodings (the .lcm constants):
//   RAW        (0): row-major uint16 little-endian, width*height*2 bytes.
//   ZLIB       (1): one zlib stream of the RAW bytes.
//   DELTA_ZLIB (2): a 16-byte header, then one zlib stream of the prediction residuals.
//
// DELTA_ZLIB header (all integers little-endian):
//   0  'O' 'D'          magic
//   2  version          1
//   3  predictor        DepthPredictor below
//   4  width  (uint32)
//   8  height (uint32)
//   12 crc32 of bytes 0..11 (zlib's crc32), so a damaged header is an error, not a wrong image
// Body: each pixel x is predicted from its decoded neighbours (left a, up b, up-left c); the
// residual r = x - pred (mod 2^16) is zig-zag mapped (0, -1, 1, -2, ... -> 0, 1, 2, 3, ...)
// so small residuals of either sign become small numbers; the low bytes of all residuals are
// stored first, then the high bytes (two byte planes: the high plane is almost all zeros on
// smooth depth and zlib folds it away). The zlib stream's Adler-32 covers the residuals.
//
// Decoding validates every length and field and returns an error for truncated, padded or
// corrupt payloads; it never reads outside `data[0, size)`.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "omni/common/result.h"

namespace omni::kinect {

enum class DepthEncoding : int8_t { kRaw = 0, kZlib = 1, kDeltaZlib = 2 };

// Neighbour predictors of DELTA_ZLIB (byte 3 of the header).
enum class DepthPredictor : uint8_t {
  kLeft = 1,  // a (row-wise delta); first column: b
  kUp = 2,    // b; first row: a
  kMed = 3,   // LOCO-I median edge detector: min(a,b) / max(a,b) / a+b-c
  kAvg = 4,   // (a + b) / 2
};

// Largest width or height accepted by the decoder (and the encoder).
constexpr int kMaxDepthSide = 16384;
constexpr size_t kDeltaHeaderBytes = 16;

struct DepthEncodeOptions {
  // Defaults chosen with `omni-bench-depth --alternatives`: MED + Z_RLE was both the smallest
  // and the fastest to encode of left/up/MED/average x levels 1/3/6 x default/filtered/RLE on
  // the rgbd datasets (Z_RLE ignores the level).
  int zlib_level = 1;  // 0..9
  DepthPredictor predictor = DepthPredictor::kMed;
  // zlib strategy: 0 Z_DEFAULT_STRATEGY, 1 Z_FILTERED, 2 Z_HUFFMAN_ONLY, 3 Z_RLE; -1 picks the
  // encoding's best: Z_RLE for DELTA_ZLIB residuals, Z_DEFAULT_STRATEGY for ZLIB's raw bytes
  // (RLE finds no runs in raw 16-bit depth).
  int zlib_strategy = -1;
};

// Encodes width*height pixels (row-major) with `encoding` into *out (replaced).
Status EncodeDepth(DepthEncoding encoding, const uint16_t* pixels, int width, int height,
                   const DepthEncodeOptions& options, std::vector<uint8_t>* out);

// Decodes `data[0, size)` in `encoding` (a raw int8 from the message; unknown values are
// errors) into width*height pixels. The image size comes from the message; DELTA_ZLIB's header
// must agree with it. On error *out is left empty.
Status DecodeDepth(int8_t encoding, const uint8_t* data, size_t size, int width, int height,
                   std::vector<uint16_t>* out);

const char* DepthEncodingName(int8_t encoding);
const char* DepthPredictorName(DepthPredictor predictor);

}  // namespace omni::kinect
