// Point-cloud insertion into an OctoMap with the free and occupied key sets of a scan computed
// in parallel, de-duplicated, then applied to the tree in one pass.
//
// The key sets are exactly those of octomap's OccupancyOcTreeBase::insertPointCloud (1.9):
// for every point within max_range a ray of free keys from the origin (computeRayKeys, the
// endpoint's own voxel excluded) and the endpoint's key as occupied; a point beyond max_range
// gives only the free ray up to max_range; keys that are occupied in this scan are removed
// from the free set. With `discretize` the points are first replaced by the centres of their
// voxels (one per voxel), as insertPointCloud(..., discretize=true) does. With `subvoxel` = n > 1
// the points are replaced by the centroids of the cells of edge resolution / n (aligned with the
// tree's voxels, so each centroid stays in the voxel of its points: the same occupied keys, rays
// close to the original ones). Every key is then
// updated once with clamping and pruning on, giving the tree insertPointCloud(lazy_eval=false)
// builds from the same points (same leaves, same inner values, same pruning).
//
// Why it is faster:
//  - rays are cast on `num_threads` threads into one bitmap over the scan's box of keys, laid
//    out in 8×8×8 bricks of one cache line with the bits of a brick in Morton order, so a ray
//    stays in one cache line for several steps and a repeated key costs one load; reading the
//    touched bricks in Morton order of their position gives the sorted updates with no hash set
//    and no sort of the keys. (A box too large for `max_bitmap_bytes` falls back to per-thread
//    open-addressing hash sets merged by shard and radix-sorted.)
//  - the update visits the keys in Morton (octree child) order in one depth-first walk, so each
//    tree node on the union of the paths is visited, expanded, pruned and re-valued once per
//    scan instead of once per key (insertPointCloud descends from the root for every key, twice
//    counting its early-abort search).
#pragma once

#include <cstdint>
#include <vector>

#include <octomap/OcTree.h>
#include <Eigen/Core>

namespace omni::octo {

struct KeySetOptions {
  int num_threads = 2;      // threads for ray casting and merging (>= 1)
  double max_range_m = -1;  // rays longer than this are cut here and add no occupied key; < 0: none
  bool discretize = false;  // one ray per voxel of the tree (octomap's `discretize`)
  int subvoxel = 0;         // > 1: one ray per (resolution / subvoxel) cell, to its centroid
  // The key sets are marked in a bitmap over the scan's bounding box of keys (8×8×8-voxel
  // bricks, one cache line each, reserved as virtual memory; only the pages rays touch become
  // resident). A box needing more than this many bytes of address space uses per-thread hash
  // sets instead (same keys, slower). 0: always the hash sets.
  size_t max_bitmap_bytes = size_t{1} << 30;
};

// Morton code of a key: bit 3*i is bit i of x, 3*i+1 of y, 3*i+2 of z. The child index of a
// key at tree depth d (0 = root) is (code >> 3 * (15 - d)) & 7, as octomap::computeChildIdx.
uint64_t MortonCode(const octomap::OcTreeKey& key);
octomap::OcTreeKey KeyFromMorton(uint64_t code);

// The updates of one scan: (MortonCode(key) << 1 | occupied), ascending, each key once.
struct KeySets {
  std::vector<uint64_t> updates;
  std::vector<octomap::OcTreeKey> Free() const;
  std::vector<octomap::OcTreeKey> Occupied() const;
};

struct InsertStats {
  size_t points = 0;         // points given
  size_t rays = 0;           // rays cast (after discretize)
  size_t free_keys = 0;      // distinct free keys (occupied ones removed)
  size_t occupied_keys = 0;  // distinct occupied keys
  int64_t keys_us = 0;       // time to compute the key sets (monotonic clock), of which
  int64_t rays_us = 0;       //   casting the rays into per-thread sets,
  int64_t merge_us = 0;      //   merging them by shard and sorting each shard (Morton order),
  int64_t sort_us = 0;       //   merging the sorted shards
  bool bitmap = false;       // the key sets were marked in the brick bitmap (else hash sets)
  int64_t update_us = 0;     // time to update the tree
};

class ParallelKeySetInserter {
 public:
  // `resolution_m` must equal the resolution of the trees given to Insert()/Apply().
  ParallelKeySetInserter(double resolution_m, const KeySetOptions& options);

  // Key sets of one scan. `points` and `origin` are in the map (tree) frame, metres.
  KeySets ComputeKeySets(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3f& origin,
                         InsertStats* stats) const;
  // The same into `out`, whose storage is reused (a builder keeps one KeySets across frames).
  void ComputeKeySets(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3f& origin,
                      KeySets* out, InsertStats* stats) const;

  // Applies the updates to `tree` (OcTree, ColorOcTree, ...: any OccupancyOcTreeBase of the
  // same resolution), each key once with the tree's hit/miss log-odds and clamping.
  template <class Tree>
  static void Apply(Tree* tree, const KeySets& sets) {
    NoApplyHook none;
    Apply(tree, sets, none);
  }
  // The same walk, telling `hook` what it did, so per-node data (a ColorOcTree's colour) can be
  // updated in the same pass:
  //   hook.Leaf(node, update)          after an occupied update at the finest level;
  //   hook.Pruned(node, begin, end)    a pruned node left alone (already clamped in the direction
  //                                    of every update in [begin, end), upstream's early abort);
  //   hook.Inner(node)                 after an inner node took its children's maximum (it was
  //                                    not pruned), children first.
  // `update` points into sets.updates.
  template <class Tree, class Hook>
  static void Apply(Tree* tree, const KeySets& sets, Hook& hook);
  struct NoApplyHook {
    template <class Node>
    void Leaf(Node*, const uint64_t*) {}
    template <class Node>
    void Pruned(Node*, const uint64_t*, const uint64_t*) {}
    template <class Node>
    void Inner(Node*) {}
  };

  // ComputeKeySets + Apply.
  template <class Tree>
  InsertStats Insert(Tree* tree, const std::vector<Eigen::Vector3f>& points,
                     const Eigen::Vector3f& origin) const {
    InsertStats stats;
    const KeySets sets = ComputeKeySets(points, origin, &stats);
    const int64_t t0 = NowMicros();
    Apply(tree, sets);
    stats.update_us = NowMicros() - t0;
    return stats;
  }

  const KeySetOptions& options() const { return options_; }
  double resolution() const { return keyer_.getResolution(); }
  static int64_t NowMicros();

 private:
  template <class Tree, class Node, class Hook>
  static void ApplyRecurs(Tree* tree, Node* node, bool just_created, unsigned depth,
                          const uint64_t* begin, const uint64_t* end, Hook& hook);
  // The reductions write into `out` (the calling thread's scratch, reused from frame to frame).
  void Discretize(const std::vector<Eigen::Vector3f>& points,
                  std::vector<Eigen::Vector3f>* out) const;
  void SubvoxelCentroids(const std::vector<Eigen::Vector3f>& points,
                         std::vector<Eigen::Vector3f>* out) const;
  // The two ways of computing the key sets of `points` (already reduced).
  bool BitmapKeySets(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3f& origin,
                     KeySets* out, InsertStats* stats) const;
  void HashKeySets(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3f& origin,
                   KeySets* out, InsertStats* stats) const;

  KeySetOptions options_;
  octomap::OcTree keyer_;  // empty tree: only its key arithmetic (computeRayKeys) is used
};

// ---------------------------------------------------------------------------------------------

template <class Tree, class Hook>
void ParallelKeySetInserter::Apply(Tree* tree, const KeySets& sets, Hook& hook) {
  const uint64_t* begin = sets.updates.data();
  const uint64_t* end = begin + sets.updates.size();
  if (begin == end) return;
  if (tree->getRoot() == nullptr) {
    // The root can only be created through updateNode: let it apply the first update.
    const octomap::OcTreeKey key = KeyFromMorton(*begin >> 1);
    tree->updateNode(key, (*begin & 1) != 0, false);
    if (*begin & 1) hook.Leaf(tree->search(key), begin);  // a fresh path: the leaf itself
    // updateNode re-valued the inner nodes of that fresh path; the hook updates them too
    // (deepest first). Those shared with later keys are visited again by the walk below.
    std::vector<typename Tree::NodeType*> path;
    auto* node = tree->getRoot();
    const unsigned depth = tree->getTreeDepth();
    for (unsigned d = 0; d < depth && tree->nodeHasChildren(node); ++d) {
      path.push_back(node);
      node =
          tree->getNodeChild(node, octomap::computeChildIdx(key, static_cast<int>(depth - 1 - d)));
    }
    for (auto it = path.rbegin(); it != path.rend(); ++it) hook.Inner(*it);
    ++begin;
    if (begin == end) return;
  }
  ApplyRecurs(tree, tree->getRoot(), false, 0, begin, end, hook);
}

// Mirrors OccupancyOcTreeBase::updateNode/updateNodeRecurs (lazy_eval = false) for a sorted
// range of updates sharing this node: a pruned node whose value is already clamped in the
// direction of every update below it is left alone (upstream's early abort); otherwise it is
// expanded; missing children are created; leaves get the hit/miss log-odds with clamping; on the
// way back the node is pruned if possible, else takes the maximum of its children.
template <class Tree, class Node, class Hook>
void ParallelKeySetInserter::ApplyRecurs(Tree* tree, Node* node, bool just_created, unsigned depth,
                                         const uint64_t* begin, const uint64_t* end, Hook& hook) {
  const unsigned max_depth = tree->getTreeDepth();
  if (depth == max_depth) {
    tree->updateNodeLogOdds(node, (*begin & 1) ? tree->getProbHitLog() : tree->getProbMissLog());
    if (*begin & 1) hook.Leaf(node, begin);
    return;
  }
  if (!tree->nodeHasChildren(node) && !just_created) {
    const float v = node->getLogOdds();
    bool all_abort = true;
    for (const uint64_t* p = begin; p != end && all_abort; ++p)
      all_abort =
          (*p & 1) ? v >= tree->getClampingThresMaxLog() : v <= tree->getClampingThresMinLog();
    if (all_abort) {
      hook.Pruned(node, begin, end);
      return;
    }
    tree->expandNode(node);
  }
  const unsigned shift = 3 * (max_depth - 1 - depth) + 1;  // +1: the occupied flag
  for (const uint64_t* p = begin; p != end;) {
    const unsigned idx = static_cast<unsigned>((*p >> shift) & 7);
    const uint64_t* q = p + 1;
    while (q != end && static_cast<unsigned>((*q >> shift) & 7) == idx) ++q;
    bool created = false;
    if (!tree->nodeChildExists(node, idx)) {
      tree->createNodeChild(node, idx);
      created = true;
    }
    ApplyRecurs(tree, tree->getNodeChild(node, idx), created, depth + 1, p, q, hook);
    p = q;
  }
  if (!tree->pruneNode(node)) {
    node->updateOccupancyChildren();
    hook.Inner(node);
  }
}

}  // namespace omni::octo
