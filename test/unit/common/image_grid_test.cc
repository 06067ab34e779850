#include <fstream>

#include <gtest/gtest.h>

#include "omni/io/grid.h"
#include "omni/io/image_io.h"
#include "test_paths.h"

namespace omni::io {
namespace {

TEST(Image, PgmRoundTrip16Bit) {
  const std::string dir = omni::testing::TempDir();
  Image im = Image::Make(3, 2, 1);
  im.max_value = 65535;
  im.at(0, 0) = 1;
  im.at(2, 1) = 60000;
  ASSERT_TRUE(WritePgm(dir + "/a.pgm", im).ok());
  auto back = ReadPnm(dir + "/a.pgm");
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->pixels, im.pixels);
}

TEST(Image, TruncatedPgmIsAnError) {
  const std::string dir = omni::testing::TempDir();
  { std::ofstream(dir + "/t.pgm", std::ios::binary) << "P5\n4 4\n255\nabc"; }
  auto r = ReadPnm(dir + "/t.pgm");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("truncated"), std::string::npos);
}

TEST(Image, PngHasSignatureAndChunks) {
  const std::string dir = omni::testing::TempDir();
  Image im = Image::Make(4, 4, 3, 128);
  ASSERT_TRUE(WritePng(dir + "/a.png", im).ok());
  std::ifstream f(dir + "/a.png", std::ios::binary);
  std::string all((std::istreambuf_iterator<char>(f)), {});
  ASSERT_GT(all.size(), 40u);
  EXPECT_EQ(all.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));
  EXPECT_EQ(all.substr(12, 4), "IHDR");
  EXPECT_NE(all.find("IDAT"), std::string::npos);
  EXPECT_EQ(all.substr(all.size() - 8, 4), "IEND");
}

TEST(Grid, ScanOfAWallMarksWallOccupiedAndSpaceFree) {
  LogOddsGrid g;
  // A wall at x = 2 m seen by beams from -30 to +30 deg from the origin facing +x.
  std::vector<float> ranges;
  const float inc = static_cast<float>(M_PI / 180);
  for (int i = -30; i <= 30; ++i) ranges.push_back(static_cast<float>(2.0 / std::cos(i * inc)));
  for (int k = 0; k < 3; ++k) g.IntegrateScan(Pose2(0.01, 0.01, 0), ranges, -30 * inc, inc, 30.f);
  const GridMap m = g.ToGridMap();
  auto cell = [&](double x, double y) {
    const int c = static_cast<int>(std::floor((x - m.origin_x_m) / m.resolution_m));
    const int r = static_cast<int>(std::floor((y - m.origin_y_m) / m.resolution_m));
    return m.Contains(c, r) ? m.at(c, r) : int8_t{-1};
  };
  EXPECT_GT(cell(2.01, 0.01), 80);
  EXPECT_LT(cell(1.0, 0.01), 20);
  EXPECT_EQ(cell(1.0, -1.5), -1);   // outside the field of view
  EXPECT_EQ(cell(0.5, -0.45), -1);  // inside the cropped map, outside the field of view
}

TEST(Grid, NanAndNegativeRangesAreIgnored) {
  LogOddsGrid g;
  std::vector<float> ranges{std::nanf(""), -1.f, INFINITY, 0.f};
  EXPECT_EQ(g.IntegrateScan(Pose2(), ranges, 0.f, 0.1f, 30.f), 0);
}

TEST(Grid, MapServerRoundTrip) {
  GridMap m;
  m.resolution_m = 0.1;
  m.origin_x_m = -1.0;
  m.origin_y_m = 2.0;
  m.width = 4;
  m.height = 3;
  m.cells = {-1, 0, 100, 0, 0, 0, 0, 100, -1, -1, 0, 0};
  const std::string dir = omni::testing::TempDir();
  ASSERT_TRUE(WriteMapServer(m, dir + "/map").ok());
  auto back = ReadMapServer(dir + "/map.yaml");
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->cells, m.cells);
  EXPECT_DOUBLE_EQ(back->origin_x_m, -1.0);
  EXPECT_DOUBLE_EQ(back->resolution_m, 0.1);
}

}  // namespace
}  // namespace omni::io
