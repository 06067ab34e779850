#include "omni/io/image_io.h"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

#include <zlib.h>

namespace omni::io {
namespace {

Status RenameInto(const std::string& tmp, const std::string& path) {
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    return MakeError(ErrorCode::kIo, "cannot rename '" + tmp + "' to '" + path + "'");
  return Status::Ok();
}

// Reads one header token of a Netpbm file, skipping whitespace and comments. A token longer
// than any magic or number is not a header (a binary file, or a device that never ends).
bool HeaderToken(std::istream& in, std::string* tok) {
  constexpr size_t kMaxToken = 16;
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
    if (tok->size() == kMaxToken) return false;
    tok->push_back(static_cast<char>(c));
  } while ((c = in.peek()) != EOF && !std::isspace(c) && in.get());
  return true;
}

void PutU32(std::string* s, uint32_t v) {
  for (int i = 3; i >= 0; --i) s->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

}  // namespace

Status CheckRegularFile(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::exists(path, ec) && !std::filesystem::is_regular_file(path, ec))
    return MakeError(ErrorCode::kInvalidArgument, "image '" + path + "' is not a regular file");
  return Status::Ok();
}

Status CheckCompressedSize(const std::string& path, double raw_bytes, int64_t width,
                           int64_t height) {
  std::error_code ec;
  const auto file_bytes = std::filesystem::file_size(path, ec);
  if (ec || raw_bytes <= 1100.0 * static_cast<double>(file_bytes) + 65536) return Status::Ok();
  return MakeError(ErrorCode::kParse, path + ": " + std::to_string(file_bytes) +
                                          " bytes cannot hold a " + std::to_string(width) + " x " +
                                          std::to_string(height) + " image");
}

Result<Image> ReadPnm(const std::string& path, int max_side) {
  if (Status s = CheckRegularFile(path); !s.ok()) return s.error();
  std::ifstream in(path, std::ios::binary);
  if (!in) return MakeError(ErrorCode::kNotFound, "cannot open image '" + path + "'");
  std::string magic, w, h, maxv;
  if (!HeaderToken(in, &magic) || (magic != "P5" && magic != "P6") || !HeaderToken(in, &w) ||
      !HeaderToken(in, &h) || !HeaderToken(in, &maxv)) {
    return MakeError(ErrorCode::kParse, path + ": not a binary PGM/PPM (P5/P6) file");
  }
  in.get();  // the single whitespace after maxval
  Image im;
  // Netpbm numbers are plain decimal digits; "12abc", "-3" or "0x10" are not a size.
  auto number = [](const std::string& t, int* v) {
    if (t.empty() || t.size() > 9 ||
        !std::all_of(t.begin(), t.end(), [](char c) { return c >= '0' && c <= '9'; }))
      return false;
    *v = std::stoi(t);
    return true;
  };
  if (!number(w, &im.width) || !number(h, &im.height) || !number(maxv, &im.max_value))
    return MakeError(ErrorCode::kParse, path + ": bad size or maxval in header ('" + w + "' '" + h +
                                            "' '" + maxv + "')");
  if (im.width <= 0 || im.height <= 0 || im.width > max_side || im.height > max_side ||
      im.max_value <= 0 || im.max_value > 65535)
    return MakeError(ErrorCode::kParse, path + ": size " + w + " x " + h + " or maxval " + maxv +
                                            " out of range (sides 1 to " +
                                            std::to_string(max_side) + ", maxval 1 to 65535)");
  im.channels = magic == "P6" ? 3 : 1;
  const size_t n = static_cast<size_t>(im.width) * im.height * im.channels;
  const int bytes = im.max_value > 255 ? 2 : 1;
  // The header's size is only a claim: read the samples in chunks, so that a short file with a
  // huge header costs what the file holds, not what it claims.
  const size_t want = n * bytes;
  std::vector<uint8_t> raw;
  constexpr size_t kChunk = size_t{1} << 20;
  while (raw.size() < want && in) {
    const size_t have = raw.size();
    raw.resize(have + std::min(kChunk, want - have));
    in.read(reinterpret_cast<char*>(raw.data() + have),
            static_cast<std::streamsize>(raw.size() - have));
    raw.resize(have + static_cast<size_t>(in.gcount()));
  }
  if (raw.size() != want)
    return MakeError(ErrorCode::kParse, path + ": pixel data truncated (" +
                                            std::to_string(raw.size()) + " of " +
                                            std::to_string(want) + " bytes)");
  im.pixels.resize(n);
  for (size_t i = 0; i < n; ++i) {
    im.pixels[i] = bytes == 2 ? static_cast<uint16_t>(raw[2 * i] << 8 | raw[2 * i + 1]) : raw[i];
    if (im.pixels[i] > im.max_value) {
      const size_t px = i / static_cast<size_t>(im.channels);
      return MakeError(ErrorCode::kParse,
                       path + ": sample " + std::to_string(im.pixels[i]) + " at pixel (" +
                           std::to_string(px % static_cast<size_t>(im.width)) + ", " +
                           std::to_string(px / static_cast<size_t>(im.width)) +
                           ") is above the maxval " + std::to_string(im.max_value));
    }
  }
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
  // Streamed: one row at a time through zlib into IDAT chunks of up to 64 KiB, so the memory
  // needed is a row and a chunk, not two more copies of the image (a 20 M-cell map drawn at 2x
  // took about 0.5 GB in those copies).
  const std::string tmp = path + ".tmp";
  std::ofstream out(tmp, std::ios::binary);
  if (!out) return MakeError(ErrorCode::kIo, "cannot write '" + tmp + "'");
  auto chunk = [&out](const char* type, const unsigned char* data, size_t n) {
    std::string head;
    PutU32(&head, static_cast<uint32_t>(n));
    head.append(type, 4);
    uLong crc = crc32(0, reinterpret_cast<const Bytef*>(type), 4);
    if (n > 0) crc = crc32(crc, data, static_cast<uInt>(n));
    std::string tail;
    PutU32(&tail, static_cast<uint32_t>(crc));
    out.write(head.data(), static_cast<std::streamsize>(head.size()));
    if (n > 0) out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(n));
    out.write(tail.data(), static_cast<std::streamsize>(tail.size()));
  };
  out.write("\x89PNG\r\n\x1a\n", 8);
  std::string ihdr;
  PutU32(&ihdr, static_cast<uint32_t>(im.width));
  PutU32(&ihdr, static_cast<uint32_t>(im.height));
  ihdr.push_back(8);                                            // bit depth
  ihdr.push_back(static_cast<char>(im.channels == 3 ? 2 : 0));  // colour type
  ihdr.append(3, '\0');                                         // compression, filter, interlace
  chunk("IHDR", reinterpret_cast<const unsigned char*>(ihdr.data()), ihdr.size());
  z_stream zs{};
  if (deflateInit(&zs, 6) != Z_OK) {
    out.close();
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    return MakeError(ErrorCode::kInternal, "zlib initialisation failed for '" + path + "'");
  }
  std::vector<unsigned char> row(1 + static_cast<size_t>(im.width) * im.channels);
  std::vector<unsigned char> buf(size_t{1} << 16);
  // Feeds `n` bytes (none with finish) and writes every full or final output buffer as IDAT.
  auto feed = [&](unsigned char* data, size_t n, bool finish) {
    zs.next_in = data;
    zs.avail_in = static_cast<uInt>(n);
    for (;;) {
      zs.next_out = buf.data();
      zs.avail_out = static_cast<uInt>(buf.size());
      const int r = deflate(&zs, finish ? Z_FINISH : Z_NO_FLUSH);
      if (r == Z_STREAM_ERROR) return false;
      const size_t got = buf.size() - zs.avail_out;
      if (got > 0) chunk("IDAT", buf.data(), got);
      if (finish ? r == Z_STREAM_END : zs.avail_in == 0 && zs.avail_out > 0) return true;
    }
  };
  bool ok = true;
  size_t i = 0;
  for (int y = 0; ok && y < im.height; ++y) {
    row[0] = 0;  // filter: none
    for (size_t x = 1; x < row.size(); ++x)
      row[x] = static_cast<unsigned char>(std::min<uint16_t>(im.pixels[i++], 255));
    ok = feed(row.data(), row.size(), false);
  }
  ok = ok && feed(nullptr, 0, true);
  deflateEnd(&zs);
  if (ok) chunk("IEND", nullptr, 0);
  out.close();
  if (!ok || !out) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);  // no half-written file left behind
    return ok ? MakeError(ErrorCode::kIo, "write to '" + tmp + "' failed")
              : MakeError(ErrorCode::kInternal, "zlib compression failed for '" + path + "'");
  }
  return RenameInto(tmp, path);
}

}  // namespace omni::io
