// JPEG decoding/encoding with libjpeg(-turbo). The only file that includes jpeglib.h.
// Built without libjpeg (OMNI_HAVE_JPEG unset), both return an error saying so.
//
// libjpeg reports fatal errors through error_exit, which must not return: it longjmps back to
// the call here. Corrupt-data warnings (e.g. "premature end of data segment") only print by
// default and fill the rest with grey; here any warning fails the decode, so a truncated
// frame is an error instead of a half-grey image.
#include "omni/octomap_builder/color_image.h"

#ifdef OMNI_HAVE_JPEG

#include <csetjmp>
#include <cstdio>
#include <cstdlib>
#include <sstream>

// jpeglib.h needs FILE and size_t declared first.
#include <jpeglib.h>

namespace omni::octo {
namespace {

struct ErrorManager {
  jpeg_error_mgr pub;  // first: libjpeg sees a jpeg_error_mgr*
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
};

void OnError(j_common_ptr info) {
  auto* err = reinterpret_cast<ErrorManager*>(info->err);
  (*info->err->format_message)(info, err->message);
  std::longjmp(err->jump, 1);
}

void OnMessage(j_common_ptr info, int level) {
  // level < 0: a warning (corrupt data); count it, print nothing.
  if (level < 0) ++info->err->num_warnings;
}

constexpr int kMaxSide = 16384;

}  // namespace

bool JpegAvailable() { return true; }

Status DecodeJpeg(const uint8_t* data, size_t size, int* width, int* height,
                  std::vector<uint8_t>* rgb) {
  if (size < 4 || data[0] != 0xFF || data[1] != 0xD8)
    return MakeError(ErrorCode::kParse, "jpeg: no SOI marker (not a JPEG file)");
  jpeg_decompress_struct info;
  ErrorManager err;
  info.err = jpeg_std_error(&err.pub);
  err.pub.error_exit = OnError;
  err.pub.emit_message = OnMessage;
  err.message[0] = '\0';
  if (setjmp(err.jump)) {
    jpeg_destroy_decompress(&info);
    return MakeError(ErrorCode::kParse, std::string("jpeg: ") + err.message);
  }
  jpeg_create_decompress(&info);
  jpeg_mem_src(&info, data, static_cast<unsigned long>(size));
  jpeg_read_header(&info, TRUE);
  if (info.image_width == 0 || info.image_height == 0 ||
      info.image_width > static_cast<JDIMENSION>(kMaxSide) ||
      info.image_height > static_cast<JDIMENSION>(kMaxSide)) {
    std::ostringstream s;
    s << "jpeg: implausible size " << info.image_width << "x" << info.image_height;
    jpeg_destroy_decompress(&info);
    return MakeError(ErrorCode::kParse, s.str());
  }
  info.out_color_space = JCS_RGB;  // grey and YCbCr both come out as R G B
  jpeg_start_decompress(&info);
  const size_t w = info.output_width, h = info.output_height;
  rgb->resize(w * h * 3);
  while (info.output_scanline < info.output_height) {
    JSAMPROW row = rgb->data() + static_cast<size_t>(info.output_scanline) * w * 3;
    jpeg_read_scanlines(&info, &row, 1);
  }
  jpeg_finish_decompress(&info);
  const long warnings = info.err->num_warnings;
  jpeg_destroy_decompress(&info);
  if (warnings > 0)
    return MakeError(ErrorCode::kParse,
                     "jpeg: corrupt or truncated data (" + std::to_string(warnings) + " warnings)");
  *width = static_cast<int>(w);
  *height = static_cast<int>(h);
  return Status::Ok();
}

Result<std::vector<uint8_t>> EncodeJpeg(const std::vector<uint8_t>& rgb, int width, int height,
                                        int quality) {
  if (width <= 0 || height <= 0 || width > kMaxSide || height > kMaxSide ||
      rgb.size() != static_cast<size_t>(width) * height * 3 || quality < 1 || quality > 100)
    return MakeError(ErrorCode::kInvalidArgument, "jpeg encode: bad size or quality");
  jpeg_compress_struct info;
  ErrorManager err;
  info.err = jpeg_std_error(&err.pub);
  err.pub.error_exit = OnError;
  err.pub.emit_message = OnMessage;
  unsigned char* out = nullptr;
  unsigned long out_size = 0;
  if (setjmp(err.jump)) {
    jpeg_destroy_compress(&info);
    std::free(out);
    return MakeError(ErrorCode::kInternal, std::string("jpeg encode: ") + err.message);
  }
  jpeg_create_compress(&info);
  jpeg_mem_dest(&info, &out, &out_size);
  info.image_width = static_cast<JDIMENSION>(width);
  info.image_height = static_cast<JDIMENSION>(height);
  info.input_components = 3;
  info.in_color_space = JCS_RGB;
  jpeg_set_defaults(&info);
  jpeg_set_quality(&info, quality, TRUE);
  jpeg_start_compress(&info, TRUE);
  while (info.next_scanline < info.image_height) {
    // libjpeg takes non-const rows; it only reads them.
    JSAMPROW row = const_cast<uint8_t*>(rgb.data()) +
                   static_cast<size_t>(info.next_scanline) * static_cast<size_t>(width) * 3;
    jpeg_write_scanlines(&info, &row, 1);
  }
  jpeg_finish_compress(&info);
  jpeg_destroy_compress(&info);
  std::vector<uint8_t> bytes(out, out + out_size);
  std::free(out);
  return bytes;
}

}  // namespace omni::octo

#else  // no libjpeg

namespace omni::octo {

bool JpegAvailable() { return false; }

Status DecodeJpeg(const uint8_t*, size_t, int*, int*, std::vector<uint8_t>*) {
  return MakeError(ErrorCode::kInvalidArgument,
                   "jpeg: built without libjpeg (install libjpeg-dev and rebuild)");
}

Result<std::vector<uint8_t>> EncodeJpeg(const std::vector<uint8_t>&, int, int, int) {
  return MakeError(ErrorCode::kInvalidArgument,
                   "jpeg: built without libjpeg (install libjpeg-dev and rebuild)");
}

}  // namespace omni::octo

#endif  // OMNI_HAVE_JPEG
