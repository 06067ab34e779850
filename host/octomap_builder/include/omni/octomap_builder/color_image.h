// Colour frames of an RGB-D camera and their registration to the depth image, for the
// ColorOcTree (colour per occupied voxel).
//
// Registration rule. A depth pixel's point (eq. 6-8, depth optical frame) takes the colour of
//  - the colour pixel at the same (u, v) when the colour image has the depth image's size and
//    either carries no intrinsics (all zero: "registered, same camera") or the same ones;
//  - otherwise the colour pixel its point projects to with the colour camera's intrinsics,
//      u_c = fx_c * x / z + cx_c,  v_c = fy_c * y / z + cy_c   (rounded to the nearest pixel),
//    assuming the colour camera has the SAME optical frame as the depth camera (depth
//    registered to colour, or a baseline small enough to ignore: a Kinect v1's 2.5 cm shifts
//    colours by about one 5 cm voxel at most). Points projecting outside the colour image stay
//    uncoloured (still inserted for occupancy).
// A colour image of another size without intrinsics cannot be registered: an error.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omni/common/result.h"
#include "omni/octomap_builder/depth_points.h"

namespace omni::octo {

// Pinhole intrinsics of the colour camera, pixels. All zero: unknown (same as depth's).
struct ColorIntrinsics {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  bool Unset() const { return fx == 0 && fy == 0 && cx == 0 && cy == 0; }
  // "" when usable for projection, else the violated constraint.
  std::string Validate() const;
};

// A decoded colour frame: row-major R, G, B bytes, row 0 at the top.
struct ColorImage {
  int64_t utime = 0;  // exposure time, microseconds since the Unix epoch
  int width = 0;
  int height = 0;
  ColorIntrinsics intrinsics;
  std::vector<uint8_t> rgb;  // 3 * width * height bytes
};

// Encodings of omni.color_image_t (the .lcm constants).
enum class ColorEncoding : int8_t { kRgb8 = 0, kJpeg = 1 };

// Decodes the `data` of a colour message into 3 * width * height bytes. RGB8 must have exactly
// that many bytes; a JPEG must decode to a width x height image (grey JPEGs are widened to RGB).
// Anything else (unknown encoding, wrong byte count, corrupt JPEG, other size) is an error.
Status DecodeColorData(int8_t encoding, const uint8_t* data, size_t size, int width, int height,
                       std::vector<uint8_t>* rgb);

// JPEG codec (libjpeg; its headers stay inside jpeg_codec.cc). Decode fails on corrupt or
// truncated data; the output is RGB. Without libjpeg at build time JpegAvailable() is false
// and both return an error saying so.
bool JpegAvailable();
Status DecodeJpeg(const uint8_t* data, size_t size, int* width, int* height,
                  std::vector<uint8_t>* rgb);
// Encodes RGB bytes (3 * width * height) at `quality` 1..100.
Result<std::vector<uint8_t>> EncodeJpeg(const std::vector<uint8_t>& rgb, int width, int height,
                                        int quality);

// Reads an 8-bit RGB, RGBA (alpha dropped) or grey (widened) PNG.
Status ReadColorPng(const std::string& path, ColorImage* image);

// Colour of a point: 0x00RRGGBB | kHasColor, or 0 when the point has none.
constexpr uint32_t kHasColor = 1u << 24;
inline uint32_t PackRgb(uint8_t r, uint8_t g, uint8_t b) {
  return kHasColor | (uint32_t{r} << 16) | (uint32_t{g} << 8) | b;
}

struct ColoredPoints {
  std::vector<Eigen::Vector3f> points;  // camera optical frame, metres (as DepthToPoints)
  std::vector<uint32_t> colors;         // one per point: PackRgb(...) or 0 (no colour)
  size_t colored = 0;                   // points with a colour
  bool projected = false;               // true: registered by projection, false: same pixel
};

// DepthToPoints plus each point's colour by the registration rule above. Fails when the depth
// frame is unusable (as DepthToPoints) or the colour image is (size and byte count disagree,
// or another size without intrinsics).
Result<ColoredPoints> DepthToColoredPoints(const DepthImage& depth, const ColorImage& color,
                                           const DepthToPointsOptions& options);

}  // namespace omni::octo
