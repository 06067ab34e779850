#include "omni/octomap_builder/color_image.h"

#include <cmath>
#include <cstring>
#include <sstream>

#include <png.h>

#include "omni/io/image_io.h"

namespace omni::octo {

std::string ColorIntrinsics::Validate() const {
  // The depth intrinsics' bounds (depth_points.h): far outside any camera, and every
  // projection stays finite.
  if (!(std::fabs(fx) >= kMinFocalPx && std::fabs(fx) <= kMaxFocalPx) ||
      !(std::fabs(fy) >= kMinFocalPx && std::fabs(fy) <= kMaxFocalPx))
    return "colour fx and fy must be finite, with magnitudes in [0.001, 1e7] pixels";
  if (!(std::fabs(cx) <= kMaxPrincipalPx) || !(std::fabs(cy) <= kMaxPrincipalPx))
    return "colour cx and cy must be finite and within +-1e6 pixels";
  return "";
}

Status DecodeColorData(int8_t encoding, const uint8_t* data, size_t size, int width, int height,
                       std::vector<uint8_t>* rgb) {
  if (width <= 0 || height <= 0 || width > 16384 || height > 16384) {
    std::ostringstream s;
    s << "colour image size " << width << "x" << height << " is not plausible";
    return MakeError(ErrorCode::kInvalidArgument, s.str());
  }
  const size_t bytes = static_cast<size_t>(width) * height * 3;
  switch (static_cast<ColorEncoding>(encoding)) {
    case ColorEncoding::kRgb8:
      if (size != bytes) {
        std::ostringstream s;
        s << "rgb8 colour: " << size << " bytes, expected " << bytes << " for " << width << "x"
          << height;
        return MakeError(ErrorCode::kParse, s.str());
      }
      rgb->assign(data, data + size);
      return Status::Ok();
    case ColorEncoding::kJpeg: {
      int w = 0, h = 0;
      if (Status s = DecodeJpeg(data, size, &w, &h, rgb); !s.ok()) return s;
      if (w != width || h != height) {
        std::ostringstream s;
        s << "jpeg colour: decoded " << w << "x" << h << ", message says " << width << "x"
          << height;
        return MakeError(ErrorCode::kParse, s.str());
      }
      return Status::Ok();
    }
  }
  std::ostringstream s;
  s << "unknown colour encoding " << static_cast<int>(encoding);
  return MakeError(ErrorCode::kParse, s.str());
}

Status ReadColorPng(const std::string& path, ColorImage* image) {
  // libpng's simplified API converts grey, palette, alpha and 16-bit to 8-bit RGB.
  if (Status s = io::CheckRegularFile(path); !s.ok()) return s;
  png_image png;
  std::memset(&png, 0, sizeof(png));
  png.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&png, path.c_str()))
    return MakeError(ErrorCode::kParse, path + ": " + png.message);
  if (png.width == 0 || png.height == 0 || png.width > 16384 || png.height > 16384) {
    png_image_free(&png);
    return MakeError(ErrorCode::kParse, path + ": implausible PNG size");
  }
  // At least a bit a pixel before 3 bytes a pixel are allocated (69 bytes saying 16384 x 16384
  // took 793 MB to refuse; review 2026-12-06).
  if (Status s = io::CheckCompressedSize(path, static_cast<double>(png.width) * png.height / 8.0,
                                         png.width, png.height);
      !s.ok()) {
    png_image_free(&png);
    return s;
  }
  png.format = PNG_FORMAT_RGB;
  std::vector<uint8_t> rgb(PNG_IMAGE_SIZE(png));
  if (!png_image_finish_read(&png, nullptr, rgb.data(), 0, nullptr)) {
    const std::string msg = png.message;
    png_image_free(&png);
    return MakeError(ErrorCode::kParse, path + ": " + msg);
  }
  image->width = static_cast<int>(png.width);
  image->height = static_cast<int>(png.height);
  image->rgb = std::move(rgb);
  return Status::Ok();
}

Result<ColoredPoints> DepthToColoredPoints(const DepthImage& depth, const ColorImage& color,
                                           const DepthToPointsOptions& options) {
  if (Status s = CheckDepthFrame(depth, options); !s.ok()) return s.error();
  if (color.width <= 0 || color.height <= 0 ||
      color.rgb.size() != static_cast<size_t>(color.width) * color.height * 3) {
    std::ostringstream s;
    s << "colour image " << color.width << "x" << color.height << " has " << color.rgb.size()
      << " bytes, expected 3 per pixel";
    return MakeError(ErrorCode::kInvalidArgument, s.str());
  }
  const DepthIntrinsics& kd = depth.intrinsics;
  const ColorIntrinsics& kc = color.intrinsics;
  const bool same_size = color.width == depth.width && color.height == depth.height;
  const bool same_camera =
      kc.Unset() || (kc.fx == kd.fx && kc.fy == kd.fy && kc.cx == kd.cx && kc.cy == kd.cy);
  ColoredPoints out;
  out.projected = !(same_size && same_camera);
  if (out.projected) {
    if (kc.Unset()) {
      std::ostringstream s;
      s << "colour image " << color.width << "x" << color.height << " differs from depth "
        << depth.width << "x" << depth.height << " and has no intrinsics to register it";
      return MakeError(ErrorCode::kInvalidArgument, s.str());
    }
    if (const std::string bad = kc.Validate(); !bad.empty())
      return MakeError(ErrorCode::kInvalidArgument, bad);
  }
  const int stride = options.pixel_stride;
  const size_t guess = static_cast<size_t>(depth.width / stride + 1) * (depth.height / stride + 1);
  out.points.reserve(guess);
  out.colors.reserve(guess);
  const uint8_t* rgb = color.rgb.data();
  const int cw = color.width, ch = color.height;
  auto add = [&](float x, float y, float z, int cu, int cv) {
    out.points.emplace_back(x, y, z);
    if (cu < 0 || cv < 0 || cu >= cw || cv >= ch) {
      out.colors.push_back(0);
      return;
    }
    const uint8_t* px = rgb + (static_cast<size_t>(cv) * cw + cu) * 3;
    out.colors.push_back(PackRgb(px[0], px[1], px[2]));
    ++out.colored;
  };
  if (!out.projected) {
    ForEachDepthPoint(depth, options,
                      [&](int u, int v, float x, float y, float z) { add(x, y, z, u, v); });
  } else {
    ForEachDepthPoint(depth, options, [&](int, int, float x, float y, float z) {
      // Same optical frame: project with the colour camera's intrinsics.
      const double uc = kc.fx * x / z + kc.cx, vc = kc.fy * y / z + kc.cy;
      const double ru = std::floor(uc + 0.5), rv = std::floor(vc + 0.5);
      const bool inside = ru >= 0 && rv >= 0 && ru < cw && rv < ch;
      add(x, y, z, inside ? static_cast<int>(ru) : -1, inside ? static_cast<int>(rv) : -1);
    });
  }
  return out;
}

}  // namespace omni::octo
