#include "omni/kinect/depth_message.h"

#include <climits>
#include <string>
#include <utility>

namespace omni::kinect {

Status FillDepthMessage(const uint16_t* pixels, int width, int height, DepthEncoding encoding,
                        const DepthEncodeOptions& options, omni::depth_image_t* msg) {
  std::vector<uint8_t> bytes;
  if (Status s = EncodeDepth(encoding, pixels, width, height, options, &bytes); !s.ok()) return s;
  if (bytes.size() > static_cast<size_t>(INT32_MAX)) {
    return MakeError(ErrorCode::kInvalidArgument, "encoded depth image exceeds 2 GiB");
  }
  msg->width = width;
  msg->height = height;
  msg->encoding = static_cast<int8_t>(encoding);
  msg->uncompressed_size = static_cast<int32_t>(static_cast<size_t>(width) * height * 2);
  msg->size = static_cast<int32_t>(bytes.size());
  msg->data = std::move(bytes);
  return Status::Ok();
}

Status ReadDepthMessage(const omni::depth_image_t& msg, std::vector<uint16_t>* out) {
  out->clear();
  if (msg.size < 0 || static_cast<size_t>(msg.size) != msg.data.size()) {
    return MakeError(ErrorCode::kParse, "depth message seq " + std::to_string(msg.seq) +
                                            ": size field " + std::to_string(msg.size) + " but " +
                                            std::to_string(msg.data.size()) + " data bytes");
  }
  if (msg.width > 0 && msg.height > 0 && msg.width <= kMaxDepthSide &&
      msg.height <= kMaxDepthSide &&
      static_cast<int64_t>(msg.uncompressed_size) !=
          static_cast<int64_t>(msg.width) * msg.height * 2) {
    return MakeError(ErrorCode::kParse,
                     "depth message seq " + std::to_string(msg.seq) + ": uncompressed_size " +
                         std::to_string(msg.uncompressed_size) + " is not " +
                         std::to_string(msg.width) + "x" + std::to_string(msg.height) + "x2");
  }
  return DecodeDepth(msg.encoding, msg.data.data(), msg.data.size(), msg.width, msg.height, out);
}

}  // namespace omni::kinect
