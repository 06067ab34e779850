#include "omni/octomap_builder/depth_points.h"

#include <cmath>
#include <cstring>
#include <sstream>
#include <unordered_map>

#include <zlib.h>

#include "omni/kinect/depth_codec.h"

namespace omni::octo {

std::string DepthIntrinsics::Validate() const {
  // The bounds are far outside any camera (a Kinect: f ~ 520 px, c ~ 320 px, scale 1000) and
  // keep every point of a 16-bit depth image finite as a float.
  if (!(std::fabs(fx) >= kMinFocalPx && std::fabs(fx) <= kMaxFocalPx) ||
      !(std::fabs(fy) >= kMinFocalPx && std::fabs(fy) <= kMaxFocalPx))
    return "fx and fy must be finite, with magnitudes in [0.001, 1e7] pixels";
  if (!(std::fabs(cx) <= kMaxPrincipalPx) || !(std::fabs(cy) <= kMaxPrincipalPx))
    return "cx and cy must be finite and within +-1e6 pixels";
  if (!(depth_scale >= kMinDepthScale && depth_scale <= kMaxDepthScale))
    return "depth_scale must be in [0.001, 1e9] raw units per metre";
  return "";
}

Status CheckDepthFrame(const DepthImage& image, const DepthToPointsOptions& options) {
  const std::string bad = image.intrinsics.Validate();
  if (!bad.empty()) return MakeError(ErrorCode::kInvalidArgument, "depth intrinsics: " + bad);
  if (image.width <= 0 || image.height <= 0 ||
      image.data.size() != static_cast<size_t>(image.width) * image.height) {
    std::ostringstream s;
    s << "depth image " << image.width << "x" << image.height << " has " << image.data.size()
      << " values";
    return MakeError(ErrorCode::kInvalidArgument, s.str());
  }
  if (options.pixel_stride < 1)
    return MakeError(ErrorCode::kInvalidArgument, "pixel_stride must be >= 1");
  if (!(options.min_depth_m >= 0) || !(options.max_depth_m > options.min_depth_m))
    return MakeError(ErrorCode::kInvalidArgument, "need 0 <= min_depth_m < max_depth_m");
  return Status::Ok();
}

Result<std::vector<Eigen::Vector3f>> DepthToPoints(const DepthImage& image,
                                                   const DepthToPointsOptions& options) {
  std::vector<Eigen::Vector3f> points;
  if (Status s = DepthToPoints(image, options, &points); !s.ok()) return s.error();
  return points;
}

Status DepthToPoints(const DepthImage& image, const DepthToPointsOptions& options,
                     std::vector<Eigen::Vector3f>* out) {
  out->clear();
  if (Status s = CheckDepthFrame(image, options); !s.ok()) return s;
  const int stride = options.pixel_stride;
  out->reserve(static_cast<size_t>(image.width / stride + 1) * (image.height / stride + 1));
  ForEachDepthPoint(image, options,
                    [out](int, int, float x, float y, float z) { out->emplace_back(x, y, z); });
  return Status::Ok();
}

std::vector<Eigen::Vector3f> VoxelDownsample(const std::vector<Eigen::Vector3f>& points,
                                             double leaf_m) {
  if (!(leaf_m > 0)) return points;
  struct Acc {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    int n = 0;
    size_t order = 0;
  };
  const double inv = 1.0 / leaf_m;
  std::unordered_map<uint64_t, Acc> cells;
  cells.reserve(points.size() / 4 + 16);
  for (const auto& p : points) {
    // 21 bits per axis, offset so negative coordinates map to positive indices.
    const auto ix =
        static_cast<uint64_t>(static_cast<int64_t>(std::floor(p.x() * inv)) + (1 << 20));
    const auto iy =
        static_cast<uint64_t>(static_cast<int64_t>(std::floor(p.y() * inv)) + (1 << 20));
    const auto iz =
        static_cast<uint64_t>(static_cast<int64_t>(std::floor(p.z() * inv)) + (1 << 20));
    const uint64_t key = (ix & 0x1fffff) | ((iy & 0x1fffff) << 21) | ((iz & 0x1fffff) << 42);
    auto [it, inserted] = cells.try_emplace(key);
    if (inserted) it->second.order = cells.size() - 1;
    it->second.sum += p.cast<double>();
    ++it->second.n;
  }
  std::vector<Eigen::Vector3f> out(cells.size());
  for (const auto& [key, acc] : cells) out[acc.order] = (acc.sum / acc.n).cast<float>();
  return out;
}

Status DecodeDepthData(int8_t encoding, const uint8_t* data, size_t size, int width, int height,
                       std::vector<uint16_t>* out) {
  // 4 Mpixel: four times the largest depth camera we know of (Azure Kinect's 1024 x 1024
  // passive IR mode is 1 Mpixel); beyond it a frame is a corrupt header or a decompression bomb.
  constexpr size_t kMaxPixels = size_t{1} << 22;
  if (width <= 0 || height <= 0 || width > 16384 || height > 16384 ||
      static_cast<size_t>(width) * static_cast<size_t>(height) > kMaxPixels) {
    std::ostringstream s;
    s << "depth image size " << width << "x" << height << " is not plausible (at most "
      << kMaxPixels << " pixels)";
    return MakeError(ErrorCode::kInvalidArgument, s.str());
  }
  const size_t n = static_cast<size_t>(width) * height;
  const size_t bytes = n * 2;
  std::vector<uint8_t> raw;
  const uint8_t* src = nullptr;
  switch (static_cast<DepthEncoding>(encoding)) {
    case DepthEncoding::kRawU16Le:
      if (size != bytes) {
        std::ostringstream s;
        s << "raw depth: " << size << " bytes, expected " << bytes;
        return MakeError(ErrorCode::kParse, s.str());
      }
      src = data;
      break;
    case DepthEncoding::kZlibU16Le: {
      raw.resize(bytes);
      uLongf len = static_cast<uLongf>(bytes);
      const int rc = uncompress(raw.data(), &len, data, static_cast<uLong>(size));
      if (rc != Z_OK || len != bytes) {
        std::ostringstream s;
        s << "zlib depth: inflate failed (zlib code " << rc << ", " << len << " of " << bytes
          << " bytes)";
        return MakeError(ErrorCode::kParse, s.str());
      }
      src = raw.data();
      break;
    }
    case DepthEncoding::kDeltaZlib:
      // The Kinect driver's codec validates the payload and the size itself.
      return kinect::DecodeDepth(encoding, data, size, width, height, out);
    default: {
      std::ostringstream s;
      s << "unknown depth encoding " << static_cast<int>(encoding);
      return MakeError(ErrorCode::kParse, s.str());
    }
  }
  out->resize(n);
  for (size_t i = 0; i < n; ++i)
    (*out)[i] = static_cast<uint16_t>(src[2 * i] | (static_cast<uint16_t>(src[2 * i + 1]) << 8));
  return Status::Ok();
}

}  // namespace omni::octo
