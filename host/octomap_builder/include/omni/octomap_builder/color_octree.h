// Colour for the ColorOcTree: the scan's key sets are applied with ParallelKeySetInserter::Apply
// (the same occupancy as an OcTree gets) and, in the same walk, each occupied voxel of the scan
// integrates the mean colour of the scan's points inside it; inner nodes take the average of
// their children's colours (ColorOcTreeNode::updateColorChildren), so the tree is always as
// ColorOcTree::updateInnerOccupancy() would leave it.
//
// Integration rule (per voxel, per scan; c = the scan's mean colour in the voxel, p = the
// voxel's occupancy probability after this scan's hit):
//   no colour yet:  colour = c
//   else:           colour = round(p * colour + (1 - p) * c)
// OctoMap's ColorOcTree::integrateNodeColor weights the same way but with (0.99 - p) for the
// new colour, so its weights sum to 0.99 and truncate: a voxel seen many times drifts darker
// (towards 2/3 of its colour once clamped at p = 0.971). Ours sum to 1 and round, so a voxel
// seen in the same colour keeps it. A pruned voxel (already clamped, left alone by the
// insertion) integrates the colours of its updates in order, as integrateNodeColor on the
// pruned node found by search() would.
// OctoMap reads (255, 255, 255) as "no colour", so pure white is stored as (254, 254, 254).
#pragma once

#include <cstdint>
#include <vector>

#include <octomap/ColorOcTree.h>
#include <Eigen/Core>

#include "omni/octomap_builder/key_set_inserter.h"

namespace omni::octo {

// Mean colour of the scan's points per occupied key, aligned with KeySets::updates.
struct ScanColors {
  std::vector<uint32_t> of_update;  // PackRgb(mean) for coloured occupied updates, else 0
  size_t colored_keys = 0;          // occupied keys with a colour
};

// `points` (map frame) with `colors` (one per point, PackRgb or 0) as given to the insertion
// before any filtering; points beyond `max_range_m` from `origin` (< 0: unlimited) add no
// occupied voxel and so no colour. Points whose voxel is not occupied in `sets` (moved by a
// voxel filter) are ignored.
ScanColors ComputeScanColors(const octomap::ColorOcTree& tree, const KeySets& sets,
                             const std::vector<Eigen::Vector3f>& points,
                             const std::vector<uint32_t>& colors, const Eigen::Vector3f& origin,
                             double max_range_m);

// The integration rule above on one node (its occupancy already updated).
void IntegrateColor(octomap::ColorOcTreeNode* node, uint32_t packed_rgb);

// The hook given to ParallelKeySetInserter::Apply for a ColorOcTree.
class ColorIntegrationHook {
 public:
  ColorIntegrationHook(const KeySets& sets, const ScanColors& colors)
      : base_(sets.updates.data()), colors_(colors.of_update.data()) {}
  void Leaf(octomap::ColorOcTreeNode* node, const uint64_t* update) {
    const uint32_t c = colors_[update - base_];
    if (c != 0) IntegrateColor(node, c);
  }
  void Pruned(octomap::ColorOcTreeNode* node, const uint64_t* begin, const uint64_t* end) {
    for (const uint64_t* p = begin; p != end; ++p)
      if ((*p & 1) && colors_[p - base_] != 0) IntegrateColor(node, colors_[p - base_]);
  }
  void Inner(octomap::ColorOcTreeNode* node) { node->updateColorChildren(); }

 private:
  const uint64_t* base_;
  const uint32_t* colors_;
};

// Applies a scan to a ColorOcTree: occupancy exactly as Apply on an OcTree, colours as above.
void ApplyColored(octomap::ColorOcTree* tree, const KeySets& sets, const ScanColors& colors);

}  // namespace omni::octo
