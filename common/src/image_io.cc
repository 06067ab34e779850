#include "omni/io/image_io.h"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <fstream>
#include <sstream>

#include <zlib.h>

namespace omni::io {
namespace {

Status RenameInto(const std::string& tmp, const std::string& path) {
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    return MakeError(ErrorCode::kIo, "cannot rename '" + tmp + "' to '" + path + "'");
  return Status::Ok();
}

// Reads one header token of a Netpbm file, skipping whitespace and comments.
bool HeaderToken(std::istream& in, std::string* tok) {
  tok->clear();
  int c;
  while ((c = in.get()) != EOF) {
    if (c == '#') {
      while ((c = in.get()) != EOF && c != '\n') {
      }
      continue;
    }
    if (!std::isspace(c)) break;
  }
  if (c == EOF) return false;
  do {
    tok->push_back(static_cast<char>(c));
  } while ((c = in.peek()) != EOF && !std::isspace(c) && in.get());
  return true;
}

void PutU32(std::string* s, uint32_t v) {
  for (int i = 3; i >= 0; --i) s->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

void PngChunk(std::string* out, const char* type, const std::string& data) {
  PutU32(out, static_cast<uint32_t>(data.size()));
  std::string body(type, 4);
  body += data;
  out->append(body);
  PutU32(out, static_cast<uint32_t>(crc32(0, reinterpret_cast<const Bytef*>(body.data()),
                                          static_cast<uInt>(body.size()))));
}

}  // namespace

Result<Image> ReadPnm(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return MakeError(ErrorCode::kNotFound, "cannot open image '" + path + "'");
  std::string magic, w, h, maxv;
  if (!HeaderToken(in, &magic) || (magic != "P5" && magic != "P6") || !HeaderToken(in, &w) ||
      !HeaderToken(in, &h) || !HeaderToken(in, &maxv)) {
    return MakeError(ErrorCode::kParse, path + ": not a binary PGM/PPM (P5/P6) file");
  }
  in.get();  // the single whitespace after maxval
  Image im;
  try {
    im.width = std::stoi(w);
    im.height = std::stoi(h);
    im.max_value = std::stoi(maxv);
  } catch (...) {
    return MakeError(ErrorCode::kParse, path + ": bad size or maxval in header");
  }
  if (im.width <= 0 || im.height <= 0 || im.width > 100000 || im.height > 100000 ||
      im.max_value <= 0 || im.max_value > 65535)
    return MakeError(ErrorCode::kParse, path + ": size or maxval out of range");
  im.channels = magic == "P6" ? 3 : 1;
  const size_t n = static_cast<size_t>(im.width) * im.height * im.channels;
  const int bytes = im.max_value > 255 ? 2 : 1;
  std::vector<uint8_t> raw(n * bytes);
  in.read(reinterpret_cast<char*>(raw.data()), static_cast<std::streamsize>(raw.size()));
  if (static_cast<size_t>(in.gcount()) != raw.size())
    return MakeError(ErrorCode::kParse, path + ": pixel data truncated (" +
                                            std::to_string(in.gcount()) + " of " +
                                            std::to_string(raw.size()) + " bytes)");
  im.pixels.resize(n);
  for (size_t i = 0; i < n; ++i)
    im.pixels[i] = bytes == 2 ? static_cast<uint16_t>(raw[2 * i] << 8 | raw[2 * i + 1]) : raw[i];
  return im;
}

Status WritePgm(const std::string& path, const Image& im) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) return MakeError(ErrorCode::kIo, "cannot write '" + tmp + "'");
    out << (im.channels == 3 ? "P6" : "P5") << '\n'
        << im.width << ' ' << im.height << '\n'
        << im.max_value << '\n';
    const bool wide = im.max_value > 255;
    std::string buf;
    buf.reserve(im.pixels.size() * (wide ? 2 : 1));
    for (uint16_t v : im.pixels) {
      if (wide) buf.push_back(static_cast<char>(v >> 8));
      buf.push_back(static_cast<char>(v & 0xff));
    }
    out.write(buf.data(), static_cast<std::streamsize>(buf.size()));
    if (!out) return MakeError(ErrorCode::kIo, "write to '" + tmp + "' failed");
  }
  return RenameInto(tmp, path);
}

Status WritePng(const std::string& path, const Image& im) {
  if (im.channels != 1 && im.channels != 3)
    return MakeError(ErrorCode::kInvalidArgument, "PNG writer supports 1 or 3 channels");
  std::string raw;
  raw.reserve(static_cast<size_t>(im.height) * (1 + static_cast<size_t>(im.width) * im.channels));
  size_t i = 0;
  for (int y = 0; y < im.height; ++y) {
    raw.push_back(0);  // filter: none
    for (int x = 0; x < im.width * im.channels; ++x)
      raw.push_back(static_cast<char>(std::min<uint16_t>(im.pixels[i++], 255)));
  }
  uLongf zlen = compressBound(static_cast<uLong>(raw.size()));
  std::string z(zlen, '\0');
  if (compress2(reinterpret_cast<Bytef*>(z.data()), &zlen,
                reinterpret_cast<const Bytef*>(raw.data()), static_cast<uLong>(raw.size()),
                6) != Z_OK)
    return MakeError(ErrorCode::kInternal, "zlib compression failed for '" + path + "'");
  z.resize(zlen);
  std::string png("\x89PNG\r\n\x1a\n", 8);
  std::string ihdr;
  PutU32(&ihdr, static_cast<uint32_t>(im.width));
  PutU32(&ihdr, static_cast<uint32_t>(im.height));
  ihdr.push_back(8);                                            // bit depth
  ihdr.push_back(static_cast<char>(im.channels == 3 ? 2 : 0));  // colour type
  ihdr.append(3, '\0');                                         // compression, filter, interlace
  PngChunk(&png, "IHDR", ihdr);
  PngChunk(&png, "IDAT", z);
  PngChunk(&png, "IEND", "");
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) return MakeError(ErrorCode::kIo, "cannot write '" + tmp + "'");
    out.write(png.data(), static_cast<std::streamsize>(png.size()));
    if (!out) return MakeError(ErrorCode::kIo, "write to '" + tmp + "' failed");
  }
  return RenameInto(tmp, path);
}

}  // namespace omni::io
