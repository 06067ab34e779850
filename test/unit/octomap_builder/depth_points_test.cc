#include <zlib.h>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "omni/kinect/depth_codec.h"
#include "omni/octomap_builder/color_image.h"
#include "omni/octomap_builder/depth_io.h"
#include "omni/octomap_builder/depth_points.h"

namespace omni::octo {
namespace {

DepthIntrinsics Kinect() { return {518.0, 519.0, 325.5, 253.5, 1000.0}; }

TEST(DepthPoints, Eq6To8HandValues) {
  const DepthIntrinsics k = Kinect();
  // d = 2000 mm at (u, v) = (425.5, 153.5): z = 2, x = 100 * 2 / 518, y = -100 * 2 / 519.
  const Eigen::Vector3d p = PixelToPoint(425.5, 153.5, 2000, k);
  EXPECT_DOUBLE_EQ(p.z(), 2.0);
  EXPECT_NEAR(p.x(), 0.386100386, 1e-9);
  EXPECT_NEAR(p.y(), -0.385356455, 1e-9);
  // At the principal point the ray is the optical axis.
  const Eigen::Vector3d c = PixelToPoint(325.5, 253.5, 1234, k);
  EXPECT_DOUBLE_EQ(c.x(), 0.0);
  EXPECT_DOUBLE_EQ(c.y(), 0.0);
  EXPECT_DOUBLE_EQ(c.z(), 1.234);
  // A negative fy (ICL-NUIM) flips y.
  const Eigen::Vector3d f = PixelToPoint(319.5, 0, 5000, {481.2, -480.0, 319.5, 239.5, 5000});
  EXPECT_DOUBLE_EQ(f.z(), 1.0);
  EXPECT_NEAR(f.y(), 239.5 / 480.0, 1e-12);
}

TEST(DepthPoints, SkipsInvalidAndOutOfRangeAndHonoursStride) {
  DepthImage im;
  im.width = 4;
  im.height = 2;
  im.intrinsics = {100, 100, 1.5, 0.5, 1000};
  im.data = {0,    500, 1000, 9000,  // 0: invalid; 0.5 m < min; 1 m ok; 9 m > max
             2000, 0,   3000, 65535};
  DepthToPointsOptions o;
  o.min_depth_m = 0.6;
  o.max_depth_m = 8.0;
  auto pts = DepthToPoints(im, o);
  ASSERT_TRUE(pts.ok());
  ASSERT_EQ(pts->size(), 3u);
  EXPECT_FLOAT_EQ((*pts)[0].z(), 1.0f);
  EXPECT_FLOAT_EQ((*pts)[1].z(), 2.0f);
  EXPECT_FLOAT_EQ((*pts)[1].x(), -1.5f * 2.0f / 100.0f);
  EXPECT_FLOAT_EQ((*pts)[2].z(), 3.0f);
  o.pixel_stride = 2;  // pixels (0,0) and (2,0): row 1 is skipped too
  pts = DepthToPoints(im, o);
  ASSERT_TRUE(pts.ok());
  ASSERT_EQ(pts->size(), 1u);
  EXPECT_FLOAT_EQ((*pts)[0].z(), 1.0f);
}

TEST(DepthPoints, RejectsBadInput) {
  DepthImage im;
  im.width = 2;
  im.height = 2;
  im.data = {1, 2, 3};
  im.intrinsics = Kinect();
  EXPECT_FALSE(DepthToPoints(im, {}).ok());  // size mismatch
  im.data.push_back(4);
  im.intrinsics.depth_scale = 0;
  auto r = DepthToPoints(im, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("depth_scale"), std::string::npos);
}

TEST(DepthPoints, VoxelDownsampleKeepsCentroids) {
  std::vector<Eigen::Vector3f> pts = {
      {0.01f, 0.01f, 0.01f}, {0.03f, 0.03f, 0.03f}, {0.5f, 0, 0}, {-0.01f, 0, 0}};
  auto out = VoxelDownsample(pts, 0.1);
  ASSERT_EQ(out.size(), 3u);  // the first two share a voxel; -0.01 is in the voxel below 0
  EXPECT_NEAR(out[0].x(), 0.02f, 1e-6);
  EXPECT_NEAR(out[1].x(), 0.5f, 1e-6);
  EXPECT_NEAR(out[2].x(), -0.01f, 1e-6);
}

TEST(DepthDecode, RawZlibAndDeltaZlibRoundTrip) {
  const int w = 3, h = 2;
  std::vector<uint16_t> values = {0, 1, 256, 1000, 65535, 42};
  std::vector<uint8_t> raw;
  for (uint16_t v : values) {
    raw.push_back(static_cast<uint8_t>(v & 0xff));
    raw.push_back(static_cast<uint8_t>(v >> 8));
  }
  std::vector<uint16_t> out;
  ASSERT_TRUE(DecodeDepthData(0, raw.data(), raw.size(), w, h, &out).ok());
  EXPECT_EQ(out, values);
  std::vector<uint8_t> z(compressBound(raw.size()));
  uLongf zlen = z.size();
  ASSERT_EQ(compress(z.data(), &zlen, raw.data(), raw.size()), Z_OK);
  out.clear();
  ASSERT_TRUE(DecodeDepthData(1, z.data(), zlen, w, h, &out).ok());
  EXPECT_EQ(out, values);
  // DELTA_ZLIB goes through the Kinect driver's codec.
  std::vector<uint8_t> delta;
  ASSERT_TRUE(
      kinect::EncodeDepth(kinect::DepthEncoding::kDeltaZlib, values.data(), w, h, {}, &delta).ok());
  out.clear();
  ASSERT_TRUE(DecodeDepthData(2, delta.data(), delta.size(), w, h, &out).ok());
  EXPECT_EQ(out, values);
  // Truncated zlib, wrong raw size, plain zlib labelled DELTA_ZLIB, truncated DELTA_ZLIB,
  // DELTA_ZLIB of another size, unknown encoding: errors.
  EXPECT_FALSE(DecodeDepthData(1, z.data(), zlen / 2, w, h, &out).ok());
  EXPECT_FALSE(DecodeDepthData(0, raw.data(), raw.size() - 1, w, h, &out).ok());
  EXPECT_FALSE(DecodeDepthData(2, z.data(), zlen, w, h, &out).ok());
  EXPECT_FALSE(DecodeDepthData(2, delta.data(), delta.size() - 1, w, h, &out).ok());
  EXPECT_FALSE(DecodeDepthData(2, delta.data(), delta.size(), h, w, &out).ok());
  EXPECT_FALSE(DecodeDepthData(7, raw.data(), raw.size(), w, h, &out).ok());
}

// A header claiming 16384 x 16384 (512 MB once inflated) is refused before anything is
// allocated, whatever the payload; real cameras' sizes pass.
TEST(DepthDecode, RefusesFramesLargerThanAnyDepthCamera) {
  std::vector<uint8_t> z(64, 0);
  std::vector<uint16_t> out;
  const Status s = DecodeDepthData(1, z.data(), z.size(), 16384, 16384, &out);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("not plausible"), std::string::npos) << s.message();
  EXPECT_TRUE(out.empty());
  EXPECT_FALSE(DecodeDepthData(1, z.data(), z.size(), 4096, 2048, &out).ok());
  for (auto [w, h] : {std::pair{640, 480}, {512, 424}, {1024, 1024}, {1280, 720}}) {
    std::vector<uint8_t> raw(static_cast<size_t>(w) * h * 2, 0);
    EXPECT_TRUE(DecodeDepthData(0, raw.data(), raw.size(), w, h, &out).ok()) << w << "x" << h;
  }
}

TEST(DepthIo, Reads16BitBigEndianPgmAndRejectsTruncation) {
  const std::string path = testing::TempDir() + "/octo_depth16.pgm";
  {
    std::ofstream f(path, std::ios::binary);
    f << "P5\n# a comment\n2 1\n65535\n";
    const unsigned char px[] = {0x01, 0x02, 0xff, 0xfe};
    f.write(reinterpret_cast<const char*>(px), 4);
  }
  DepthImage im;
  ASSERT_TRUE(ReadDepthFile(path, &im).ok());
  ASSERT_EQ(im.width, 2);
  ASSERT_EQ(im.height, 1);
  EXPECT_EQ(im.data[0], 0x0102);
  EXPECT_EQ(im.data[1], 0xfffe);
  std::filesystem::resize_file(path, std::filesystem::file_size(path) - 1);
  EXPECT_FALSE(ReadDepthFile(path, &im).ok());
  EXPECT_FALSE(ReadDepthFile(testing::TempDir() + "/missing.png", &im).ok());
}

// A corrupt PNG is an error that carries libpng's reason and prints nothing (libpng's own
// handler wrote "libpng error: ..." on stderr); a header claiming far more than the file can
// hold (16384 x 16384 x 16 bit, 512 MB, in a 100-byte file) is refused before it is allocated.
TEST(DepthIo, ACorruptOrOversizedPngIsAnErrorThatSaysWhyQuietly) {
  const std::string path = testing::TempDir() + "/octo_small.png";
  std::vector<uint8_t> px(8 * 6);
  for (size_t i = 0; i < px.size(); ++i) px[i] = static_cast<uint8_t>(i * 5);
  ASSERT_TRUE(WritePng8(path, 8, 6, 1, px).ok());
  std::string bytes;
  {
    std::ifstream f(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(f), {});
  }
  DepthImage im;
  ASSERT_TRUE(ReadDepthFile(path, &im).ok());
  EXPECT_EQ(im.data[7], 35);
  // Damage the compressed data (the IDAT chunk's body).
  std::string damaged = bytes;
  const size_t idat = damaged.find("IDAT");
  ASSERT_NE(idat, std::string::npos);
  for (size_t i = idat + 6; i < idat + 12 && i < damaged.size(); ++i) damaged[i] ^= 0x5a;
  std::ofstream(path, std::ios::binary | std::ios::trunc) << damaged;
  ::testing::internal::CaptureStderr();
  const Status s = ReadDepthFile(path, &im);
  const std::string printed = ::testing::internal::GetCapturedStderr();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("corrupt PNG data ("), std::string::npos) << s.message();
  EXPECT_EQ(printed, "");
  // IHDR (at byte 8: length, "IHDR", 13 bytes, CRC) rewritten to 16384 x 16384, 16-bit grey.
  std::string huge = bytes;
  const unsigned char ihdr[13] = {0, 0, 0x40, 0, 0, 0, 0x40, 0, 16, 0, 0, 0, 0};
  huge.replace(16, 13, reinterpret_cast<const char*>(ihdr), 13);
  const uLong crc = crc32(0, reinterpret_cast<const Bytef*>(huge.data() + 12), 17);
  for (int k = 0; k < 4; ++k) huge[29 + k] = static_cast<char>((crc >> (24 - 8 * k)) & 0xff);
  std::ofstream(path, std::ios::binary | std::ios::trunc) << huge;
  const Status big = ReadDepthFile(path, &im);
  ASSERT_FALSE(big.ok());
  EXPECT_NE(big.message().find("cannot hold a 16384 x 16384 image"), std::string::npos)
      << big.message();
  // The colour reader the same (it took 793 MB to refuse such a file).
  ColorImage color;
  const Status big_color = ReadColorPng(path, &color);
  ASSERT_FALSE(big_color.ok());
  EXPECT_NE(big_color.message().find("cannot hold a 16384 x 16384 image"), std::string::npos)
      << big_color.message();
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
  ASSERT_TRUE(ReadColorPng(path, &color).ok());
  EXPECT_EQ(color.width, 8);
  EXPECT_EQ(color.rgb.size(), 8u * 6u * 3u);
}

TEST(DepthIo, ReadsDatasetFramesWithDocumentedRanges) {
  const std::string icl = std::string(OMNI_DATASETS_DIR) + "/rgbd/iclnuim-5frames/depth/1.png";
  const std::string kin = std::string(OMNI_DATASETS_DIR) + "/rgbd/kinect-5frames/depth/1.pgm";
  if (!std::filesystem::exists(icl) || !std::filesystem::exists(kin))
    GTEST_SKIP() << "dataset rgbd/ absent";
  DepthImage a, b;
  ASSERT_TRUE(ReadDepthFile(icl, &a).ok());
  ASSERT_TRUE(ReadDepthFile(kin, &b).ok());
  ASSERT_EQ(a.width, 640);
  ASSERT_EQ(a.height, 480);
  ASSERT_EQ(b.width, 640);
  // datasets/README + SOURCE.md: ICL frame 1 every pixel valid, 8215..17160; Kinect frame 1
  // 209,236 non-zero pixels, 946..9823.
  uint16_t amin = 65535, amax = 0, bmin = 65535, bmax = 0;
  size_t bvalid = 0;
  for (uint16_t v : a.data) amin = std::min(amin, v), amax = std::max(amax, v);
  for (uint16_t v : b.data)
    if (v) ++bvalid, bmin = std::min(bmin, v), bmax = std::max(bmax, v);
  EXPECT_EQ(amin, 8215);
  EXPECT_EQ(amax, 17160);
  EXPECT_EQ(bvalid, 209236u);
  EXPECT_EQ(bmin, 946);
  EXPECT_EQ(bmax, 9823);
  auto poses = ReadPoseFile(std::string(OMNI_DATASETS_DIR) + "/rgbd/kinect-5frames/pose.txt");
  ASSERT_TRUE(poses.ok());
  EXPECT_EQ(poses->size(), 5u);
}

}  // namespace
}  // namespace omni::octo
