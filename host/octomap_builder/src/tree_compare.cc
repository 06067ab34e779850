#include "omni/octomap_builder/tree_compare.h"

#include <cmath>
#include <map>
#include <tuple>

namespace omni::octo {
namespace {

// Calls f(key) for every finest-level voxel of the occupied leaves of `t`.
template <class F>
void ForEachOccupiedVoxel(const octomap::OcTree& t, F&& f) {
  const unsigned max_depth = t.getTreeDepth();
  for (auto it = t.begin_leafs(), end = t.end_leafs(); it != end; ++it) {
    if (!t.isNodeOccupied(*it)) continue;
    const unsigned level = max_depth - it.getDepth();
    const octomap::OcTreeKey base = it.getIndexKey();
    const unsigned n = 1u << level;
    for (unsigned dx = 0; dx < n; ++dx)
      for (unsigned dy = 0; dy < n; ++dy)
        for (unsigned dz = 0; dz < n; ++dz)
          f(octomap::OcTreeKey(static_cast<uint16_t>(base[0] + dx),
                               static_cast<uint16_t>(base[1] + dy),
                               static_cast<uint16_t>(base[2] + dz)));
  }
}

}  // namespace

OccupiedComparison CompareOccupied(const octomap::OcTree& a, const octomap::OcTree& b) {
  OccupiedComparison c;
  ForEachOccupiedVoxel(a, [&](const octomap::OcTreeKey& k) {
    ++c.occupied_a;
    const octomap::OcTreeNode* n = b.search(k);
    if (n && b.isNodeOccupied(n)) ++c.intersection;
  });
  ForEachOccupiedVoxel(b, [&](const octomap::OcTreeKey&) { ++c.occupied_b; });
  const size_t uni = c.occupied_a + c.occupied_b - c.intersection;
  c.iou = uni == 0 ? 1.0 : static_cast<double>(c.intersection) / static_cast<double>(uni);
  return c;
}

bool SameLeaves(const octomap::OcTree& a, const octomap::OcTree& b, float tolerance) {
  if (a.getResolution() != b.getResolution()) return false;
  using Id = std::tuple<uint16_t, uint16_t, uint16_t, unsigned>;
  std::map<Id, float> la;
  for (auto it = a.begin_leafs(), end = a.end_leafs(); it != end; ++it) {
    const auto k = it.getKey();
    la[Id(k[0], k[1], k[2], it.getDepth())] = it->getLogOdds();
  }
  size_t nb = 0;
  for (auto it = b.begin_leafs(), end = b.end_leafs(); it != end; ++it) {
    ++nb;
    const auto k = it.getKey();
    auto f = la.find(Id(k[0], k[1], k[2], it.getDepth()));
    if (f == la.end() || std::fabs(f->second - it->getLogOdds()) > tolerance) return false;
  }
  return nb == la.size();
}

}  // namespace omni::octo
