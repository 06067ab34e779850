#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <thread>
#include <tuple>

#include <gtest/gtest.h>

#include "omni/octomap_builder/key_set_inserter.h"
#include "omni/octomap_builder/octomap_builder.h"
#include "omni/octomap_builder/tree_compare.h"

namespace omni::octo {
namespace {

using KeyTuple = std::tuple<int, int, int>;
std::set<KeyTuple> ToSet(const std::vector<octomap::OcTreeKey>& keys) {
  std::set<KeyTuple> s;
  for (const auto& k : keys) s.emplace(k[0], k[1], k[2]);
  return s;
}
std::set<KeyTuple> ToSet(const octomap::KeySet& keys) {
  std::set<KeyTuple> s;
  for (const auto& k : keys) s.emplace(k[0], k[1], k[2]);
  return s;
}

// A room-like scan: points on the walls of a box around the origin, some beyond max range.
std::vector<Eigen::Vector3f> BoxScan(int n, unsigned seed, const Eigen::Vector3f& shift) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < n; ++i) {
    Eigen::Vector3f d(u(rng), u(rng), 0.4f * u(rng));
    const float m = d.cwiseAbs().maxCoeff();
    pts.push_back(shift + d / m * (i % 7 == 0 ? 6.0f : 2.5f));  // every 7th far away
  }
  return pts;
}

octomap::Pointcloud ToCloud(const std::vector<Eigen::Vector3f>& pts) {
  octomap::Pointcloud pc;
  for (const auto& p : pts) pc.push_back(p.x(), p.y(), p.z());
  return pc;
}

TEST(Morton, RoundTripAndChildOrder) {
  const octomap::OcTreeKey k(32768 + 5, 32768 - 3, 12345);
  const octomap::OcTreeKey back = KeyFromMorton(MortonCode(k));
  EXPECT_EQ(back, k);
  // The child index at every depth equals octomap::computeChildIdx.
  const uint64_t m = MortonCode(k);
  for (unsigned depth = 0; depth < 16; ++depth)
    EXPECT_EQ((m >> (3 * (15 - depth))) & 7, octomap::computeChildIdx(k, 15 - depth)) << depth;
}

TEST(KeySets, EqualOctomapComputeUpdate) {
  const double res = 0.1;
  const auto pts = BoxScan(3000, 1, {0.3f, -0.2f, 0.1f});
  const Eigen::Vector3f origin(0.05f, 0.02f, 0.3f);
  // Both ways of computing them: the brick bitmap (default) and the hash sets it falls back to
  // when the scan's box is too large (forced with max_bitmap_bytes = 0). The box of this scan
  // straddles the keys' 2^15 boundary, where every Morton bit above a brick changes.
  for (double maxrange : {-1.0, 4.0}) {
    for (int threads : {1, 3}) {
      for (bool bitmap : {true, false}) {
        KeySetOptions o;
        o.num_threads = threads;
        o.max_range_m = maxrange;
        if (!bitmap) o.max_bitmap_bytes = 0;
        ParallelKeySetInserter ins(res, o);
        InsertStats st;
        const KeySets ours = ins.ComputeKeySets(pts, origin, &st);
        EXPECT_EQ(st.bitmap, bitmap);
        octomap::OcTree ref(res);
        octomap::KeySet free_ref, occ_ref;
        ref.computeUpdate(ToCloud(pts), octomap::point3d(origin.x(), origin.y(), origin.z()),
                          free_ref, occ_ref, maxrange);
        EXPECT_EQ(ToSet(ours.Free()), ToSet(free_ref))
            << "maxrange " << maxrange << " threads " << threads;
        EXPECT_EQ(ToSet(ours.Occupied()), ToSet(occ_ref)) << "maxrange " << maxrange;
        EXPECT_EQ(st.free_keys, free_ref.size());
        EXPECT_EQ(st.occupied_keys, occ_ref.size());
        EXPECT_TRUE(std::is_sorted(ours.updates.begin(), ours.updates.end()));
        if (maxrange > 0) {
          EXPECT_LT(occ_ref.size(), 3000u);  // far points add no occupied key
        }
      }
    }
  }
}

TEST(KeySets, BitmapTooLargeFallsBackToHashSets) {
  // A scan whose box needs more bitmap than allowed is computed with the hash sets: same keys.
  const double res = 0.05;
  const auto pts = BoxScan(500, 5, {0.f, 0.f, 0.f});
  KeySetOptions small;
  small.max_bitmap_bytes = 4096;  // a 6 m box at 5 cm needs megabytes
  KeySetOptions big;
  InsertStats st_small, st_big;
  const KeySets a = ParallelKeySetInserter(res, small).ComputeKeySets(pts, {0, 0, 0}, &st_small);
  const KeySets b = ParallelKeySetInserter(res, big).ComputeKeySets(pts, {0, 0, 0}, &st_big);
  EXPECT_FALSE(st_small.bitmap);
  EXPECT_TRUE(st_big.bitmap);
  EXPECT_EQ(a.updates, b.updates);
  EXPECT_GT(a.updates.size(), 10000u);
}

TEST(KeySets, ReusedStorageGivesWhatAFreshComputationGives) {
  // The builder keeps one KeySets and the reductions' tables from frame to frame: a large frame,
  // then a small one, then a large one again give exactly what fresh computations give, whatever
  // the reduction and the way the sets are computed.
  const double res = 0.05;
  const std::vector<std::vector<Eigen::Vector3f>> frames = {BoxScan(20000, 11, {0.1f, 0.f, 0.f}),
                                                            BoxScan(300, 12, {1.f, -0.5f, 0.2f}),
                                                            BoxScan(8000, 13, {-0.4f, 0.3f, 0.f})};
  for (int reduction = 0; reduction < 3; ++reduction) {
    for (bool bitmap : {true, false}) {
      KeySetOptions o;
      o.num_threads = 2;
      o.max_range_m = 4.0;
      o.discretize = reduction == 1;
      o.subvoxel = reduction == 2 ? 2 : 0;
      if (!bitmap) o.max_bitmap_bytes = 0;
      const ParallelKeySetInserter ins(res, o);
      KeySets kept;
      for (size_t f = 0; f < frames.size(); ++f) {
        const Eigen::Vector3f origin(0.05f * f, 0.f, 0.3f);
        InsertStats st_kept, st_fresh;
        ins.ComputeKeySets(frames[f], origin, &kept, &st_kept);
        // Fresh: a new inserter on a new thread (so with its own, empty scratch).
        KeySets fresh;
        std::thread([&] {
          fresh = ParallelKeySetInserter(res, o).ComputeKeySets(frames[f], origin, &st_fresh);
        }).join();
        EXPECT_EQ(kept.updates, fresh.updates)
            << "reduction " << reduction << " bitmap " << bitmap << " frame " << f;
        EXPECT_EQ(st_kept.rays, st_fresh.rays);
        EXPECT_EQ(st_kept.bitmap, bitmap);
        EXPECT_GT(kept.updates.size(), 100u);
      }
    }
  }
}

TEST(KeySets, TreeEqualsInsertPointCloudOverSeveralScans) {
  const double res = 0.1;
  for (bool discretize : {false, true}) {
    KeySetOptions o;
    o.num_threads = 2;
    o.max_range_m = 5.0;
    o.discretize = discretize;
    ParallelKeySetInserter ins(res, o);
    octomap::OcTree ours(res), ref(res);
    for (unsigned scan = 0; scan < 4; ++scan) {
      const Eigen::Vector3f origin(0.3f * scan, 0.1f * scan, 0.2f);
      // The same room seen from moving origins: leaves get hit, missed, clamped, pruned.
      const auto pts = BoxScan(4000, 7 + scan, {0.f, 0.f, 0.f});
      ins.Insert(&ours, pts, origin);
      ref.insertPointCloud(ToCloud(pts), octomap::point3d(origin.x(), origin.y(), origin.z()), 5.0,
                           false, discretize);
    }
    EXPECT_GT(ref.getNumLeafNodes(), 1000u);
    EXPECT_TRUE(SameLeaves(ours, ref)) << "discretize " << discretize;
    EXPECT_EQ(ours.size(), ref.size());  // same pruning: same node count
    const auto cmp = CompareOccupied(ours, ref);
    EXPECT_DOUBLE_EQ(cmp.iou, 1.0);
    // Inner nodes carry the same (max-of-children) values.
    double ours_root = ours.getRoot()->getLogOdds(), ref_root = ref.getRoot()->getLogOdds();
    EXPECT_FLOAT_EQ(static_cast<float>(ours_root), static_cast<float>(ref_root));
  }
}

TEST(KeySets, RepeatedScansClampAndPruneLikeOctomap) {
  // The same scan many times drives leaves to the clamping thresholds, where octomap prunes
  // uniform regions and skips updates (early abort): the trees must still match.
  const double res = 0.2;
  KeySetOptions o;
  o.num_threads = 2;
  ParallelKeySetInserter ins(res, o);
  octomap::OcTree ours(res), ref(res);
  const auto pts = BoxScan(2000, 3, {0, 0, 0});
  for (int i = 0; i < 12; ++i) {
    ins.Insert(&ours, pts, Eigen::Vector3f::Zero());
    ref.insertPointCloud(ToCloud(pts), octomap::point3d(0, 0, 0), -1, false, false);
  }
  EXPECT_TRUE(SameLeaves(ours, ref));
  EXPECT_EQ(ours.size(), ref.size());
}

TEST(KeySets, SubvoxelKeepsTheOccupiedKeysAndFewerRays) {
  const double res = 0.1;
  // A dense scan (many points per voxel), as a depth camera gives: a wavy wall 2 m ahead.
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 200; ++j)
      pts.emplace_back(2.0f + 0.05f * std::sin(0.1f * i), -0.5f + 0.005f * i, -0.5f + 0.005f * j);
  const Eigen::Vector3f origin(0.02f, 0.01f, 0.1f);
  KeySetOptions exact;
  exact.max_range_m = 5.0;
  KeySetOptions sub = exact;
  sub.subvoxel = 2;
  InsertStats se, ss;
  const KeySets ke = ParallelKeySetInserter(res, exact).ComputeKeySets(pts, origin, &se);
  const KeySets ks = ParallelKeySetInserter(res, sub).ComputeKeySets(pts, origin, &ss);
  EXPECT_EQ(ToSet(ks.Occupied()), ToSet(ke.Occupied()));
  EXPECT_LT(ss.rays * 2, se.rays);
  // The free sets differ only a little (rays end at centroids, not at the points).
  const auto fe = ToSet(ke.Free()), fs = ToSet(ks.Free());
  size_t common = 0;
  for (const auto& k : fs) common += fe.count(k);
  EXPECT_GT(static_cast<double>(common) / static_cast<double>(fe.size() + fs.size() - common), 0.9);
  // Over scans from several places the occupied voxels of the two trees agree closely.
  octomap::OcTree te(res), ts(res);
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3f o(0.1f * k, 0.3f * k - 0.3f, 0.05f * k);
    ParallelKeySetInserter(res, exact).Insert(&te, pts, o);
    ParallelKeySetInserter(res, sub).Insert(&ts, pts, o);
  }
  EXPECT_GT(CompareOccupied(ts, te).iou, 0.98);
}

TEST(OctomapBuilder, PlaneAtKnownDistance) {
  // A camera 1 m above the floor looking along the map's +x at a wall 2 m ahead.
  OctomapBuilderOptions opt;
  opt.resolution_m = 0.05;
  opt.max_range_m = 5.0;
  opt.depth.min_depth_m = 0.1;
  opt.depth.max_depth_m = 5.0;
  opt.discretize = true;
  opt.mount.height_m = 1.0;
  OctomapBuilder builder(opt);
  DepthImage im;
  im.width = 64;
  im.height = 48;
  im.intrinsics = {50.0, 50.0, 31.5, 23.5, 1000.0};
  im.data.assign(static_cast<size_t>(im.width) * im.height, 2000);  // z = 2 m everywhere
  im.data[5] = 0;                                                   // one invalid pixel
  const Eigen::Isometry3d cam = CameraInMap(Pose2(0, 0, 0), opt.mount);
  auto st = builder.InsertDepth(im, cam);
  ASSERT_TRUE(st.ok()) << st.error().message;
  EXPECT_EQ(st->points, static_cast<size_t>(im.width * im.height - 1));
  const octomap::OcTree& t = builder.tree();
  // The wall: occupied voxels at x = 2 m (the voxel holding 2.0), for the image's extent:
  // |y| <= 2 * 31.5 / 50 = 1.26 m, |z - 1| <= 2 * 23.5 / 50 = 0.94 m.
  for (double y : {-1.0, 0.0, 0.6}) {
    for (double z : {0.3, 1.0, 1.8}) {
      const octomap::OcTreeNode* n = t.search(2.02, y, z);
      ASSERT_NE(n, nullptr) << y << " " << z;
      EXPECT_TRUE(t.isNodeOccupied(n)) << y << " " << z;
      // Free space before the wall, along the rays.
      const octomap::OcTreeNode* f = t.search(1.0 + 0.5 * (0.0), y * 0.5, 1.0 + (z - 1.0) * 0.5);
      ASSERT_NE(f, nullptr);
      EXPECT_FALSE(t.isNodeOccupied(f));
    }
  }
  // Nothing is known behind the wall or outside the field of view.
  EXPECT_EQ(t.search(2.5, 0.0, 1.0), nullptr);
  EXPECT_EQ(t.search(1.0, 2.0, 1.0), nullptr);
  // All occupied voxels lie in the wall's voxel slab.
  const double slab = std::floor(2.0 / 0.05) * 0.05;
  for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it)
    if (t.isNodeOccupied(*it)) {
      EXPECT_GE(it.getX(), slab - 1e-6);
      EXPECT_LE(it.getX(), slab + 0.05 + 1e-6);
    }
}

// A camera pose far outside the octree (a corrupt pose file, a foreign POSE_* message at
// 1e20 m) maps nothing and is reported as such. OctoMap turns a coordinate into a key with a
// plain cast to int, which is undefined beyond the int range: the sanitizer build
// (float-cast-overflow) fails this test if such a pose reaches it.
TEST(OctomapBuilder, ACameraFarOutsideTheTreeMapsNothing) {
  OctomapBuilderOptions opt;
  opt.resolution_m = 0.05;
  opt.max_range_m = 5.0;
  opt.keep_cloud = true;
  OctomapBuilder builder(opt);
  DepthImage im;
  im.width = 16;
  im.height = 12;
  im.intrinsics = {12.5, 12.5, 7.5, 5.5, 1000.0};
  im.data.assign(static_cast<size_t>(im.width) * im.height, 2000);
  for (const double x : {2000.0, 1e6, 1e12, 1e20, 1e300, std::numeric_limits<double>::infinity(),
                         std::numeric_limits<double>::quiet_NaN()}) {
    Eigen::Isometry3d cam = CameraInMap(Pose2(0, 0, 0), opt.mount);
    cam.translation().x() = x;
    auto st = builder.InsertDepth(im, cam);
    ASSERT_TRUE(st.ok()) << x << ": " << st.error().message;
    EXPECT_EQ(st->points, static_cast<size_t>(im.width * im.height)) << x;
    EXPECT_EQ(st->insert.free_keys + st->insert.occupied_keys, 0u) << x;
  }
  EXPECT_EQ(builder.tree().size(), 0u);
  EXPECT_TRUE(builder.AggregateCloud().empty());
  // A camera inside the tree still maps.
  auto st = builder.InsertDepth(im, CameraInMap(Pose2(1000, -1000, 0), opt.mount));
  ASSERT_TRUE(st.ok());
  EXPECT_GT(st->insert.occupied_keys, 0u);
}

}  // namespace
}  // namespace omni::octo
