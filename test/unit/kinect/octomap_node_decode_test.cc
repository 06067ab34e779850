// The OctoMap builder's bus path takes DELTA_ZLIB depth from the Kinect codec: a message filled
// by FillDepthMessage comes out of FromDepthMessage pixel-exact, and a damaged one is an error.
#include <vector>

#include <gtest/gtest.h>

#include "omni/kinect/depth_message.h"
#include "omni/octomap_builder/octomap_node.h"

namespace omni::kinect {
namespace {

TEST(DepthMessage, OctomapBuilderDecodesDeltaZlibMessages) {
  const int w = 80, h = 60;
  std::vector<uint16_t> px(static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      px[static_cast<size_t>(y) * w + x] = static_cast<uint16_t>(x == y ? 0 : 2000 + x - y);
  omni::depth_image_t msg{};
  msg.utime = 1;
  msg.frame = "depth_optical";
  msg.fx = 518.0;
  msg.fy = 519.0;
  msg.cx = 39.5;
  msg.cy = 29.5;
  msg.depth_scale = 1000;
  ASSERT_TRUE(FillDepthMessage(px.data(), w, h, DepthEncoding::kDeltaZlib, {}, &msg).ok());
  auto im = octo::FromDepthMessage(msg);
  ASSERT_TRUE(im.ok()) << im.error().message;
  EXPECT_EQ(im->width, w);
  EXPECT_EQ(im->height, h);
  EXPECT_EQ(im->data, px);
  msg.data[msg.data.size() / 2] ^= 0x10;
  EXPECT_FALSE(octo::FromDepthMessage(msg).ok());
}

}  // namespace
}  // namespace omni::kinect
