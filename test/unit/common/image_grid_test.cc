#include <sys/stat.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>

#include <gtest/gtest.h>
#include <zlib.h>

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

// The header's size is a claim the bytes must back: a 20-byte file that says 100000 x 100000
// 16-bit RGB is refused by what it holds (it used to be 60 GB asked of the allocator, and an
// abort; 60000 x 60000 grey took 3.5 GB and 20 s to refuse).
TEST(Image, AHugeHeaderOnAShortFileIsRefusedByWhatTheFileHolds) {
  const std::string dir = omni::testing::TempDir();
  { std::ofstream(dir + "/h.ppm", std::ios::binary) << "P6\n100000 100000\n65535\nabc"; }
  auto r = ReadPnm(dir + "/h.ppm");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("truncated (3 of 60000000000 bytes)"), std::string::npos)
      << r.error().message;
  // Beyond the sides the caller allows: refused from the header alone.
  { std::ofstream(dir + "/w.pgm", std::ios::binary) << "P5\n20000 2\n255\n"; }
  auto wide = ReadPnm(dir + "/w.pgm", 16384);
  ASSERT_FALSE(wide.ok());
  EXPECT_NE(wide.error().message.find("out of range"), std::string::npos) << wide.error().message;
}

// Header numbers are decimal digits: what std::stoi would half-read ("4x" as 4, "+4", " -4")
// is an error naming the tokens; a file with no whitespace for its first 16 bytes (a binary
// file, a device) is not read on.
TEST(Image, HeaderNumbersAreDigitsAndTokensAreShort) {
  const std::string dir = omni::testing::TempDir();
  for (const char* header : {"P5\n4x 4\n255\n", "P5\n+4 4\n255\n", "P5\n4 -4\n255\n",
                             "P5\n4 4\n0x10\n", "P5\n4 4\n1e3\n", "P5\n00000000004 4\n255\n"}) {
    { std::ofstream(dir + "/n.pgm", std::ios::binary) << header << std::string(64, 'a'); }
    auto r = ReadPnm(dir + "/n.pgm");
    EXPECT_FALSE(r.ok()) << header;
  }
  { std::ofstream(dir + "/z.pgm", std::ios::binary) << std::string(1 << 16, '\0'); }
  auto zeros = ReadPnm(dir + "/z.pgm");
  ASSERT_FALSE(zeros.ok());
  EXPECT_NE(zeros.error().message.find("not a binary PGM/PPM"), std::string::npos);
  // Comments stay legal anywhere in the header, and a 16-bit grey image reads as before.
  {
    std::ofstream(dir + "/c.pgm", std::ios::binary)
        << "P5 # made by hand\n2 1\n# max\n65535\n\x01\x02\x03\x04";
  }
  auto c = ReadPnm(dir + "/c.pgm");
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(c->pixels, (std::vector<uint16_t>{0x0102, 0x0304}));
}

// A sample above the maxval is a malformed file, named with the pixel; a FIFO or device as the
// image (a map YAML's `image: /dev/stdin`) is refused instead of read until it ends.
TEST(Image, SamplesAboveMaxvalAndNonRegularFilesAreErrors) {
  const std::string dir = omni::testing::TempDir();
  { std::ofstream(dir + "/m.pgm", std::ios::binary) << "P5\n2 1\n200\n\x10\xf0"; }
  auto r = ReadPnm(dir + "/m.pgm");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("sample 240 at pixel (1, 0) is above the maxval 200"),
            std::string::npos)
      << r.error().message;
  const std::string fifo = dir + "/fifo.pgm";
  std::filesystem::remove(fifo);
  ASSERT_EQ(mkfifo(fifo.c_str(), 0600), 0);
  auto f = ReadPnm(fifo);
  ASSERT_FALSE(f.ok());
  EXPECT_NE(f.error().message.find("not a regular file"), std::string::npos);
  std::filesystem::remove(fifo);
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

// The PNG is decoded here with zlib: every chunk's CRC holds, the IDAT chunks (the writer
// streams them, 64 KiB each at most) inflate to the rows, each a filter byte 0 and the pixels.
TEST(Image, PngDecodesToThePixelsWritten) {
  const std::string dir = omni::testing::TempDir();
  Image im = Image::Make(401, 303, 3, 0);
  uint32_t state = 12345;
  for (auto& p : im.pixels) {
    state = state * 1664525u + 1013904223u;
    p = static_cast<uint16_t>(state >> 24);  // noise: compresses poorly, many IDAT chunks
  }
  im.pixels[7] = 300;  // above 255: written as 255
  ASSERT_TRUE(WritePng(dir + "/n.png", im).ok());
  std::ifstream f(dir + "/n.png", std::ios::binary);
  std::string all((std::istreambuf_iterator<char>(f)), {});
  ASSERT_EQ(all.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));
  auto u32 = [&all](size_t at) {
    uint32_t v = 0;
    for (int k = 0; k < 4; ++k) v = (v << 8) | static_cast<unsigned char>(all[at + k]);
    return v;
  };
  std::string idat, last;
  int idat_chunks = 0;
  for (size_t at = 8; at < all.size();) {
    ASSERT_LE(at + 12, all.size());
    const uint32_t n = u32(at);
    ASSERT_LE(at + 12 + n, all.size());
    const std::string type = all.substr(at + 4, 4);
    const uLong crc = crc32(0, reinterpret_cast<const Bytef*>(all.data() + at + 4), n + 4);
    EXPECT_EQ(u32(at + 8 + n), static_cast<uint32_t>(crc)) << type;
    if (type == "IHDR") {
      EXPECT_EQ(u32(at + 8), 401u);
      EXPECT_EQ(u32(at + 12), 303u);
    }
    if (type == "IDAT") {
      idat += all.substr(at + 8, n);
      ++idat_chunks;
    }
    last = type;
    at += 12 + n;
  }
  EXPECT_EQ(last, "IEND");
  EXPECT_GT(idat_chunks, 1);
  const size_t row = 1 + 401 * 3;
  std::string raw(row * 303, '\0');
  uLongf raw_len = static_cast<uLongf>(raw.size());
  ASSERT_EQ(
      uncompress(reinterpret_cast<Bytef*>(raw.data()), &raw_len,
                 reinterpret_cast<const Bytef*>(idat.data()), static_cast<uLong>(idat.size())),
      Z_OK);
  ASSERT_EQ(raw_len, raw.size());
  size_t i = 0;
  for (int y = 0; y < 303; ++y) {
    ASSERT_EQ(raw[y * row], 0);
    for (size_t x = 1; x < row; ++x, ++i)
      ASSERT_EQ(static_cast<unsigned char>(raw[y * row + x]), std::min<uint16_t>(im.pixels[i], 255))
          << y << " " << x;
  }
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

TEST(Grid, AbsurdPosesAreRefusedNotAllocated) {
  LogOddsOptions o;
  o.max_cells = 1 << 20;
  LogOddsGrid g(o);
  std::vector<float> ranges(100, 2.f);
  EXPECT_EQ(g.IntegrateScan(Pose2(), ranges, -0.5f, 0.01f, 30.f), 100);
  const size_t cells = g.allocated_cells();
  EXPECT_EQ(g.IntegrateScan(Pose2(1e4, 0, 0), ranges, -0.5f, 0.01f, 30.f), 0);  // 10 km out
  EXPECT_EQ(g.IntegrateScan(Pose2(1e300, 0, 0), ranges, -0.5f, 0.01f, 30.f), 0);
  EXPECT_EQ(g.IntegrateScan(Pose2(0, -1e18, 0), ranges, -0.5f, 0.01f, 30.f), 0);
  EXPECT_EQ(g.refused_beams(), 300);
  EXPECT_EQ(g.allocated_cells(), cells);
  // Nearby, the grid grows as before, up to the cap.
  EXPECT_EQ(g.IntegrateScan(Pose2(20, 0, 0), ranges, -0.5f, 0.01f, 30.f), 100);
  EXPECT_LE(static_cast<int64_t>(g.allocated_cells()), o.max_cells);
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

// map_server's numbers are checked where they are read: a resolution that is infinite, or
// thresholds that are out of [0, 1] or in the wrong order, name the file.
TEST(Grid, MapServerYamlWithAbsurdNumbersIsAnError) {
  GridMap m;
  m.resolution_m = 0.1;
  m.width = 2;
  m.height = 2;
  m.cells = {-1, 0, 100, 0};
  const std::string dir = omni::testing::TempDir();
  ASSERT_TRUE(WriteMapServer(m, dir + "/map").ok());
  const std::string image = "image: map.pgm\norigin: [0, 0, 0]\n";
  for (const std::string& body :
       {image + "resolution: .inf\n", image + "resolution: .nan\n", image + "resolution: -0.1\n",
        image + "resolution: 0.1\noccupied_thresh: 1.5\n",
        image + "resolution: 0.1\nfree_thresh: 0.7\noccupied_thresh: 0.6\n",
        image + "resolution: 0.1\nfree_thresh: .nan\n",
        std::string("image: map.pgm\nresolution: 0.1\norigin: [.inf, 0, 0]\n"),
        std::string("image: map.pgm\nresolution: 0.1\norigin: 7\n"),
        std::string("resolution: 0.1\norigin: [0, 0, 0]\n")}) {
    { std::ofstream(dir + "/bad.yaml") << body; }
    auto r = ReadMapServer(dir + "/bad.yaml");
    ASSERT_FALSE(r.ok()) << body;
    EXPECT_NE(r.error().message.find(dir + "/bad.yaml"), std::string::npos) << r.error().message;
  }
  {
    std::ofstream(dir + "/good.yaml")
        << image + "resolution: 0.1\nfree_thresh: 0.1\noccupied_thresh: 0.6\n";
  }
  auto good = ReadMapServer(dir + "/good.yaml");
  ASSERT_TRUE(good.ok()) << good.error().message;
  EXPECT_EQ(good->cells, m.cells);
}

// A grid turned by yaw about its origin corner, resampled onto the frame's axes: at a quarter
// and a half turn every cell lands where its centre is in the frame, with its value; at an
// oblique angle a straight wall stays on its line.
TEST(Grid, AxisAlignedPutsATurnedGridWhereItsCellsAre) {
  GridMap m;
  m.resolution_m = 0.1;
  m.origin_x_m = 1.0;
  m.origin_y_m = -2.0;
  m.width = 4;
  m.height = 3;
  m.cells = {-1, 0, 100, 0, 0, 0, 0, 100, -1, -1, 0, 0};
  EXPECT_EQ(AxisAligned(m, 0.0)->cells, m.cells);
  for (const double yaw : {M_PI / 2, M_PI, -M_PI / 2}) {
    const GridMap a = *AxisAligned(m, yaw);
    EXPECT_EQ(static_cast<size_t>(a.width) * a.height, m.cells.size()) << yaw;
    for (int r = 0; r < m.height; ++r)
      for (int c = 0; c < m.width; ++c) {
        const double u = (c + 0.5) * 0.1, v = (r + 0.5) * 0.1;
        const double x = m.origin_x_m + std::cos(yaw) * u - std::sin(yaw) * v;
        const double y = m.origin_y_m + std::sin(yaw) * u + std::cos(yaw) * v;
        const int ac = static_cast<int>(std::floor((x - a.origin_x_m) / 0.1));
        const int ar = static_cast<int>(std::floor((y - a.origin_y_m) / 0.1));
        ASSERT_TRUE(a.Contains(ac, ar)) << yaw;
        EXPECT_EQ(a.at(ac, ar), m.at(c, r)) << "yaw " << yaw << " cell " << c << "," << r;
      }
  }
  // A 4 m wall along the grid's u axis (row 10 of a 5 cm grid), turned by 0.3 rad.
  GridMap w;
  w.resolution_m = 0.05;
  w.width = 80;
  w.height = 21;
  w.cells.assign(80 * 21, 0);
  for (int c = 0; c < 80; ++c) w.at(c, 10) = 100;
  const GridMap a = *AxisAligned(w, 0.3);
  int occupied = 0;
  for (int r = 0; r < a.height; ++r)
    for (int c = 0; c < a.width; ++c) {
      if (a.at(c, r) != 100) continue;
      ++occupied;
      const double x = a.origin_x_m + (c + 0.5) * 0.05, y = a.origin_y_m + (r + 0.5) * 0.05;
      // Distance to the wall's centre line, v = 0.525 m in the grid's axes.
      const double v = -std::sin(0.3) * x + std::cos(0.3) * y;
      EXPECT_NEAR(v, 0.525, 0.05) << c << "," << r;
    }
  EXPECT_GT(occupied, 70);
  EXPECT_LT(occupied, 130);
  // A long thin grid turned 45 degrees would need a huge box: an error, nothing allocated; so
  // are a non-finite turn and resolution.
  GridMap thin;
  thin.resolution_m = 0.05;
  thin.width = 1000000;
  thin.height = 1;
  thin.cells.assign(1000000, 0);
  EXPECT_FALSE(AxisAligned(thin, M_PI / 4).ok());
  EXPECT_TRUE(AxisAligned(thin, M_PI / 2).ok());  // a quarter turn: the same number of cells
  EXPECT_FALSE(AxisAligned(m, std::nan("")).ok());
  GridMap inf = m;
  inf.resolution_m = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(AxisAligned(inf, 0.3).ok());
}

TEST(Grid, MapServerOriginYawIsResampledNotIgnored) {
  const std::string dir = omni::testing::TempDir();
  GridMap m;
  m.resolution_m = 0.1;
  m.width = 4;
  m.height = 3;
  m.cells = {-1, 0, 100, 0, 0, 0, 0, 100, -1, -1, 0, 0};
  ASSERT_TRUE(WriteMapServer(m, dir + "/turned").ok());
  {
    std::ofstream y(dir + "/turned.yaml");
    y << "image: turned.pgm\nresolution: 0.1\norigin: [1.0, 2.0, 1.5707963267948966]\n"
         "occupied_thresh: 0.65\nfree_thresh: 0.196\nnegate: 0\n";
  }
  auto back = ReadMapServer(dir + "/turned.yaml");
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->width, 3);  // a quarter turn: 3 wide, 4 high
  EXPECT_EQ(back->height, 4);
  EXPECT_NEAR(back->origin_x_m, 0.7, 1e-9);
  EXPECT_NEAR(back->origin_y_m, 2.0, 1e-9);
  {
    std::ofstream y(dir + "/bad.yaml");
    y << "image: turned.pgm\nresolution: 0.1\norigin: [1.0, 2.0, .nan]\n";
  }
  auto bad = ReadMapServer(dir + "/bad.yaml");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("origin must be finite"), std::string::npos);
}

// 2 x 2 blocks of a 5 x 3 grid (the last column and row cover fewer cells): occupied wins over
// free, free over unknown; origin kept, cells twice the size.
TEST(Grid, CoarsenGridKeepsOneCellWallsAndCoversTheEdges) {
  GridMap m;
  m.resolution_m = 0.025;
  m.origin_x_m = -1.0;
  m.origin_y_m = 2.0;
  m.width = 5;
  m.height = 3;
  m.cells = {0,  0,  -1, -1, 0,     // row 0
             0,  70, -1, -1, -1,    // row 1
             -1, -1, 0,  -1, 100};  // row 2
  const GridMap c = CoarsenGrid(m, 2);
  EXPECT_DOUBLE_EQ(c.resolution_m, 0.05);
  EXPECT_DOUBLE_EQ(c.origin_x_m, -1.0);
  EXPECT_DOUBLE_EQ(c.origin_y_m, 2.0);
  ASSERT_EQ(c.width, 3);
  ASSERT_EQ(c.height, 2);
  EXPECT_EQ(c.at(0, 0), 70);  // one occupied fine cell among free ones
  EXPECT_EQ(c.at(1, 0), -1);  // nothing seen
  EXPECT_EQ(c.at(2, 0), 0);   // the last column: one column of fine cells, one free
  EXPECT_EQ(c.at(0, 1), -1);
  EXPECT_EQ(c.at(1, 1), 0);
  EXPECT_EQ(c.at(2, 1), 100);  // the corner cell covers one fine cell
  const GridMap same = CoarsenGrid(m, 1);
  EXPECT_EQ(same.cells, m.cells);
  EXPECT_DOUBLE_EQ(same.resolution_m, m.resolution_m);
}

}  // namespace
}  // namespace omni::io
