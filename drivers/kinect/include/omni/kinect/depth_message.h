// omni.depth_image_t <-> pixels through the depth codec. Separate from depth_codec.h so the
// codec itself stays free of the LCM-generated types.
#pragma once

#include <cstdint>
#include <vector>

#include "omni/common/result.h"
#include "omni/depth_image_t.hpp"
#include "omni/kinect/depth_codec.h"

namespace omni::kinect {

// Encodes width*height pixels into msg->data and sets width, height, encoding,
// uncompressed_size and size. The other fields (time, seq, frame, intrinsics) are the caller's.
Status FillDepthMessage(const uint16_t* pixels, int width, int height, DepthEncoding encoding,
                        const DepthEncodeOptions& options, omni::depth_image_t* msg);

// Checks the message's own bookkeeping (size == data.size(), uncompressed_size ==
// width*height*2) and decodes its data into width*height pixels.
Status ReadDepthMessage(const omni::depth_image_t& msg, std::vector<uint16_t>* out);

}  // namespace omni::kinect
