#include "omni/octomap_builder/color_octree.h"

#include <algorithm>
#include <cmath>

#include "omni/octomap_builder/color_image.h"

namespace omni::octo {
namespace {

inline uint64_t Mix(uint64_t k) {
  k ^= k >> 31;
  k *= 0x9E3779B97F4A7C15ull;
  k ^= k >> 29;
  return k;
}

inline uint64_t Packed(const octomap::OcTreeKey& k) {
  return static_cast<uint64_t>(k[0]) | (static_cast<uint64_t>(k[1]) << 16) |
         (static_cast<uint64_t>(k[2]) << 32);
}

struct ColorSum {
  uint32_t r = 0, g = 0, b = 0, n = 0;
};

uint8_t RoundByte(double v) { return static_cast<uint8_t>(std::clamp(std::lround(v), 0L, 255L)); }

}  // namespace

ScanColors ComputeScanColors(const octomap::ColorOcTree& tree, const KeySets& sets,
                             const std::vector<Eigen::Vector3f>& points,
                             const std::vector<uint32_t>& colors, const Eigen::Vector3f& origin,
                             double max_range_m) {
  ScanColors out;
  out.of_update.assign(sets.updates.size(), 0);
  if (points.size() != colors.size()) return out;
  // Open-addressing map: occupied key (packed x | y << 16 | z << 32, cheaper per point than
  // its Morton code) -> its index among the occupied updates.
  size_t n_occ = 0;
  for (uint64_t u : sets.updates) n_occ += u & 1;
  if (n_occ == 0) return out;
  size_t cap = 64;
  while (cap < 2 * n_occ) cap *= 2;
  const size_t mask = cap - 1;
  constexpr uint64_t kEmpty = ~uint64_t{0};
  std::vector<uint64_t> slot_code(cap, kEmpty);
  std::vector<uint32_t> slot_index(cap, 0);
  std::vector<uint32_t> update_of_occ;  // occupied key k is sets.updates[update_of_occ[k]]
  update_of_occ.reserve(n_occ);
  for (size_t i = 0; i < sets.updates.size(); ++i) {
    if (!(sets.updates[i] & 1)) continue;
    const uint64_t code = Packed(KeyFromMorton(sets.updates[i] >> 1));
    size_t j = Mix(code) & mask;
    while (slot_code[j] != kEmpty) j = (j + 1) & mask;
    slot_code[j] = code;
    slot_index[j] = static_cast<uint32_t>(update_of_occ.size());
    update_of_occ.push_back(static_cast<uint32_t>(i));
  }
  auto find = [&](uint64_t code) -> int64_t {
    size_t j = Mix(code) & mask;
    for (;;) {
      if (slot_code[j] == code) return slot_index[j];
      if (slot_code[j] == kEmpty) return -1;
      j = (j + 1) & mask;
    }
  };
  std::vector<ColorSum> sums(n_occ);
  const octomap::point3d o(origin.x(), origin.y(), origin.z());
  // Neighbouring pixels mostly fall in the same voxel: remember the last lookup.
  uint64_t last_code = kEmpty;
  int64_t last_index = -1;
  for (size_t i = 0; i < points.size(); ++i) {
    const uint32_t c = colors[i];
    if (c == 0) continue;
    const octomap::point3d p(points[i].x(), points[i].y(), points[i].z());
    // The expression the key sets use to decide whether a point adds an occupied voxel.
    if (max_range_m >= 0.0 && (p - o).norm() > max_range_m) continue;
    octomap::OcTreeKey key;
    if (!tree.coordToKeyChecked(p, key)) continue;
    const uint64_t code = Packed(key);
    if (code != last_code) {
      last_code = code;
      last_index = find(code);
    }
    if (last_index < 0) continue;
    ColorSum& s = sums[static_cast<size_t>(last_index)];
    s.r += (c >> 16) & 0xff;
    s.g += (c >> 8) & 0xff;
    s.b += c & 0xff;
    ++s.n;
  }
  for (size_t i = 0; i < sums.size(); ++i) {
    const ColorSum& s = sums[i];
    if (s.n == 0) continue;
    const double inv = 1.0 / s.n;
    out.of_update[update_of_occ[i]] =
        PackRgb(RoundByte(s.r * inv), RoundByte(s.g * inv), RoundByte(s.b * inv));
    ++out.colored_keys;
  }
  return out;
}

void IntegrateColor(octomap::ColorOcTreeNode* node, uint32_t packed_rgb) {
  const double r = (packed_rgb >> 16) & 0xff, g = (packed_rgb >> 8) & 0xff, b = packed_rgb & 0xff;
  octomap::ColorOcTreeNode::Color out;
  if (!node->isColorSet()) {
    out = octomap::ColorOcTreeNode::Color(static_cast<uint8_t>(r), static_cast<uint8_t>(g),
                                          static_cast<uint8_t>(b));
  } else {
    const octomap::ColorOcTreeNode::Color prev = node->getColor();
    const double p = node->getOccupancy();
    out = octomap::ColorOcTreeNode::Color(RoundByte(p * prev.r + (1 - p) * r),
                                          RoundByte(p * prev.g + (1 - p) * g),
                                          RoundByte(p * prev.b + (1 - p) * b));
  }
  if (out.r == 255 && out.g == 255 && out.b == 255) out = {254, 254, 254};  // white != unset
  node->setColor(out);
}

void ApplyColored(octomap::ColorOcTree* tree, const KeySets& sets, const ScanColors& colors) {
  ColorIntegrationHook hook(sets, colors);
  ParallelKeySetInserter::Apply(tree, sets, hook);
}

}  // namespace omni::octo
