#include "omni/kinect/depth_codec.h"

#include <zlib.h>

#include <algorithm>
#include <climits>
#include <cstring>
#include <sstream>
#include <string>

namespace omni::kinect {
namespace {

// deflate cannot expand data by more than ~1032:1 when inflated; a payload that claims a larger
// image than that is rejected before any allocation the size of the claimed image.
constexpr size_t kMaxInflateRatio = 1032;
constexpr uint8_t kMagic0 = 'O';
constexpr uint8_t kMagic1 = 'D';
constexpr uint8_t kVersion = 1;

Error ParseError(const std::string& what) { return MakeError(ErrorCode::kParse, what); }

std::string SizeText(int width, int height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

Status CheckSize(int width, int height) {
  if (width <= 0 || height <= 0 || width > kMaxDepthSide || height > kMaxDepthSide) {
    return MakeError(ErrorCode::kInvalidArgument, "depth image size " + SizeText(width, height) +
                                                      " is not plausible (1.." +
                                                      std::to_string(kMaxDepthSide) + " per side)");
  }
  return Status::Ok();
}

void PutU32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
uint32_t GetU32(const uint8_t* p) {
  return static_cast<uint32_t>(p[0]) | (static_cast<uint32_t>(p[1]) << 8) |
         (static_cast<uint32_t>(p[2]) << 16) | (static_cast<uint32_t>(p[3]) << 24);
}

inline uint16_t ZigZag(uint16_t r) {
  return static_cast<uint16_t>((r << 1) ^ static_cast<uint16_t>(0u - (r >> 15)));
}
inline uint16_t UnZigZag(uint16_t z) {
  return static_cast<uint16_t>((z >> 1) ^ static_cast<uint16_t>(0u - (z & 1u)));
}

inline int Med(int a, int b, int c) {
  const int mx = a > b ? a : b;
  const int mn = a > b ? b : a;
  if (c >= mx) return mn;
  if (c <= mn) return mx;
  return a + b - c;
}

// Prediction of pixel (x, y >= 1, x >= 1) from its left a, up b and up-left c neighbours.
template <DepthPredictor P>
inline int Predict(int a, int b, int c) {
  if constexpr (P == DepthPredictor::kLeft) {
    (void)b;
    (void)c;
    return a;
  } else if constexpr (P == DepthPredictor::kUp) {
    (void)a;
    (void)c;
    return b;
  } else if constexpr (P == DepthPredictor::kMed) {
    return Med(a, b, c);
  } else {
    (void)c;
    return (a + b) >> 1;
  }
}

// Residuals of all pixels as two byte planes: lo[0, n) then hi[0, n) in `planes`.
// Row 0 is predicted from the left (first pixel from 0); column 0 of the other rows from above.
template <DepthPredictor P>
void Residuals(const uint16_t* px, int width, int height, uint8_t* planes) {
  const size_t n = static_cast<size_t>(width) * height;
  uint8_t* lo = planes;
  uint8_t* hi = planes + n;
  auto put = [&](size_t i, int value, int pred) {
    const uint16_t z = ZigZag(static_cast<uint16_t>(value - pred));
    lo[i] = static_cast<uint8_t>(z);
    hi[i] = static_cast<uint8_t>(z >> 8);
  };
  put(0, px[0], 0);
  for (int x = 1; x < width; ++x) put(x, px[x], px[x - 1]);
  for (int y = 1; y < height; ++y) {
    const size_t row = static_cast<size_t>(y) * width;
    const uint16_t* cur = px + row;
    const uint16_t* up = cur - width;
    put(row, cur[0], up[0]);
    for (int x = 1; x < width; ++x) put(row + x, cur[x], Predict<P>(cur[x - 1], up[x], up[x - 1]));
  }
}

template <DepthPredictor P>
void Reconstruct(const uint8_t* planes, int width, int height, uint16_t* px) {
  const size_t n = static_cast<size_t>(width) * height;
  const uint8_t* lo = planes;
  const uint8_t* hi = planes + n;
  auto get = [&](size_t i, int pred) {
    const uint16_t z = static_cast<uint16_t>(lo[i] | (hi[i] << 8));
    return static_cast<uint16_t>(pred + UnZigZag(z));
  };
  px[0] = get(0, 0);
  for (int x = 1; x < width; ++x) px[x] = get(x, px[x - 1]);
  for (int y = 1; y < height; ++y) {
    const size_t row = static_cast<size_t>(y) * width;
    uint16_t* cur = px + row;
    const uint16_t* up = cur - width;
    cur[0] = get(row, up[0]);
    for (int x = 1; x < width; ++x) cur[x] = get(row + x, Predict<P>(cur[x - 1], up[x], up[x - 1]));
  }
}

bool KnownPredictor(uint8_t p) {
  return p >= static_cast<uint8_t>(DepthPredictor::kLeft) &&
         p <= static_cast<uint8_t>(DepthPredictor::kAvg);
}

// Appends one zlib stream of src[0, n) to *out.
Status Deflate(const uint8_t* src, size_t n, int level, int strategy, std::vector<uint8_t>* out) {
  if (level < 0 || level > 9) {
    return MakeError(ErrorCode::kInvalidArgument,
                     "zlib level " + std::to_string(level) + " is outside 0..9");
  }
  if (n > UINT_MAX / 2) return MakeError(ErrorCode::kInvalidArgument, "depth image too large");
  z_stream z{};
  if (deflateInit2(&z, level, Z_DEFLATED, 15, 8, strategy) != Z_OK) {
    return MakeError(ErrorCode::kInvalidArgument, "zlib refused level " + std::to_string(level) +
                                                      " strategy " + std::to_string(strategy));
  }
  const size_t start = out->size();
  const size_t bound = deflateBound(&z, static_cast<uLong>(n));
  out->resize(start + bound);
  z.next_in = const_cast<Bytef*>(src);  // zlib's API is not const-correct; it does not write
  z.avail_in = static_cast<uInt>(n);
  z.next_out = out->data() + start;
  z.avail_out = static_cast<uInt>(bound);
  const int rc = deflate(&z, Z_FINISH);
  const size_t written = z.total_out;
  deflateEnd(&z);
  if (rc != Z_STREAM_END) {
    out->resize(start);
    return MakeError(ErrorCode::kInternal, "zlib deflate failed (code " + std::to_string(rc) + ")");
  }
  out->resize(start + written);
  return Status::Ok();
}

// Inflates exactly one zlib stream that must fill dst[0, n) and use every byte of src[0, size).
Status InflateExact(const char* what, const uint8_t* src, size_t size, uint8_t* dst, size_t n) {
  if (size > UINT_MAX || n > UINT_MAX) return ParseError(std::string(what) + ": payload too large");
  z_stream z{};
  if (inflateInit(&z) != Z_OK) return MakeError(ErrorCode::kInternal, "zlib inflateInit failed");
  z.next_in = const_cast<Bytef*>(src);  // inflate only reads its input
  z.avail_in = static_cast<uInt>(size);
  z.next_out = dst;
  z.avail_out = static_cast<uInt>(n);
  const int rc = inflate(&z, Z_FINISH);
  const size_t produced = z.total_out;
  const size_t consumed = z.total_in;
  const bool more_output = rc == Z_BUF_ERROR && z.avail_out == 0;
  const char* msg = z.msg;
  std::ostringstream s;
  if (rc == Z_STREAM_END) {
    if (produced != n) {
      s << what << ": stream holds " << produced << " bytes, expected " << n;
    } else if (consumed != size) {
      s << what << ": " << (size - consumed) << " bytes after the end of the zlib stream (of "
        << size << ")";
    }
  } else if (more_output) {
    s << what << ": stream holds more than the expected " << n << " bytes";
  } else if (rc == Z_BUF_ERROR || rc == Z_OK) {
    s << what << ": truncated zlib stream (" << size << " bytes give " << produced << " of " << n
      << ")";
  } else {
    s << what << ": corrupt zlib stream at input byte " << consumed << " (zlib code " << rc
      << (msg ? std::string(", ") + msg : std::string()) << ")";
  }
  inflateEnd(&z);
  if (!s.str().empty()) return ParseError(s.str());
  return Status::Ok();
}

}  // namespace

const char* DepthEncodingName(int8_t encoding) {
  switch (encoding) {
    case 0:
      return "RAW";
    case 1:
      return "ZLIB";
    case 2:
      return "DELTA_ZLIB";
    default:
      return "unknown";
  }
}

const char* DepthPredictorName(DepthPredictor predictor) {
  switch (predictor) {
    case DepthPredictor::kLeft:
      return "left";
    case DepthPredictor::kUp:
      return "up";
    case DepthPredictor::kMed:
      return "med";
    case DepthPredictor::kAvg:
      return "avg";
  }
  return "unknown";
}

Status EncodeDepth(DepthEncoding encoding, const uint16_t* pixels, int width, int height,
                   const DepthEncodeOptions& options, std::vector<uint8_t>* out) {
  out->clear();
  if (Status s = CheckSize(width, height); !s.ok()) return s;
  if (pixels == nullptr) return MakeError(ErrorCode::kInvalidArgument, "no depth pixels");
  const size_t n = static_cast<size_t>(width) * height;
  switch (encoding) {
    case DepthEncoding::kRaw:
    case DepthEncoding::kZlib: {
      std::vector<uint8_t> raw(2 * n);
      for (size_t i = 0; i < n; ++i) {
        raw[2 * i] = static_cast<uint8_t>(pixels[i]);
        raw[2 * i + 1] = static_cast<uint8_t>(pixels[i] >> 8);
      }
      if (encoding == DepthEncoding::kRaw) {
        *out = std::move(raw);
        return Status::Ok();
      }
      return Deflate(raw.data(), raw.size(), options.zlib_level,
                     options.zlib_strategy < 0 ? Z_DEFAULT_STRATEGY : options.zlib_strategy, out);
    }
    case DepthEncoding::kDeltaZlib: {
      const uint8_t p = static_cast<uint8_t>(options.predictor);
      if (!KnownPredictor(p)) {
        return MakeError(ErrorCode::kInvalidArgument,
                         "unknown depth predictor " + std::to_string(static_cast<int>(p)));
      }
      std::vector<uint8_t> planes(2 * n);
      switch (options.predictor) {
        case DepthPredictor::kLeft:
          Residuals<DepthPredictor::kLeft>(pixels, width, height, planes.data());
          break;
        case DepthPredictor::kUp:
          Residuals<DepthPredictor::kUp>(pixels, width, height, planes.data());
          break;
        case DepthPredictor::kMed:
          Residuals<DepthPredictor::kMed>(pixels, width, height, planes.data());
          break;
        case DepthPredictor::kAvg:
          Residuals<DepthPredictor::kAvg>(pixels, width, height, planes.data());
          break;
      }
      out->resize(kDeltaHeaderBytes);
      uint8_t* h = out->data();
      h[0] = kMagic0;
      h[1] = kMagic1;
      h[2] = kVersion;
      h[3] = p;
      PutU32(h + 4, static_cast<uint32_t>(width));
      PutU32(h + 8, static_cast<uint32_t>(height));
      PutU32(h + 12, static_cast<uint32_t>(crc32(0L, h, 12)));
      Status s = Deflate(planes.data(), planes.size(), options.zlib_level,
                         options.zlib_strategy < 0 ? Z_RLE : options.zlib_strategy, out);
      if (!s.ok()) out->clear();
      return s;
    }
  }
  return MakeError(ErrorCode::kInvalidArgument,
                   "unknown depth encoding " + std::to_string(static_cast<int>(encoding)));
}

Status DecodeDepth(int8_t encoding, const uint8_t* data, size_t size, int width, int height,
                   std::vector<uint16_t>* out) {
  out->clear();
  if (Status s = CheckSize(width, height); !s.ok()) return s;
  if (data == nullptr && size > 0) return MakeError(ErrorCode::kInvalidArgument, "no data");
  const size_t n = static_cast<size_t>(width) * height;
  const size_t bytes = 2 * n;
  const std::string dims = SizeText(width, height);
  switch (encoding) {
    case static_cast<int8_t>(DepthEncoding::kRaw): {
      if (size != bytes) {
        return ParseError("RAW depth " + dims + ": " + std::to_string(size) + " bytes, expected " +
                          std::to_string(bytes));
      }
      out->resize(n);
      for (size_t i = 0; i < n; ++i)
        (*out)[i] = static_cast<uint16_t>(data[2 * i] | (data[2 * i + 1] << 8));
      return Status::Ok();
    }
    case static_cast<int8_t>(DepthEncoding::kZlib): {
      if (size == 0 || bytes / kMaxInflateRatio > size) {
        return ParseError("ZLIB depth " + dims + ": " + std::to_string(size) +
                          " bytes cannot hold a zlib stream of " + std::to_string(bytes) +
                          " bytes");
      }
      std::vector<uint8_t> raw(bytes);
      if (Status s = InflateExact(("ZLIB depth " + dims).c_str(), data, size, raw.data(), bytes);
          !s.ok())
        return s;
      out->resize(n);
      for (size_t i = 0; i < n; ++i)
        (*out)[i] = static_cast<uint16_t>(raw[2 * i] | (raw[2 * i + 1] << 8));
      return Status::Ok();
    }
    case static_cast<int8_t>(DepthEncoding::kDeltaZlib): {
      const std::string what = "DELTA_ZLIB depth " + dims;
      if (size < kDeltaHeaderBytes) {
        return ParseError(what + ": " + std::to_string(size) + " bytes, shorter than the " +
                          std::to_string(kDeltaHeaderBytes) + "-byte header");
      }
      if (data[0] != kMagic0 || data[1] != kMagic1) return ParseError(what + ": bad magic");
      if (GetU32(data + 12) != static_cast<uint32_t>(crc32(0L, data, 12)))
        return ParseError(what + ": header checksum mismatch (damaged header)");
      if (data[2] != kVersion) {
        return ParseError(what + ": codec version " + std::to_string(data[2]) +
                          " is not supported (expected " + std::to_string(kVersion) + ")");
      }
      if (!KnownPredictor(data[3]))
        return ParseError(what + ": unknown predictor " + std::to_string(data[3]));
      const uint32_t hw = GetU32(data + 4);
      const uint32_t hh = GetU32(data + 8);
      if (hw != static_cast<uint32_t>(width) || hh != static_cast<uint32_t>(height)) {
        return ParseError(what + ": header says " + std::to_string(hw) + "x" + std::to_string(hh));
      }
      const size_t body = size - kDeltaHeaderBytes;
      if (body == 0 || bytes / kMaxInflateRatio > body) {
        return ParseError(what + ": " + std::to_string(body) +
                          " body bytes cannot hold a zlib stream of " + std::to_string(bytes) +
                          " bytes");
      }
      std::vector<uint8_t> planes(bytes);
      if (Status s =
              InflateExact(what.c_str(), data + kDeltaHeaderBytes, body, planes.data(), bytes);
          !s.ok())
        return s;
      out->resize(n);
      switch (static_cast<DepthPredictor>(data[3])) {
        case DepthPredictor::kLeft:
          Reconstruct<DepthPredictor::kLeft>(planes.data(), width, height, out->data());
          break;
        case DepthPredictor::kUp:
          Reconstruct<DepthPredictor::kUp>(planes.data(), width, height, out->data());
          break;
        case DepthPredictor::kMed:
          Reconstruct<DepthPredictor::kMed>(planes.data(), width, height, out->data());
          break;
        case DepthPredictor::kAvg:
          Reconstruct<DepthPredictor::kAvg>(planes.data(), width, height, out->data());
          break;
      }
      return Status::Ok();
    }
    default:
      return ParseError("unknown depth encoding " + std::to_string(static_cast<int>(encoding)));
  }
}

}  // namespace omni::kinect
