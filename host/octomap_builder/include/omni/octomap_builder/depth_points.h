// Depth image to 3D points: paper 002 section III-C, eq. (6)-(8).
//
// A pixel (u, v) (u = column to the right, v = row down) with raw value d > 0 lies in the
// camera optical frame (z forward along the optical axis, x right, y down) at
//   z = d / s                  (6)
//   x = (u - cx) * z / fx      (7)
//   y = (v - cy) * z / fy      (8)
// with s the depth scale in raw units per metre. d = 0 is "no measurement" and is skipped.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omni/common/result.h"

namespace omni::octo {

// Plausibility bounds of camera intrinsics (Validate): far outside any real camera, and they
// keep every back-projected point of a 16-bit depth image finite.
inline constexpr double kMinFocalPx = 1e-3;
inline constexpr double kMaxFocalPx = 1e7;
inline constexpr double kMaxPrincipalPx = 1e6;
inline constexpr double kMinDepthScale = 1e-3;
inline constexpr double kMaxDepthScale = 1e9;

struct DepthIntrinsics {
  double fx = 0;           // focal length along u, pixels (negative flips the axis)
  double fy = 0;           // focal length along v, pixels
  double cx = 0;           // principal point u, pixels
  double cy = 0;           // principal point v, pixels
  double depth_scale = 0;  // raw units per metre (1000: millimetres)
  // "" when usable, else which constraint is violated.
  std::string Validate() const;
};

// A decoded depth frame: row-major uint16 raw values.
struct DepthImage {
  int64_t utime = 0;  // exposure time, microseconds since the Unix epoch
  int width = 0;
  int height = 0;
  DepthIntrinsics intrinsics;
  std::vector<uint16_t> data;  // width * height raw values
  uint16_t at(int u, int v) const { return data[static_cast<size_t>(v) * width + u]; }
};

struct DepthToPointsOptions {
  double min_depth_m = 0.3;  // pixels nearer than this (along z) are skipped
  double max_depth_m = 8.0;  // pixels farther than this (along z) are skipped
  int pixel_stride = 1;      // use every n-th pixel along u and v (1 = all)
};

// Eq. (6)-(8) for one pixel; the point is in the camera optical frame, metres.
inline Eigen::Vector3d PixelToPoint(double u, double v, double d, const DepthIntrinsics& k) {
  const double z = d / k.depth_scale;  // (6)
  return {(u - k.cx) * z / k.fx,       // (7)
          (v - k.cy) * z / k.fy,       // (8)
          z};
}

// All valid pixels of `image` as points in the camera optical frame (float, metres).
// Fails when the intrinsics or options are unusable or the data size does not match.
Result<std::vector<Eigen::Vector3f>> DepthToPoints(const DepthImage& image,
                                                   const DepthToPointsOptions& options);
// The same into `out` (replaced; its storage reused from frame to frame). On failure `out` is
// left empty.
Status DepthToPoints(const DepthImage& image, const DepthToPointsOptions& options,
                     std::vector<Eigen::Vector3f>* out);

// The checks DepthToPoints makes before converting (intrinsics, size, options).
Status CheckDepthFrame(const DepthImage& image, const DepthToPointsOptions& options);

// Calls f(u, v, x, y, z) for every valid pixel in row order (the points DepthToPoints returns,
// in the same order, as floats). Call CheckDepthFrame first.
template <class F>
void ForEachDepthPoint(const DepthImage& image, const DepthToPointsOptions& options, F&& f) {
  const DepthIntrinsics& k = image.intrinsics;
  // Raw limits, so the per-pixel test is an integer compare.
  const double dmin = options.min_depth_m * k.depth_scale;
  const double dmax = options.max_depth_m * k.depth_scale;
  const double inv_s = 1.0 / k.depth_scale;
  const double inv_fx = 1.0 / k.fx, inv_fy = 1.0 / k.fy;
  const int stride = options.pixel_stride;
  for (int v = 0; v < image.height; v += stride) {
    const uint16_t* row = image.data.data() + static_cast<size_t>(v) * image.width;
    const double yf = (v - k.cy) * inv_fy;
    for (int u = 0; u < image.width; u += stride) {
      const uint16_t d = row[u];
      if (d == 0 || d < dmin || d > dmax) continue;
      const double z = d * inv_s;                // (6)
      const double x = (u - k.cx) * z * inv_fx;  // (7)
      const double y = yf * z;                   // (8)
      f(u, v, static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
    }
  }
}

// Voxel-grid filter (like PCL's VoxelGrid): one point per occupied cube of edge `leaf_m`, at
// the centroid of the points inside it. Order of the output follows first appearance.
std::vector<Eigen::Vector3f> VoxelDownsample(const std::vector<Eigen::Vector3f>& points,
                                             double leaf_m);

// Encodings of omni.depth_image_t (the .lcm constants).
enum class DepthEncoding : int8_t { kRawU16Le = 0, kZlibU16Le = 1, kDeltaZlib = 2 };

// Decodes the `data` of a depth message into width*height uint16 values. RAW and ZLIB are
// decoded here; DELTA_ZLIB by the Kinect driver's codec (omni/kinect/depth_codec.h).
Status DecodeDepthData(int8_t encoding, const uint8_t* data, size_t size, int width, int height,
                       std::vector<uint16_t>* out);

}  // namespace omni::octo
