#include "omni/octomap_builder/depth_io.h"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <sstream>
#include <utility>

#include <png.h>
#include <unistd.h>

#include "omni/io/image_io.h"

namespace omni::octo {
namespace {

Error IoError(const std::string& what, const std::string& path) {
  return MakeError(ErrorCode::kIo, what + " " + path + ": " + std::strerror(errno));
}

struct FileCloser {
  void operator()(FILE* f) const {
    if (f) std::fclose(f);
  }
};
using File = std::unique_ptr<FILE, FileCloser>;

// libpng's errors and warnings go to the Status, not to stderr (its default handlers print
// "libpng error: ..." for every corrupt file).
struct PngMessages {
  std::string error;
};
[[noreturn]] void PngError(png_structp png, png_const_charp message) {
  if (auto* m = static_cast<PngMessages*>(png_get_error_ptr(png))) m->error = message;
  png_longjmp(png, 1);
}
void PngWarning(png_structp, png_const_charp) {}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

Status ReadDepthPng(const std::string& path, DepthImage* image) {
  if (Status s = io::CheckRegularFile(path); !s.ok()) return s;
  File f(std::fopen(path.c_str(), "rb"));
  if (!f) return IoError("cannot open", path);
  uint8_t sig[8];
  if (std::fread(sig, 1, 8, f.get()) != 8 || png_sig_cmp(sig, 0, 8) != 0)
    return MakeError(ErrorCode::kParse, path + ": not a PNG file");
  PngMessages messages;
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &messages, PngError, PngWarning);
  if (!png) return MakeError(ErrorCode::kInternal, "png_create_read_struct failed");
  png_infop info = png_create_info_struct(png);
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    return MakeError(ErrorCode::kInternal, "png_create_info_struct failed");
  }
  std::vector<uint8_t> buf;
  std::vector<png_bytep> rows;
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return MakeError(ErrorCode::kParse, path + ": corrupt PNG data (" + messages.error + ")");
  }
  png_init_io(png, f.get());
  png_set_sig_bytes(png, 8);
  png_read_info(png, info);
  const png_uint_32 w = png_get_image_width(png, info);
  const png_uint_32 h = png_get_image_height(png, info);
  const int depth = png_get_bit_depth(png, info);
  const int color = png_get_color_type(png, info);
  if (color != PNG_COLOR_TYPE_GRAY || (depth != 16 && depth != 8) || w == 0 || h == 0 ||
      w > 16384 || h > 16384) {
    png_destroy_read_struct(&png, &info, nullptr);
    std::ostringstream s;
    s << path << ": expected a greyscale 8- or 16-bit PNG (color type " << color << ", bit depth "
      << depth << ")";
    return MakeError(ErrorCode::kParse, s.str());
  }
  if (depth == 16) png_set_swap(png);  // PNG is big-endian; we want host order
  png_read_update_info(png, info);
  const size_t rowbytes = png_get_rowbytes(png, info);
  // A 100-byte file saying 16384 x 16384 x 16 bit is not 512 MB.
  if (Status s = io::CheckCompressedSize(path, static_cast<double>(rowbytes) * h, w, h); !s.ok()) {
    png_destroy_read_struct(&png, &info, nullptr);
    return s;
  }
  buf.resize(rowbytes * h);
  rows.resize(h);
  for (png_uint_32 y = 0; y < h; ++y) rows[y] = buf.data() + y * rowbytes;
  png_read_image(png, rows.data());
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  image->width = static_cast<int>(w);
  image->height = static_cast<int>(h);
  image->data.resize(static_cast<size_t>(w) * h);
  for (size_t y = 0; y < h; ++y)
    for (size_t x = 0; x < w; ++x) {
      uint16_t v;
      if (depth == 16)
        std::memcpy(&v, rows[y] + 2 * x, 2);
      else
        v = rows[y][x];
      image->data[y * w + x] = v;
    }
  return Status::Ok();
}

Status ReadDepthPgm(const std::string& path, DepthImage* image) {
  auto pnm = io::ReadPnm(path, 16384);
  if (!pnm.ok()) return pnm.error();
  if (pnm->channels != 1)
    return MakeError(ErrorCode::kParse, path + ": a depth image must be a grey PGM (P5), not PPM");
  image->width = pnm->width;
  image->height = pnm->height;
  image->data = std::move(pnm->pixels);
  return Status::Ok();
}

Status ReadDepthFile(const std::string& path, DepthImage* image) {
  if (EndsWith(path, ".png")) return ReadDepthPng(path, image);
  if (EndsWith(path, ".pgm")) return ReadDepthPgm(path, image);
  return MakeError(ErrorCode::kInvalidArgument, path + ": depth files must be .png or .pgm");
}

Result<std::vector<Eigen::Isometry3d>> ReadPoseFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) return IoError("cannot open", path);
  std::vector<Eigen::Isometry3d> poses;
  std::string line;
  int lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream s(line);
    double tx, ty, tz, qx, qy, qz, qw;
    if (!(s >> tx >> ty >> tz >> qx >> qy >> qz >> qw)) {
      return MakeError(ErrorCode::kParse,
                       path + ":" + std::to_string(lineno) + ": expected \"tx ty tz qx qy qz qw\"");
    }
    Eigen::Quaterniond q(qw, qx, qy, qz);
    if (!(std::abs(q.norm() - 1.0) < 1e-2))
      return MakeError(ErrorCode::kParse,
                       path + ":" + std::to_string(lineno) + ": quaternion is not unit length");
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = q.normalized().toRotationMatrix();
    t.translation() = Eigen::Vector3d(tx, ty, tz);
    poses.push_back(t);
  }
  return poses;
}

Status WritePng8(const std::string& path, int width, int height, int channels,
                 const std::vector<uint8_t>& pixels) {
  if ((channels != 1 && channels != 3) || width <= 0 || height <= 0 ||
      pixels.size() != static_cast<size_t>(width) * height * channels)
    return MakeError(ErrorCode::kInvalidArgument, path + ": bad image size for PNG");
  const std::string tmp = path + ".tmp";
  {
    File f(std::fopen(tmp.c_str(), "wb"));
    if (!f) return IoError("cannot create", tmp);
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    if (!png || !info) {
      png_destroy_write_struct(&png, &info);
      return MakeError(ErrorCode::kInternal, "libpng init failed");
    }
    if (setjmp(png_jmpbuf(png))) {
      png_destroy_write_struct(&png, &info);
      return MakeError(ErrorCode::kIo, "libpng failed writing " + tmp);
    }
    png_init_io(png, f.get());
    png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8,
                 channels == 1 ? PNG_COLOR_TYPE_GRAY : PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int y = 0; y < height; ++y)
      png_write_row(
          png, const_cast<png_bytep>(pixels.data() + static_cast<size_t>(y) * width * channels));
    png_write_end(png, nullptr);
    png_destroy_write_struct(&png, &info);
    if (std::fflush(f.get()) != 0) return IoError("cannot write", tmp);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return IoError("cannot rename to", path);
  return Status::Ok();
}

Status WritePgm8(const std::string& path, int width, int height,
                 const std::vector<uint8_t>& pixels) {
  if (width <= 0 || height <= 0 || pixels.size() != static_cast<size_t>(width) * height)
    return MakeError(ErrorCode::kInvalidArgument, path + ": bad image size for PGM");
  std::string bytes = "P5\n" + std::to_string(width) + " " + std::to_string(height) + "\n255\n";
  bytes.append(reinterpret_cast<const char*>(pixels.data()), pixels.size());
  return WriteFileAtomic(path, bytes);
}

Status WritePcd(const std::string& path, const std::vector<Eigen::Vector3f>& points, bool binary) {
  std::ostringstream s;
  s << "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
    << "TYPE F F F\nCOUNT 1 1 1\nWIDTH " << points.size() << "\nHEIGHT 1\n"
    << "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS " << points.size() << "\nDATA "
    << (binary ? "binary" : "ascii") << "\n";
  std::string bytes = s.str();
  if (binary) {
    for (const auto& p : points) {
      const float xyz[3] = {p.x(), p.y(), p.z()};
      bytes.append(reinterpret_cast<const char*>(xyz), sizeof(xyz));
    }
  } else {
    std::ostringstream body;
    body.precision(7);
    for (const auto& p : points) body << p.x() << " " << p.y() << " " << p.z() << "\n";
    bytes += body.str();
  }
  return WriteFileAtomic(path, bytes);
}

Status WriteFileAtomic(const std::string& path, const std::string& bytes) {
  const std::string tmp = path + ".tmp";
  File f(std::fopen(tmp.c_str(), "wb"));
  if (!f) return IoError("cannot create", tmp);
  if (std::fwrite(bytes.data(), 1, bytes.size(), f.get()) != bytes.size() ||
      std::fflush(f.get()) != 0)
    return IoError("cannot write", tmp);
  if (::fsync(fileno(f.get())) != 0) return IoError("cannot sync", tmp);
  f.reset();
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return IoError("cannot rename to", path);
  return Status::Ok();
}

}  // namespace omni::octo
