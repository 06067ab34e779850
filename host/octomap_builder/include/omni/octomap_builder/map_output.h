// What the builder writes: the tree as .bt/.ot (atomically), its serialised bytes for the bus,
// a 2D grid projected from a height band, and a rendered top view.
#pragma once

#include <memory>
#include <string>
#include <string_view>

#include <octomap/ColorOcTree.h>
#include <octomap/OcTree.h>

#include "omni/common/result.h"
#include "omni/io/grid.h"
#include "omni/io/image_io.h"

namespace omni::octo {

// Binary form (.bt: occupied/free per node; the tree is not modified) or the full form (.ot:
// log-odds per node).
std::string SerializeTree(const octomap::OcTree& tree, bool binary);
// Writes `base`.bt and `base`.ot, each through a temporary file and rename().
Status SaveTree(const octomap::OcTree& tree, const std::string& base);
// Reads a .bt (binary) or .ot (full) file holding an OcTree.
Result<std::unique_ptr<octomap::OcTree>> LoadTree(const std::string& path);
// The same on bytes in memory (an OCTOMAP message's data); errors name `what`.
Result<std::unique_ptr<octomap::OcTree>> ParseTree(const std::string& bytes, bool binary,
                                                   const std::string& what);
// Only the check ParseTree and ParseColorTree make before octomap reads the bytes (header, then
// the node layout walked within the buffer and the tree depth), for `tree_type` "OcTree" or
// "ColorOcTree" (full form only): "" when readable, else why not. Cheap next to building the tree.
std::string CheckTreeBytes(std::string_view bytes, bool binary, const std::string& tree_type);

// A ColorOcTree in the full form (.ot: log-odds and R G B per node; OctoMap has no colour in
// .bt), written through a temporary file and rename(); read back as LoadTree reads (the header
// and node layout checked, then OctoMap's node reader).
std::string SerializeColorTree(const octomap::ColorOcTree& tree);
Status SaveColorTree(const octomap::ColorOcTree& tree, const std::string& path);
Result<std::unique_ptr<octomap::ColorOcTree>> LoadColorTree(const std::string& path);
// The same check and read on bytes already in memory (an OCTOMAP_COLOR message's data); errors
// name `what`.
Result<std::unique_ptr<octomap::ColorOcTree>> ParseColorTree(const std::string& bytes,
                                                             const std::string& what);

// Which map axis is "up" (z for the robot's map frame; camera-posed datasets often have -y).
// The grid's x, y are the remaining axes in right-handed order: up z -> (x, y), up y -> (z, x),
// up x -> (y, z); a negative up axis mirrors the grid's second axis.
struct UpAxis {
  int axis = 2;  // 0 x, 1 y, 2 z
  int sign = 1;  // +1 or -1
  // Parses "x", "-y", "z", ...; false for anything else.
  static bool Parse(const std::string& text, UpAxis* out);
};

struct GridProjectionOptions {
  double min_z_m = 0.05;  // height band along `up`: voxels overlapping [min_z, max_z] count
  double max_z_m = 1.8;
  double resolution_m = 0;  // grid cell edge; 0: the tree's resolution
  UpAxis up;
};

// Occupied (100) where any occupied leaf overlaps the band above the cell, else free (0) where
// a free leaf does, else unknown (-1). The grid covers the band's known leaves.
Result<io::GridMap> ProjectToGrid(const octomap::OcTree& tree,
                                  const GridProjectionOptions& options);

// Top view of the occupied voxels, one pixel per leaf column, coloured by the height of the
// highest occupied voxel (blue low .. red high), light grey where only free space is known.
// A map wider than kMaxTopViewPixels at one pixel per leaf is drawn with pixels of 2, 4, 8 ...
// leaves (the highest voxel under each); an empty tree is one grey pixel.
inline constexpr double kMaxTopViewPixels = 16e6;
io::Image RenderTopView(const octomap::OcTree& tree, const UpAxis& up = {});
// The same view with each pixel in the colour of its highest occupied voxel (by height where
// that voxel has no colour).
io::Image RenderTopViewColor(const octomap::ColorOcTree& tree, const UpAxis& up = {});

}  // namespace omni::octo
