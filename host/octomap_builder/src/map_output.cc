#include "omni/octomap_builder/map_output.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iomanip>
#include <limits>
#include <sstream>
#include <string_view>
#include <type_traits>

#include "omni/octomap_builder/color_image.h"
#include "omni/octomap_builder/depth_io.h"

namespace omni::octo {

std::string SerializeTree(const octomap::OcTree& tree, bool binary) {
  std::ostringstream s(std::ios::binary);
  if (binary) {
    // The .bt header, then OctoMap's own node data. (OctoMap's writeBinaryConst writes the same
    // form but then prints " done." on stderr, which put a line in the node's log for every
    // OCTOMAP message and every save.) The first line is what readers look for; lines starting
    // with '#' are comments; the resolution is written with every digit a double holds.
    s << "# Octomap OcTree binary file\n# written by omni\nid " << tree.getTreeType() << "\nsize "
      << tree.size() << "\nres " << std::setprecision(std::numeric_limits<double>::max_digits10)
      << tree.getResolution() << "\ndata\n";
    tree.writeBinaryData(s);
  } else {
    tree.write(s);
  }
  return s.str();
}

Status SaveTree(const octomap::OcTree& tree, const std::string& base) {
  if (Status s = WriteFileAtomic(base + ".bt", SerializeTree(tree, true)); !s.ok()) return s;
  return WriteFileAtomic(base + ".ot", SerializeTree(tree, false));
}

namespace {

// OctoMap's readers recurse on child bits read from the stream and never check for the end of
// it, so a truncated or corrupt file can recurse without bound (a stack overflow). These walk
// the same node layout over the bytes first, bounded by the buffer and the tree depth.
//   full (.ot):   node = value (float) [+ R G B for a ColorOcTree] + 1 byte, bit i set: child i
//                 follows (depth first)
//   binary (.bt): node = 2 bytes, 2 bits per child (11: inner, its node follows afterwards)
// `nodes` counts the nodes the reader will create, which it then compares with the header's size.
bool WalkFull(std::string_view b, size_t* pos, int depth, size_t node_size, long long* nodes) {
  if (b.size() - *pos < node_size) return false;
  const auto mask = static_cast<uint8_t>(b[*pos + node_size - 1]);
  *pos += node_size;
  ++*nodes;
  if (mask != 0 && depth >= 16) return false;
  for (int i = 0; i < 8; ++i)
    if ((mask >> i) & 1)
      if (!WalkFull(b, pos, depth + 1, node_size, nodes)) return false;
  return true;
}

// (Each child whose bits are not 00 is a node: 01 and 10 are leaves without a record of their own.)
bool WalkBinary(std::string_view b, size_t* pos, int depth, long long* nodes) {
  if (b.size() - *pos < 2) return false;
  const unsigned bits = static_cast<uint8_t>(b[*pos]) | (static_cast<uint8_t>(b[*pos + 1]) << 8);
  *pos += 2;
  for (int i = 0; i < 8; ++i) {
    const unsigned child = (bits >> (2 * i)) & 3;
    if (child != 0) ++*nodes;
    if (child != 3) continue;
    if (depth + 1 >= 16) return false;
    if (!WalkBinary(b, pos, depth + 1, nodes)) return false;
  }
  return true;
}

// What the header says: the resolution, the node count and where the node data starts.
struct TreeHeader {
  double resolution = 0;
  long long size = 0;
  size_t data = 0;
};

// Checks the header ("id <type>", "size N", "res R", "data") and the node layout after it. A full
// node is its data (`node_bytes`: 4 for OcTree's float, 7 for ColorOcTree's float + RGB) and a
// child-mask byte.
std::string ValidateTreeFile(std::string_view bytes, bool binary,
                             const std::string& type = "OcTree", size_t node_bytes = 4,
                             TreeHeader* out = nullptr) {
  // OctoMap's readers refuse a file whose first line is not theirs (and print why to stderr).
  const std::string_view first = binary ? "# Octomap OcTree binary file" : "# Octomap OcTree file";
  if (bytes.substr(0, first.size()) != first)
    return "the first line is not '" + std::string(first) + "'";
  const size_t data = bytes.find("\ndata\n");
  if (data == std::string_view::npos) return "no 'data' line in the header";
  const std::string header(bytes.substr(0, data));
  const std::string id = "\nid " + type;
  const size_t at = header.find(id);
  if (at == std::string::npos ||
      (at + id.size() < header.size() &&
       !std::isspace(static_cast<unsigned char>(header[at + id.size()]))))
    return "not an " + type + " (id line)";
  const size_t sz = header.find("\nsize ");
  if (sz == std::string::npos) return "no 'size' line in the header";
  const long long n = std::atoll(header.c_str() + sz + 6);
  if (n < 0) return "a negative size in the header";
  // OctoMap's file readers refuse a resolution that is not a positive number; its node readers,
  // which ParseTree calls, never see the header, so the check refuses it here (0, a negative or
  // a non-finite one would turn every coordinate of the tree into inf or NaN).
  const size_t rs = header.find("\nres ");
  if (rs == std::string::npos) return "no 'res' line in the header";
  const double res = std::strtod(header.c_str() + rs + 5, nullptr);
  if (!(res > 0) || !std::isfinite(res)) return "the resolution is not a positive number";
  if (out) *out = {res, n, data + 6};
  if (n == 0) return "";
  size_t pos = data + 6;
  long long nodes = binary ? 1 : 0;  // the binary form has no record for the root itself
  const bool ok = binary ? WalkBinary(bytes, &pos, 0, &nodes)
                         : WalkFull(bytes, &pos, 0, node_bytes + 1, &nodes);
  if (!ok) return "truncated or corrupt node data";
  if (nodes != n)
    return "the header's size is " + std::to_string(n) + " nodes, the data holds " +
           std::to_string(nodes);
  return "";
}

}  // namespace

Result<std::unique_ptr<octomap::OcTree>> LoadTree(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  if (!file) return MakeError(ErrorCode::kNotFound, "cannot open " + path);
  std::stringstream buf;
  buf << file.rdbuf();
  const bool binary = path.size() >= 3 && path.compare(path.size() - 3, 3, ".bt") == 0;
  return ParseTree(buf.str(), binary, path);
}

std::string CheckTreeBytes(std::string_view bytes, bool binary, const std::string& tree_type) {
  if (tree_type == "ColorOcTree")
    return binary ? "a ColorOcTree has no binary form"
                  : ValidateTreeFile(bytes, false, tree_type, 7);
  if (tree_type != "OcTree") return "tree type '" + tree_type + "' is not OcTree or ColorOcTree";
  return ValidateTreeFile(bytes, binary);
}

namespace {

// The node data after a checked header, read by OctoMap's own node readers. (Its file readers,
// readBinary and AbstractOcTree::read, parse the same header but print "Reading ... octree
// type" on stderr for every tree.) The count read must be the header's.
template <class Tree>
Result<std::unique_ptr<Tree>> ReadNodes(const std::string& bytes, const TreeHeader& h, bool binary,
                                        const std::string& what, const std::string& form) {
  auto tree = std::make_unique<Tree>(h.resolution);
  if (h.size > 0) {
    std::istringstream in(bytes.substr(h.data), std::ios::binary);
    if (binary) {
      if constexpr (std::is_same_v<Tree, octomap::OcTree>) tree->readBinaryData(in);
    } else {
      tree->readData(in);
    }
    if (in.fail()) return MakeError(ErrorCode::kParse, what + ": not a readable " + form);
  }
  if (static_cast<long long>(tree->size()) != h.size)
    return MakeError(ErrorCode::kParse, what + ": not a readable " + form +
                                            ": the header's size is " + std::to_string(h.size) +
                                            " nodes, the data holds " +
                                            std::to_string(tree->size()));
  return tree;
}

}  // namespace

Result<std::unique_ptr<octomap::OcTree>> ParseTree(const std::string& bytes, bool binary,
                                                   const std::string& what) {
  TreeHeader h;
  const std::string form = std::string(binary ? ".bt" : ".ot") + " OcTree";
  if (const std::string bad = ValidateTreeFile(bytes, binary, "OcTree", 4, &h); !bad.empty())
    return MakeError(ErrorCode::kParse, what + ": not a readable " + form + ": " + bad);
  return ReadNodes<octomap::OcTree>(bytes, h, binary, what, form);
}

std::string SerializeColorTree(const octomap::ColorOcTree& tree) {
  std::ostringstream s(std::ios::binary);
  tree.write(s);
  return s.str();
}

Status SaveColorTree(const octomap::ColorOcTree& tree, const std::string& path) {
  return WriteFileAtomic(path, SerializeColorTree(tree));
}

Result<std::unique_ptr<octomap::ColorOcTree>> LoadColorTree(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  if (!file) return MakeError(ErrorCode::kNotFound, "cannot open " + path);
  std::stringstream buf;
  buf << file.rdbuf();
  return ParseColorTree(buf.str(), path);
}

Result<std::unique_ptr<octomap::ColorOcTree>> ParseColorTree(const std::string& bytes,
                                                             const std::string& what) {
  TreeHeader h;
  if (const std::string bad = ValidateTreeFile(bytes, false, "ColorOcTree", 7, &h); !bad.empty())
    return MakeError(ErrorCode::kParse, what + ": not a readable .ot ColorOcTree: " + bad);
  return ReadNodes<octomap::ColorOcTree>(bytes, h, false, what, ".ot ColorOcTree");
}

bool UpAxis::Parse(const std::string& text, UpAxis* out) {
  std::string t = text;
  int sign = 1;
  if (!t.empty() && (t[0] == '-' || t[0] == '+')) {
    sign = t[0] == '-' ? -1 : 1;
    t = t.substr(1);
  }
  if (t != "x" && t != "y" && t != "z") return false;
  out->axis = t[0] - 'x';
  out->sign = sign;
  return true;
}

namespace {
// (grid x, grid y, height) of a map point for an up axis.
struct Planar {
  double u, v, h;
};
Planar ToPlanar(double x, double y, double z, const UpAxis& up) {
  const double p[3] = {x, y, z};
  const int a = up.axis, b = (up.axis + 1) % 3, c = (up.axis + 2) % 3;
  return {p[b], up.sign * p[c], up.sign * p[a]};
}
}  // namespace

Result<io::GridMap> ProjectToGrid(const octomap::OcTree& tree, const GridProjectionOptions& o) {
  if (!(o.max_z_m > o.min_z_m))
    return MakeError(ErrorCode::kInvalidArgument, "grid projection: need min_z_m < max_z_m");
  const double res = o.resolution_m > 0 ? o.resolution_m : tree.getResolution();
  // Pass 1: extent of the leaves in the band.
  double min_x = std::numeric_limits<double>::max(), min_y = min_x;
  double max_x = std::numeric_limits<double>::lowest(), max_y = max_x;
  auto in_band = [&](double z, double half) {
    return z + half > o.min_z_m && z - half < o.max_z_m;
  };
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const double half = it.getSize() / 2;
    const Planar p = ToPlanar(it.getX(), it.getY(), it.getZ(), o.up);
    if (!in_band(p.h, half)) continue;
    min_x = std::min(min_x, p.u - half);
    min_y = std::min(min_y, p.v - half);
    max_x = std::max(max_x, p.u + half);
    max_y = std::max(max_y, p.v + half);
  }
  io::GridMap g;
  g.resolution_m = res;
  if (min_x > max_x) return g;  // nothing known in the band: an empty grid
  g.origin_x_m = std::floor(min_x / res) * res;
  g.origin_y_m = std::floor(min_y / res) * res;
  const double cols = std::ceil((max_x - g.origin_x_m) / res - 1e-9);
  const double rows = std::ceil((max_y - g.origin_y_m) / res - 1e-9);
  // Checked before the casts to int: no receiver takes more than io::kMaxGridCells cells.
  if (!(cols * rows <= static_cast<double>(io::kMaxGridCells)))
    return MakeError(ErrorCode::kOutOfRange,
                     "grid projection: a " + std::to_string(static_cast<int64_t>(cols)) + " x " +
                         std::to_string(static_cast<int64_t>(rows)) +
                         " grid is more than a grid message carries (2^28 cells)");
  g.width = static_cast<int>(cols);
  g.height = static_cast<int>(rows);
  g.cells.assign(static_cast<size_t>(g.width) * g.height, -1);
  // Pass 2: cells covered by each leaf's footprint (cell centres inside it).
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const double half = it.getSize() / 2;
    const Planar p = ToPlanar(it.getX(), it.getY(), it.getZ(), o.up);
    if (!in_band(p.h, half)) continue;
    const bool occ = tree.isNodeOccupied(*it);
    const int c0 =
        std::max(0, static_cast<int>(std::floor((p.u - half - g.origin_x_m) / res + 1e-6)));
    const int c1 =
        std::min(g.width, static_cast<int>(std::ceil((p.u + half - g.origin_x_m) / res - 1e-6)));
    const int r0 =
        std::max(0, static_cast<int>(std::floor((p.v - half - g.origin_y_m) / res + 1e-6)));
    const int r1 =
        std::min(g.height, static_cast<int>(std::ceil((p.v + half - g.origin_y_m) / res - 1e-6)));
    for (int r = r0; r < r1; ++r)
      for (int c = c0; c < c1; ++c) {
        int8_t& cell = g.at(c, r);
        if (occ)
          cell = 100;
        else if (cell < 0)
          cell = 0;
      }
  }
  return g;
}

namespace {

// `color_of(node)`: PackRgb of a voxel's own colour, or 0 to colour it by height.
template <class Tree, class ColorOf>
io::Image RenderTop(const Tree& tree, const UpAxis& up, ColorOf color_of) {
  const double res = tree.getResolution();
  if (tree.size() == 0) return io::Image::Make(1, 1, 3, 128);
  double x0 = std::numeric_limits<double>::max(), y0 = x0;
  double x1 = std::numeric_limits<double>::lowest(), y1 = x1;
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const double half = it.getSize() / 2;
    const Planar p = ToPlanar(it.getX(), it.getY(), it.getZ(), up);
    x0 = std::min(x0, p.u - half);
    y0 = std::min(y0, p.v - half);
    x1 = std::max(x1, p.u + half);
    y1 = std::max(y1, p.v + half);
  }
  // One pixel per leaf column, or per 2, 4, 8 ... of them when that would be too many pixels
  // (a 1 cm tree over its whole key range is 65536 x 65536): a coarser view, never none.
  double pix = res;
  while (std::ceil((x1 - x0) / pix) * std::ceil((y1 - y0) / pix) > kMaxTopViewPixels) pix *= 2;
  const int w = std::max(1, static_cast<int>(std::ceil((x1 - x0) / pix - 1e-6)));
  const int h = std::max(1, static_cast<int>(std::ceil((y1 - y0) / pix - 1e-6)));
  std::vector<float> top(static_cast<size_t>(w) * h, -std::numeric_limits<float>::infinity());
  std::vector<uint8_t> known(static_cast<size_t>(w) * h, 0);
  std::vector<uint32_t> top_rgb(static_cast<size_t>(w) * h, 0);  // colour of the top voxel
  double zmin = std::numeric_limits<double>::max(), zmax = std::numeric_limits<double>::lowest();
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const double half = it.getSize() / 2;
    const bool occ = tree.isNodeOccupied(*it);
    const Planar p = ToPlanar(it.getX(), it.getY(), it.getZ(), up);
    const int c0 = std::max(0, static_cast<int>(std::floor((p.u - half - x0) / pix + 1e-6)));
    const int c1 = std::min(w, static_cast<int>(std::ceil((p.u + half - x0) / pix - 1e-6)));
    const int r0 = std::max(0, static_cast<int>(std::floor((p.v - half - y0) / pix + 1e-6)));
    const int r1 = std::min(h, static_cast<int>(std::ceil((p.v + half - y0) / pix - 1e-6)));
    const float ztop = static_cast<float>(p.h + half);
    if (occ) {
      zmin = std::min(zmin, p.h);
      zmax = std::max(zmax, p.h);
    }
    for (int r = r0; r < r1; ++r)
      for (int c = c0; c < c1; ++c) {
        const size_t i = static_cast<size_t>(r) * w + c;
        known[i] = 1;
        if (occ && ztop > top[i]) {
          top[i] = ztop;
          top_rgb[i] = color_of(*it);
        }
      }
  }
  io::Image im = io::Image::Make(w, h, 3, 40);  // dark: never seen
  const double span = zmax > zmin ? zmax - zmin : 1.0;
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      const size_t i = static_cast<size_t>(r) * w + c;
      const int y = h - 1 - r;  // north up
      if (std::isfinite(top[i]) && top_rgb[i] != 0) {
        im.at(c, y, 0) = static_cast<uint16_t>((top_rgb[i] >> 16) & 0xff);
        im.at(c, y, 1) = static_cast<uint16_t>((top_rgb[i] >> 8) & 0xff);
        im.at(c, y, 2) = static_cast<uint16_t>(top_rgb[i] & 0xff);
      } else if (std::isfinite(top[i])) {
        const double f = std::clamp((top[i] - zmin) / span, 0.0, 1.0);
        // blue -> green -> red
        const double rr = std::clamp(2 * f - 1, 0.0, 1.0), bb = std::clamp(1 - 2 * f, 0.0, 1.0);
        const double gg = 1 - rr - bb;
        im.at(c, y, 0) = static_cast<uint16_t>(40 + 215 * rr);
        im.at(c, y, 1) = static_cast<uint16_t>(40 + 215 * gg);
        im.at(c, y, 2) = static_cast<uint16_t>(40 + 215 * bb);
      } else if (known[i]) {
        for (int ch = 0; ch < 3; ++ch) im.at(c, y, ch) = 225;
      }
    }
  return im;
}

}  // namespace

io::Image RenderTopView(const octomap::OcTree& tree, const UpAxis& up) {
  return RenderTop(tree, up, [](const octomap::OcTreeNode&) { return uint32_t{0}; });
}

io::Image RenderTopViewColor(const octomap::ColorOcTree& tree, const UpAxis& up) {
  return RenderTop(tree, up, [](const octomap::ColorOcTreeNode& n) -> uint32_t {
    if (!n.isColorSet()) return 0;
    const auto c = n.getColor();
    return PackRgb(c.r, c.g, c.b);
  });
}

}  // namespace omni::octo
