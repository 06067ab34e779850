// Colour: decoding (RGB8, JPEG), registration to depth, integration into a ColorOcTree, the
// .ot round trip, and pairing colour with depth frames in the pipeline.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <tuple>

#include <gtest/gtest.h>

#include "omni/octomap_builder/color_image.h"
#include "omni/octomap_builder/color_octree.h"
#include "omni/octomap_builder/map_output.h"
#include "omni/octomap_builder/octomap_builder.h"

namespace omni::octo {
namespace {

namespace fs = std::filesystem;

using Rgb = std::tuple<int, int, int>;
Rgb ColorOf(const octomap::ColorOcTreeNode& n) {
  const auto c = n.getColor();
  return {c.r, c.g, c.b};
}

// Pixels encode their own position: R = u, G = v, B = 7.
ColorImage PositionImage(int w, int h) {
  ColorImage im;
  im.width = w;
  im.height = h;
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      im.rgb.push_back(static_cast<uint8_t>(u));
      im.rgb.push_back(static_cast<uint8_t>(v));
      im.rgb.push_back(7);
    }
  return im;
}

DepthImage FlatDepth(int w, int h, double fx, double cx, double cy, uint16_t d) {
  DepthImage im;
  im.width = w;
  im.height = h;
  im.intrinsics = {fx, fx, cx, cy, 1000.0};
  im.data.assign(static_cast<size_t>(w) * h, d);
  return im;
}

TEST(ColorDecode, Rgb8NeedsExactlyThreeBytesPerPixel) {
  std::vector<uint8_t> data(4 * 3 * 3, 9), rgb;
  ASSERT_TRUE(DecodeColorData(0, data.data(), data.size(), 4, 3, &rgb).ok());
  EXPECT_EQ(rgb, data);
  const Status short_by_one = DecodeColorData(0, data.data(), data.size() - 1, 4, 3, &rgb);
  ASSERT_FALSE(short_by_one.ok());
  EXPECT_NE(short_by_one.message().find("35 bytes, expected 36"), std::string::npos)
      << short_by_one.message();
  EXPECT_FALSE(DecodeColorData(0, data.data(), data.size(), 0, 3, &rgb).ok());
  EXPECT_FALSE(DecodeColorData(5, data.data(), data.size(), 4, 3, &rgb).ok());  // encoding
}

TEST(ColorDecode, JpegRoundTripAndCorruptData) {
  if (!JpegAvailable()) GTEST_SKIP() << "built without libjpeg (libjpeg-dev not installed)";
  // A smooth gradient survives JPEG at quality 95 within a few levels.
  const int w = 64, h = 48;
  std::vector<uint8_t> rgb;
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      rgb.push_back(static_cast<uint8_t>(u * 4));
      rgb.push_back(static_cast<uint8_t>(v * 5));
      rgb.push_back(128);
    }
  auto jpeg = EncodeJpeg(rgb, w, h, 95);
  ASSERT_TRUE(jpeg.ok()) << jpeg.error().message;
  EXPECT_LT(jpeg->size(), rgb.size());
  std::vector<uint8_t> out;
  ASSERT_TRUE(DecodeColorData(1, jpeg->data(), jpeg->size(), w, h, &out).ok());
  ASSERT_EQ(out.size(), rgb.size());
  double err = 0;
  for (size_t i = 0; i < out.size(); ++i) err += std::abs(int(out[i]) - int(rgb[i]));
  EXPECT_LT(err / out.size(), 3.0);
  // The message's size must be the JPEG's.
  const Status other_size = DecodeColorData(1, jpeg->data(), jpeg->size(), w, h + 1, &out);
  ASSERT_FALSE(other_size.ok());
  EXPECT_NE(other_size.message().find("decoded 64x48"), std::string::npos) << other_size.message();
  // Truncated, garbage and empty payloads are errors (libjpeg's warnings count as errors).
  for (size_t cut : {jpeg->size() / 2, jpeg->size() - 2, size_t{3}}) {
    EXPECT_FALSE(DecodeColorData(1, jpeg->data(), cut, w, h, &out).ok()) << "cut at " << cut;
  }
  std::vector<uint8_t> garbage(500, 0x5a);
  EXPECT_FALSE(DecodeColorData(1, garbage.data(), garbage.size(), w, h, &out).ok());
  std::vector<uint8_t> broken = *jpeg;
  for (size_t i = broken.size() / 3; i < broken.size() / 3 + 40; ++i) broken[i] = 0xff;
  EXPECT_FALSE(DecodeColorData(1, broken.data(), broken.size(), w, h, &out).ok());
}

TEST(ColorRegistration, SamePixelWhenRegisteredOrSameIntrinsics) {
  const DepthImage d = FlatDepth(40, 30, 30.0, 19.5, 14.5, 1500);
  ColorImage c = PositionImage(40, 30);
  DepthToPointsOptions o;
  o.pixel_stride = 3;
  for (bool with_intrinsics : {false, true}) {
    if (with_intrinsics) c.intrinsics = {30.0, 30.0, 19.5, 14.5};
    auto cp = DepthToColoredPoints(d, c, o);
    ASSERT_TRUE(cp.ok()) << cp.error().message;
    EXPECT_FALSE(cp->projected);
    auto pts = DepthToPoints(d, o);
    ASSERT_TRUE(pts.ok());
    ASSERT_EQ(cp->points, *pts);  // the same points, in the same order
    ASSERT_EQ(cp->colors.size(), pts->size());
    EXPECT_EQ(cp->colored, pts->size());
    // Point i is pixel (u, v) = (3 (i % 14), 3 (i / 14)).
    for (size_t i = 0; i < cp->colors.size(); ++i) {
      const int u = 3 * static_cast<int>(i % 14), v = 3 * static_cast<int>(i / 14);
      EXPECT_EQ(cp->colors[i], PackRgb(static_cast<uint8_t>(u), static_cast<uint8_t>(v), 7)) << i;
    }
  }
}

TEST(ColorRegistration, ProjectsIntoAColorCameraOfAnotherSize) {
  // Depth 80x60 (fx 60, cx 40, cy 30); colour 40x30 at half the focal length with the
  // principal point at (20, 15): pixel (u, v) of depth lands on (u / 2, v / 2).
  const DepthImage d = FlatDepth(80, 60, 60.0, 40.0, 30.0, 2000);
  ColorImage c = PositionImage(40, 30);
  c.intrinsics = {30.0, 30.0, 20.0, 15.0};
  DepthToPointsOptions o;
  auto cp = DepthToColoredPoints(d, c, o);
  ASSERT_TRUE(cp.ok()) << cp.error().message;
  EXPECT_TRUE(cp->projected);
  ASSERT_EQ(cp->points.size(), 80u * 60u);
  size_t checked = 0;
  for (int v = 0; v < 60; v += 2)
    for (int u = 0; u < 80; u += 2) {
      const size_t i = static_cast<size_t>(v) * 80 + u;
      EXPECT_EQ(cp->colors[i], PackRgb(static_cast<uint8_t>(u / 2), static_cast<uint8_t>(v / 2), 7))
          << u << " " << v;
      ++checked;
    }
  EXPECT_EQ(checked, 1200u);
  // A colour camera shifted so that its image covers only part of the depth image: the rest
  // stays uncoloured but is still there.
  c.intrinsics.cx = -5.0;  // u_c = u / 2 - 25: depth columns u < 50 fall outside
  cp = DepthToColoredPoints(d, c, o);
  ASSERT_TRUE(cp.ok());
  EXPECT_EQ(cp->points.size(), 80u * 60u);
  size_t uncolored_left = 0;
  for (int v = 0; v < 60; ++v)
    for (int u = 0; u < 80; ++u)
      if (cp->colors[static_cast<size_t>(v) * 80 + u] == 0) uncolored_left += u < 49;
  EXPECT_EQ(uncolored_left, 49u * 60u);
  EXPECT_EQ(cp->colored, 80u * 60u - 49u * 60u);
}

TEST(ColorRegistration, BadColorInputIsAnError) {
  const DepthImage d = FlatDepth(40, 30, 30.0, 19.5, 14.5, 1500);
  DepthToPointsOptions o;
  ColorImage other = PositionImage(20, 15);  // another size, no intrinsics
  auto r = DepthToColoredPoints(d, other, o);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("no intrinsics"), std::string::npos) << r.error().message;
  ColorImage short_rgb = PositionImage(40, 30);
  short_rgb.rgb.pop_back();
  r = DepthToColoredPoints(d, short_rgb, o);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("3599 bytes"), std::string::npos) << r.error().message;
  ColorImage bad_k = PositionImage(20, 15);
  bad_k.intrinsics = {0.0, 30.0, 10.0, 7.0};
  EXPECT_FALSE(DepthToColoredPoints(d, bad_k, o).ok());
}

TEST(ColorIntegration, ConstantColorStaysAndWhiteStaysSet) {
  octomap::ColorOcTree t(0.1);
  octomap::ColorOcTreeNode* n = t.updateNode(0.05, 0.05, 0.05, true);
  for (int i = 0; i < 60; ++i) {
    t.updateNode(0.05, 0.05, 0.05, true);  // clamps at 0.971
    IntegrateColor(n, PackRgb(201, 40, 93));
  }
  EXPECT_EQ(ColorOf(*n), Rgb(201, 40, 93));
  // OctoMap's integrateNodeColor darkens the same sequence (weights p and 0.99 - p).
  octomap::ColorOcTree u(0.1);
  for (int i = 0; i < 60; ++i) {
    u.updateNode(0.05, 0.05, 0.05, true);
    u.integrateNodeColor(0.05f, 0.05f, 0.05f, 201, 40, 93);
  }
  EXPECT_LT(std::get<0>(ColorOf(*u.search(0.05, 0.05, 0.05))), 190);
  // Blending: p * old + (1 - p) * new with p the occupancy.
  octomap::ColorOcTree b(0.1);
  octomap::ColorOcTreeNode* m = b.updateNode(0.05, 0.05, 0.05, true);  // p = 0.7
  IntegrateColor(m, PackRgb(100, 100, 100));
  IntegrateColor(m, PackRgb(200, 0, 100));
  EXPECT_EQ(ColorOf(*m), Rgb(130, 70, 100));
  // Pure white would read as "no colour" in OctoMap.
  octomap::ColorOcTreeNode* w = b.updateNode(1.05, 0.05, 0.05, true);
  IntegrateColor(w, PackRgb(255, 255, 255));
  EXPECT_TRUE(w->isColorSet());
  EXPECT_EQ(ColorOf(*w), Rgb(254, 254, 254));
}

// A wall 2.03 m ahead of a camera 1 m up looking along +x: the left half of the colour image
// red, the right half blue (image left = map +y).
constexpr uint8_t kRed[3] = {220, 30, 40};
constexpr uint8_t kBlue[3] = {30, 60, 210};

OctomapBuilderOptions ColorOptions() {
  OctomapBuilderOptions opt;
  opt.resolution_m = 0.05;
  opt.max_range_m = 5.0;
  opt.depth.min_depth_m = 0.1;
  opt.depth.max_depth_m = 5.0;
  opt.mount.height_m = 1.0;
  opt.color = true;
  return opt;
}

ColorImage SplitColorImage(int w, int h) {
  ColorImage c;
  c.width = w;
  c.height = h;
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const uint8_t* px = u < w / 2 ? kRed : kBlue;
      c.rgb.insert(c.rgb.end(), px, px + 3);
    }
  return c;
}

TEST(ColorOctomap, WallOfKnownColorsAtTheRightPlace) {
  for (int subvoxel : {0, 2}) {
    OctomapBuilderOptions opt = ColorOptions();
    opt.subvoxel = subvoxel;
    OctomapBuilder builder(opt);
    const DepthImage d = FlatDepth(64, 48, 50.0, 31.5, 23.5, 2030);
    const ColorImage c = SplitColorImage(64, 48);
    const Eigen::Isometry3d cam = CameraInMap(Pose2(0, 0, 0), opt.mount);
    for (int scan = 0; scan < 5; ++scan) {
      auto st = builder.InsertDepthColor(d, c, cam);
      ASSERT_TRUE(st.ok()) << st.error().message;
      EXPECT_EQ(st->colored_points, 64u * 48u);
      EXPECT_EQ(st->colored_keys, st->insert.occupied_keys);
    }
    const octomap::ColorOcTree& t = *builder.color_tree();
    size_t red = 0, blue = 0, occupied = 0;
    for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it) {
      if (!t.isNodeOccupied(*it)) continue;
      ++occupied;
      // In the wall's slab [2.0, 2.05) and coloured.
      EXPECT_NEAR(it.getX(), 2.025, 1e-4);
      ASSERT_TRUE(it->isColorSet());
      // Voxels clearly on one side of the split (map y = 0) have that side's colour exactly:
      // the same colour every scan.
      if (it.getY() > 0.05) {
        EXPECT_EQ(ColorOf(*it), Rgb(kRed[0], kRed[1], kRed[2])) << it.getY() << " " << it.getZ();
        ++red;
      } else if (it.getY() < -0.05) {
        EXPECT_EQ(ColorOf(*it), Rgb(kBlue[0], kBlue[1], kBlue[2])) << it.getY();
        ++blue;
      }
    }
    // |y| <= 2.03 * 31.5 / 50 = 1.28 m, |z - 1| <= 2.03 * 23.5 / 50 = 0.95 m.
    EXPECT_GT(red, 300u);
    EXPECT_GT(blue, 300u);
    EXPECT_NEAR(static_cast<double>(red), static_cast<double>(blue), 0.1 * red);
    // Free space before the wall; the OcTree has exactly the ColorOcTree's occupancy.
    const octomap::ColorOcTreeNode* f = t.search(1.0, 0.2, 1.0);
    ASSERT_NE(f, nullptr);
    EXPECT_FALSE(t.isNodeOccupied(f));
    size_t plain_leaves = 0;
    for (auto it = builder.tree().begin_leafs(); it != builder.tree().end_leafs(); ++it) {
      ++plain_leaves;
      const octomap::ColorOcTreeNode* n = t.search(it.getKey(), it.getDepth());
      ASSERT_NE(n, nullptr);
      EXPECT_FLOAT_EQ(n->getLogOdds(), it->getLogOdds());
    }
    EXPECT_EQ(plain_leaves, t.getNumLeafNodes());
    EXPECT_GE(occupied, red + blue);
  }
}

// Random scans with random colours, several origins; repeated until parts clamp and prune.
// (Returns a reference: OctoMap's tree copy constructors copy nodes as their base class, so a
// copied ColorOcTree loses its colours.)
const octomap::ColorOcTree& RandomColorTree(OctomapBuilder* builder) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::uniform_int_distribution<int> c(0, 255);
  for (int scan = 0; scan < 12; ++scan) {
    std::vector<Eigen::Vector3f> pts;
    std::vector<uint32_t> colors;
    for (int i = 0; i < 3000; ++i) {
      // A box room 2 m around the origin, so scans overlap and occupied voxels repeat.
      Eigen::Vector3f p(u(rng), u(rng), u(rng));
      const int axis = i % 3;
      p[axis] = p[axis] > 0 ? 1.5f : -1.5f;
      pts.push_back(p);
      colors.push_back(
          i % 5 == 0 ? 0u
                     : PackRgb(static_cast<uint8_t>(c(rng)), static_cast<uint8_t>(c(rng)), 100));
    }
    Eigen::Isometry3d at = Eigen::Isometry3d::Identity();
    at.translation() = Eigen::Vector3d(0.1 * (scan % 3), -0.05 * (scan % 2), 0.0);
    builder->InsertPoints(pts, at, &colors);
  }
  return *builder->color_tree();
}

TEST(ColorOctomap, InnerColorsAreWhatUpdateInnerOccupancyGives) {
  OctomapBuilderOptions opt = ColorOptions();
  opt.resolution_m = 0.1;
  OctomapBuilder builder(opt);
  const octomap::ColorOcTree& ours = RandomColorTree(&builder);
  // A deep copy through OctoMap's own serialisation, then its full inner update.
  std::stringstream bytes;
  ASSERT_TRUE(ours.write(bytes));
  std::unique_ptr<octomap::AbstractOcTree> any(octomap::AbstractOcTree::read(bytes));
  auto* ref_ptr = dynamic_cast<octomap::ColorOcTree*>(any.get());
  ASSERT_NE(ref_ptr, nullptr);
  octomap::ColorOcTree& ref = *ref_ptr;
  ref.updateInnerOccupancy();
  ASSERT_EQ(ours.size(), ref.size());
  size_t inner = 0, colored_inner = 0;
  auto a = ours.begin_tree(), b = ref.begin_tree();
  for (; a != ours.end_tree() && b != ref.end_tree(); ++a, ++b) {
    ASSERT_EQ(a.getKey(), b.getKey());
    ASSERT_EQ(a.getDepth(), b.getDepth());
    EXPECT_EQ(a->getValue(), b->getValue()) << a.getDepth();
    EXPECT_EQ(ColorOf(*a), ColorOf(*b)) << "depth " << a.getDepth();
    if (!a.isLeaf()) {
      ++inner;
      colored_inner += a->isColorSet();
    }
  }
  EXPECT_TRUE(a == ours.end_tree() && b == ref.end_tree());
  EXPECT_GT(inner, 1000u);
  EXPECT_GT(colored_inner, 100u);
  // The plain tree has the same leaves (same occupancy, same pruning).
  size_t n = 0;
  for (auto it = builder.tree().begin_leafs(); it != builder.tree().end_leafs(); ++it, ++n) {
    const auto* c = ours.search(it.getKey(), it.getDepth());
    ASSERT_NE(c, nullptr);
    EXPECT_FLOAT_EQ(c->getLogOdds(), it->getLogOdds());
  }
  EXPECT_EQ(n, ours.getNumLeafNodes());
}

TEST(MapOutput, ColorTreeSavesAndLoadsBackAsColorOcTree) {
  OctomapBuilderOptions opt = ColorOptions();
  opt.resolution_m = 0.1;
  OctomapBuilder builder(opt);
  const octomap::ColorOcTree& t = RandomColorTree(&builder);
  const std::string dir = testing::TempDir() + "/octo_color_save";
  fs::create_directories(dir);
  ASSERT_TRUE(SaveColorTree(t, dir + "/map_color.ot").ok());
  EXPECT_FALSE(fs::exists(dir + "/map_color.ot.tmp"));
  // OctoMap's own generic reader gives a ColorOcTree.
  {
    std::ifstream in(dir + "/map_color.ot", std::ios::binary);
    std::unique_ptr<octomap::AbstractOcTree> any(octomap::AbstractOcTree::read(in));
    ASSERT_NE(any, nullptr);
    EXPECT_EQ(any->getTreeType(), "ColorOcTree");
    EXPECT_NE(dynamic_cast<octomap::ColorOcTree*>(any.get()), nullptr);
  }
  auto loaded = LoadColorTree(dir + "/map_color.ot");
  ASSERT_TRUE(loaded.ok()) << loaded.error().message;
  const octomap::ColorOcTree& l = **loaded;
  EXPECT_EQ(l.getResolution(), 0.1);
  ASSERT_EQ(l.getNumLeafNodes(), t.getNumLeafNodes());
  size_t colored = 0;
  for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it) {
    const auto* n = l.search(it.getKey(), it.getDepth());
    ASSERT_NE(n, nullptr);
    EXPECT_EQ(n->getLogOdds(), it->getLogOdds());
    EXPECT_EQ(ColorOf(*n), ColorOf(*it));
    colored += it->isColorSet();
  }
  EXPECT_GT(colored, 1000u);
  // Not an OcTree, and an OcTree is not a ColorOcTree; truncated files are errors.
  EXPECT_FALSE(LoadTree(dir + "/map_color.ot").ok());
  ASSERT_TRUE(SaveTree(builder.tree(), dir + "/plain").ok());
  EXPECT_FALSE(LoadColorTree(dir + "/plain.ot").ok());
  std::ifstream good(dir + "/map_color.ot", std::ios::binary);
  std::stringstream all;
  all << good.rdbuf();
  const std::string bytes = all.str();
  for (size_t cut : {bytes.size() / 2, bytes.size() - 1}) {
    std::ofstream(dir + "/cut.ot", std::ios::binary) << bytes.substr(0, cut);
    EXPECT_FALSE(LoadColorTree(dir + "/cut.ot").ok()) << cut;
  }
  // The colour view paints the top voxels in their colours.
  const io::Image view = RenderTopViewColor(t);
  EXPECT_GT(view.width, 10);
}

// A depth-only pipeline (colour off) and a flat depth frame of the wall 2.03 m ahead.
struct DepthOnlyPipeline {
  static OctomapBuilderOptions Options() {
    OctomapBuilderOptions opt = ColorOptions();
    opt.color = false;
    opt.keep_cloud = true;
    return opt;
  }
  OctomapPipeline p{Options()};
  const int64_t t0 = 1000000000;
  DepthImage d = FlatDepth(64, 48, 50.0, 31.5, 23.5, 2030);
};

// A pose 10^5 m out puts every point of the frame outside the octree's key range (about
// +-1638 m at 5 cm): nothing is mapped, and the frame is counted as such, not as inserted.
TEST(OctomapPipeline, AFrameOutsideTheKeyRangeIsCountedNotInserted) {
  DepthOnlyPipeline f;
  auto& [p, t0, d] = f;
  p.AddPose(t0, Pose2(0, 0, 0));
  p.AddPose(t0 + 100000, Pose2(0, 0, 0));
  d.utime = t0 + 50000;
  p.AddDepth(d);
  EXPECT_EQ(p.Process(t0 + 100000), 1);
  const size_t cloud = p.builder().AggregateCloud().size();
  EXPECT_GT(cloud, 0u);
  p.AddPose(t0 + 200000, Pose2(1e5, 0, 0));
  p.AddPose(t0 + 300000, Pose2(1e5, 0, 0));
  d.utime = t0 + 250000;
  p.AddDepth(d);
  EXPECT_EQ(p.Process(t0 + 300000), 0);
  EXPECT_EQ(p.counters().frames_inserted, 1);
  EXPECT_EQ(p.counters().frames_out_of_range, 1);
  EXPECT_NE(p.last_error().find("key range"), std::string::npos) << p.last_error();
  EXPECT_EQ(p.builder().AggregateCloud().size(), cloud);  // nor is it in the kept cloud
}

// A pose no SLAM could give (NaN, 1e7 m, 1e20 m, a heading of 1e9 rad) is refused and
// counted, never interpolated into a camera pose: the frame waits for real poses around it.
TEST(OctomapPipeline, AbsurdPosesAreRefusedAndCounted) {
  DepthOnlyPipeline f;
  auto& [p, t0, d] = f;
  p.AddPose(t0, Pose2(0, 0, 0));
  p.AddPose(t0 + 10000, Pose2(std::nan(""), 0, 0));
  p.AddPose(t0 + 20000, Pose2(1e7, 0, 0));
  p.AddPose(t0 + 30000, Pose2(0, -1e20, 0));
  p.AddPose(t0 + 40000, Pose2(0, 0, 1e9));
  d.utime = t0 + 50000;
  p.AddDepth(d);
  EXPECT_EQ(p.Process(t0 + 60000), 0);  // no pose after the frame yet
  EXPECT_EQ(p.poser_counters().poses_invalid, 4);
  EXPECT_EQ(p.poser_counters().poses_out_of_order, 0);
  p.AddPose(t0 + 100000, Pose2(0.1, 0, 0));
  EXPECT_EQ(p.Process(t0 + 100000), 1);
  EXPECT_EQ(p.counters().frames_inserted, 1);
  EXPECT_EQ(p.counters().frames_out_of_range, 0);
}

// A depth frame stamped an hour ahead must not become the pipeline's `now`: the frame before
// it, still waiting for its pose, would expire at once.
TEST(OctomapPipeline, AFutureDepthFrameDoesNotExpireTheWaitingOnes) {
  DepthOnlyPipeline f;
  auto& [p, t0, d] = f;
  p.AddPose(t0, Pose2(0, 0, 0));
  d.utime = t0 + 50000;
  p.AddDepth(d);
  d.utime = t0 + 3600000000LL;
  p.AddDepth(d);
  EXPECT_EQ(p.newest_utime(), t0 + 50000);
  EXPECT_EQ(p.Process(p.newest_utime()), 0);  // waits for a pose at or after its time
  p.AddPose(t0 + 100000, Pose2(0, 0, 0));
  EXPECT_EQ(p.Process(p.newest_utime()), 1);
  EXPECT_EQ(p.poser_counters().frames_dropped_no_pose, 0);
}

// The end of the input: a frame that a pose taken can still pose goes in, one newer than every
// pose is counted as dropped without a pose (the node used to exit with it uncounted).
TEST(OctomapPipeline, FinishInputPosesWhatItCanAndCountsTheRest) {
  DepthOnlyPipeline f;
  auto& [p, t0, d] = f;
  p.AddPose(t0, Pose2(0, 0, 0));
  p.AddPose(t0 + 100000, Pose2(0.1, 0, 0));
  d.utime = t0 + 50000;
  p.AddDepth(d);
  d.utime = t0 + 150000;
  p.AddDepth(d);
  EXPECT_EQ(p.FinishInput(), 1);
  EXPECT_EQ(p.counters().frames_inserted, 1);
  EXPECT_EQ(p.poser_counters().frames_dropped_no_pose, 1);
}

// A colour frame stamped 2.5 s ahead of the depth frames (another clock, or a glitch) moved the
// pipeline's time on, and every depth frame still waiting for its pose expired and was dropped
// as having none (review finding). The pipeline's time follows poses and depth frames only.
TEST(ColorOctomap, ColourStampedAheadDoesNotExpireFramesWaitingForTheirPose) {
  OctomapBuilderOptions opt = ColorOptions();
  opt.poser.max_latency_us = 1000000;
  OctomapPipeline p(opt);
  const int64_t t0 = 1000000000;
  DepthImage d = FlatDepth(64, 48, 50.0, 31.5, 23.5, 2030);
  p.AddPose(t0, Pose2(0, 0, 0));
  d.utime = t0 + 50000;
  p.AddDepth(d);  // its pose after it is late
  ColorImage ahead = SplitColorImage(64, 48);
  ahead.utime = t0 + 2500000;
  p.AddColor(ahead);
  EXPECT_EQ(p.Process(p.newest_utime()), 0);
  EXPECT_EQ(p.poser_counters().frames_dropped_no_pose, 0);
  p.AddPose(t0 + 100000, Pose2(0, 0, 0));
  EXPECT_EQ(p.Process(p.newest_utime()), 1);  // posed; the colour is too far: uncoloured
  EXPECT_EQ(p.counters().frames_inserted, 1);
  EXPECT_EQ(p.counters().frames_uncolored, 1);
}

// With colour on, frames waiting for the insert budget wait among those waiting for colour:
// at most kMaxBacklog of them, the oldest dropped and counted (they grew without bound, review
// finding); the end of the input inserts all that are left, without a cap.
TEST(ColorOctomap, TheInsertBudgetsBacklogIsBoundedWithColourToo) {
  OctomapBuilderOptions opt = ColorOptions();
  opt.poser.max_queued_frames = 1000;  // the poser's own queue lets them all through
  OctomapPipeline p(opt);
  p.set_insert_budget_us(0);  // one frame a call
  const int64_t t0 = 1000000000;
  const int kFrames = static_cast<int>(OctomapPipeline::kMaxBacklog) + 20;
  DepthImage d = FlatDepth(16, 12, 12.5, 7.5, 5.5, 2030);
  for (int i = 0; i < kFrames; ++i) {
    d.utime = t0 + 10000 * i;
    p.AddDepth(d);
  }
  p.AddPose(t0 - 1, Pose2(0, 0, 0));
  p.AddPose(t0 + 10000 * kFrames, Pose2(0, 0, 0));
  ColorImage late = SplitColorImage(16, 12);
  late.utime = t0 + 10000 * kFrames + 1000000;  // lets every frame go (uncoloured)
  p.AddColor(late);
  EXPECT_EQ(p.Process(p.newest_utime()), 1);
  EXPECT_EQ(p.counters().frames_dropped_backlog, 20);
  EXPECT_EQ(p.FinishInput(), static_cast<int>(OctomapPipeline::kMaxBacklog) - 1);
  EXPECT_EQ(p.counters().frames_inserted, static_cast<int64_t>(OctomapPipeline::kMaxBacklog));
}

// Pipeline pairing: poses every 100 ms, depth frames at 50 ms offsets.
TEST(ColorOctomap, PipelinePairsNearestColorAndCountsTheRest) {
  OctomapBuilderOptions opt = ColorOptions();
  opt.color_max_dt_us = 10000;
  opt.poser.max_latency_us = 300000;
  OctomapPipeline p(opt);
  const int64_t t0 = 1000000000;
  const DepthImage d = FlatDepth(64, 48, 50.0, 31.5, 23.5, 2030);
  auto depth_at = [&](int64_t t) {
    DepthImage im = d;
    im.utime = t;
    return im;
  };
  auto color_at = [&](int64_t t) {
    ColorImage c = SplitColorImage(64, 48);
    c.utime = t;
    return c;
  };
  for (int i = 0; i <= 10; ++i) p.AddPose(t0 + i * 100000, Pose2(0, 0, 0));
  // Frame 1: colour 4 ms before and 8 ms after: the nearer one (before) is taken.
  p.AddDepth(depth_at(t0 + 50000));
  p.AddColor(color_at(t0 + 46000));
  // Posed, but a nearer colour frame may still come: it waits.
  EXPECT_EQ(p.Process(t0 + 50000), 0);
  p.AddColor(color_at(t0 + 58000));
  p.AddColor(color_at(t0 + 61000));  // later than 50 ms + 10 ms: frame 1 is decided
  EXPECT_EQ(p.Process(t0 + 61000), 1);
  EXPECT_EQ(p.counters().frames_colored, 1);
  // Frame 2: the nearest colour is 30 ms away: inserted uncoloured once a later colour comes.
  p.AddDepth(depth_at(t0 + 150000));
  p.AddColor(color_at(t0 + 180000));
  EXPECT_EQ(p.Process(t0 + 180000), 1);
  EXPECT_EQ(p.counters().frames_uncolored, 1);
  // Frame 3: a colour partner of another size without intrinsics: counted, inserted uncoloured.
  p.AddDepth(depth_at(t0 + 250000));
  ColorImage small = SplitColorImage(32, 24);
  small.utime = t0 + 251000;
  p.AddColor(small);
  p.AddColor(color_at(t0 + 270000));
  EXPECT_EQ(p.Process(t0 + 270000), 1);
  EXPECT_EQ(p.counters().color_invalid, 1);
  EXPECT_EQ(p.counters().frames_uncolored, 2);
  EXPECT_NE(p.last_error().find("no intrinsics"), std::string::npos) << p.last_error();
  // Frame 4: no colour after it ever comes; it waits until the latency has passed.
  p.AddDepth(depth_at(t0 + 350000));
  p.AddColor(color_at(t0 + 352000));
  EXPECT_EQ(p.Process(t0 + 400000), 0);
  EXPECT_EQ(p.Process(t0 + 660000), 1);
  EXPECT_EQ(p.counters().frames_colored, 2);
  // Out-of-order colour is rejected.
  p.AddColor(color_at(t0));
  EXPECT_EQ(p.counters().color_out_of_order, 1);
  EXPECT_EQ(p.counters().frames_inserted, 4);
  EXPECT_EQ(p.counters().color_frames_in, 8);
  // Used: 46 and 352 ms; 251 ms was tried (counted invalid); never used: 58, 61, 180, 270 ms.
  EXPECT_EQ(p.counters().color_dropped, 4);  // dropped so far (352 ms is still buffered)
  const octomap::ColorOcTree& t = *p.builder().color_tree();
  const octomap::ColorOcTreeNode* n = t.search(2.03, 0.5, 1.0);
  ASSERT_NE(n, nullptr);
  EXPECT_EQ(ColorOf(*n), Rgb(kRed[0], kRed[1], kRed[2]));
}

TEST(OctomapBuilderConfig, ColorSection) {
  auto o = OctomapBuilderOptions::LoadFile(std::string(OMNI_SOURCE_DIR) +
                                           "/config/octomap_builder.yaml");
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_FALSE(o->color);
  EXPECT_EQ(o->color_channel, "RGB");
  EXPECT_EQ(o->color_max_dt_us, 20000);
  const std::string base = R"(
pose_source: rbpf
tree: {resolution_m: 0.1, max_range_m: 4.0}
depth: {min_depth_m: 0.3, max_depth_m: 5.0}
camera_mount: {height_m: 0.4}
poses: {max_latency_s: 0.2}
grid: {min_z_m: 0.1, max_z_m: 1.5}
)";
  auto r = ConfigReader::FromString(
      base + "color_channel: CAM_RGB\ncolor: {enabled: true, max_pair_dt_s: 0.033}\n", "c.yaml");
  ASSERT_TRUE(r.ok());
  o = OctomapBuilderOptions::Load(*r);
  ASSERT_TRUE(o.ok()) << o.error().message;
  EXPECT_TRUE(o->color);
  EXPECT_EQ(o->color_channel, "CAM_RGB");
  EXPECT_EQ(o->color_max_dt_us, 33000);
  r = ConfigReader::FromString(base + "color: {enable: true, max_pair_dt_s: 5}\n", "bad.yaml");
  ASSERT_TRUE(r.ok());
  o = OctomapBuilderOptions::Load(*r);
  ASSERT_FALSE(o.ok());
  EXPECT_NE(o.error().message.find("color.enable"), std::string::npos) << o.error().message;
  EXPECT_NE(o.error().message.find("color.max_pair_dt_s"), std::string::npos) << o.error().message;
}

}  // namespace
}  // namespace omni::octo
