// Comparing two OctoMaps voxel by voxel at the finest level (a pruned leaf counts as all the
// voxels it covers), for the benchmark's agreement figure and the round-trip tests.
#pragma once

#include <cstddef>

#include <octomap/OcTree.h>

namespace omni::octo {

struct OccupiedComparison {
  size_t occupied_a = 0;    // occupied voxels of a
  size_t occupied_b = 0;    // occupied voxels of b
  size_t intersection = 0;  // voxels occupied in both
  double iou = 0;           // intersection / union (1 when both are empty)
};

// Trees must have the same resolution (and so the same key space).
OccupiedComparison CompareOccupied(const octomap::OcTree& a, const octomap::OcTree& b);

// True when both trees have the same leaves (key, depth) with log-odds within `tolerance`.
bool SameLeaves(const octomap::OcTree& a, const octomap::OcTree& b, float tolerance = 1e-4f);

}  // namespace omni::octo
