// Grids as map_fusion receives them: two or three occupancy_grid_t messages, each through
// bus::FromGridMessage as the node takes them, then aligned and voted by Fuse, twice (the second
// time from the first's alignments, as the node fuses again when a map changed). The grids'
// size, cell size, origin, heading and cells come from the input, absurd cell sizes and origins
// among them. What must hold: a fusion gives a grid of the base map's size with cells -1, 0 or
// 100 and vote counts that add up to at most its cells, and every alignment it reports is finite.
// Seeds: an L-shaped corridor seen by three "mappers", shifted, turned and at other cell sizes.
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "fuzz.h"
#include "omni/bus/convert.h"
#include "omni/map_fusion/fusion.h"
#include "omni/occupancy_grid_t.hpp"
#include "quiet_logs.h"

namespace {

constexpr int kMaxSide = 80;

// Cell sizes: mostly ordinary (1 cm to 20 cm); a few codes give what a foreign publisher could
// send and FromGridMessage lets through unless it refuses them.
double Resolution(omni::fuzz::Reader& r) {
  const uint8_t code = r.U8();
  switch (code) {
    case 250:
      return 1e-300;
    case 251:
      return 1e300;
    case 252:
      return 1e-6;
    case 253:
      return 1e3;
    case 254:
      return std::numeric_limits<double>::denorm_min();
    case 255:
      return 0.0;
    default:
      return 0.01 + 0.19 * code / 249.0;
  }
}

double Offset(omni::fuzz::Reader& r) {
  const uint8_t code = r.U8();
  switch (code) {
    case 252:
      return 9.9e5;
    case 253:
      return -1e7;
    case 254:
      return std::numeric_limits<double>::quiet_NaN();
    case 255:
      return 1e300;
    default:
      return (static_cast<int>(code) - 126) * 0.05;  // about +-6 m
  }
}

omni::occupancy_grid_t Grid(omni::fuzz::Reader& r, int index) {
  omni::occupancy_grid_t g{};
  g.utime = 1000000;
  g.source = "fuzz" + std::to_string(index);
  g.frame = "map";
  g.width = r.U8() % (kMaxSide + 1);
  g.height = r.U8() % (kMaxSide + 1);
  g.resolution_m = Resolution(r);
  g.origin_x_m = Offset(r);
  g.origin_y_m = Offset(r);
  const uint8_t yaw = r.U8();
  g.origin_yaw_rad = yaw == 255 ? std::numeric_limits<double>::infinity() : (yaw - 128) * 0.025;
  g.num_cells = g.width * g.height;
  g.encoding = omni::occupancy_grid_t::ENCODING_RAW;
  // Cells: each input byte is one cell (unknown, free, occupied, or any value as sent), a run
  // of the input's cells repeated to fill the grid.
  const size_t run = r.U16() % 2048;
  const std::string cells = r.Bytes(run);
  g.data.resize(static_cast<size_t>(g.num_cells));
  for (size_t i = 0; i < g.data.size(); ++i) {
    const uint8_t c = cells.empty() ? 0 : static_cast<uint8_t>(cells[i % cells.size()]);
    g.data[i] = c < 3 ? (c == 0 ? -1 : c == 1 ? 0 : 100) : static_cast<int8_t>(c);
  }
  g.num_bytes = static_cast<int32_t>(g.data.size());
  return g;
}

void CheckFusion(const omni::map_fusion::FusionResult& f,
                 const std::vector<omni::map_fusion::SourceMap>& maps, size_t min_maps) {
  const omni::io::GridMap* base = nullptr;
  for (const auto& m : maps)
    if (m.name == f.base) base = &m.map;
  OMNI_FUZZ_CHECK(base != nullptr);
  OMNI_FUZZ_CHECK(f.fused.width == base->width && f.fused.height == base->height);
  OMNI_FUZZ_CHECK(f.fused.cells.size() == static_cast<size_t>(f.fused.width) * f.fused.height);
  for (int8_t c : f.fused.cells) OMNI_FUZZ_CHECK(c == -1 || c == 0 || c == 100);
  OMNI_FUZZ_CHECK(f.unanimous + f.majority + f.ties <= f.fused.cells.size());
  OMNI_FUZZ_CHECK(f.sources.size() == maps.size());
  OMNI_FUZZ_CHECK(f.maps_used >= min_maps && f.maps_used <= maps.size());
  for (const auto& s : f.sources) {
    if (!s.used) continue;
    const auto& a = s.alignment;
    OMNI_FUZZ_CHECK(std::isfinite(a.rotation_rad) && std::isfinite(a.dx_m) &&
                    std::isfinite(a.dy_m));
    OMNI_FUZZ_CHECK(s.overlap_fraction >= 0 && s.overlap_fraction <= 1);
    OMNI_FUZZ_CHECK(s.conflict_fraction >= 0 && s.conflict_fraction <= 1);
    OMNI_FUZZ_CHECK(s.walls_on_base_free >= 0 && s.walls_on_base_free <= 1);
    OMNI_FUZZ_CHECK(s.base_walls_on_free >= 0 && s.base_walls_on_free <= 1);
    // The combined share lies between the two ways' shares.
    OMNI_FUZZ_CHECK(
        s.conflict_fraction >= std::min(s.walls_on_base_free, s.base_walls_on_free) - 1e-12 &&
        s.conflict_fraction <= std::max(s.walls_on_base_free, s.base_walls_on_free) + 1e-12);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  omni::fuzz::QuietLogs();
  omni::fuzz::Reader r(data, size);
  const int n = 2 + r.U8() % 2;
  std::vector<omni::map_fusion::SourceMap> maps;
  for (int i = 0; i < n; ++i) {
    auto map = omni::bus::FromGridMessage(Grid(r, i));
    if (!map.ok()) continue;  // refused on arrival, counted by the node
    maps.push_back({"map" + std::to_string(i), std::move(*map)});
  }
  omni::map_fusion::FusionOptions options;
  options.min_maps = 2;
  options.align.threads = 1;
  omni::map_fusion::AlignmentHints hints;
  for (int pass = 0; pass < 2; ++pass) {
    auto fused = omni::map_fusion::Fuse(maps, options, &hints);
    if (fused.ok()) CheckFusion(*fused, maps, static_cast<size_t>(options.min_maps));
  }
  return 0;
}

namespace {

// An L-shaped corridor on a w x h grid of `res` cells: walls occupied, the floor free, the rest
// unknown, as byte codes 2, 1 and 0.
std::string Corridor(int w, int h) {
  std::string cells(static_cast<size_t>(w) * h, '\0');
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const bool in_h = y >= h / 3 && y < h / 3 + 6 && x >= 4 && x < w - 4;
      const bool in_v = x >= w / 2 && x < w / 2 + 6 && y >= 4 && y < h - 4;
      const bool wall_h = (y == h / 3 - 1 || y == h / 3 + 6) && x >= 3 && x < w - 3;
      const bool wall_v = (x == w / 2 - 1 || x == w / 2 + 6) && y >= 3 && y < h - 3;
      char c = 0;
      if (in_h || in_v)
        c = 1;
      else if (wall_h || wall_v)
        c = 2;
      cells[static_cast<size_t>(y) * w + x] = c;
    }
  return cells;
}

std::string GridBytes(int w, int h, uint8_t res_code, uint8_t ox, uint8_t oy, uint8_t yaw) {
  std::string s;
  s += static_cast<char>(w);
  s += static_cast<char>(h);
  s += static_cast<char>(res_code);
  s += static_cast<char>(ox);
  s += static_cast<char>(oy);
  s += static_cast<char>(yaw);
  const std::string cells = Corridor(w, h);
  s += static_cast<char>(cells.size() & 0xff);
  s += static_cast<char>(cells.size() >> 8);
  return s + cells;
}

}  // namespace

void omni::fuzz::Seeds(SeedList* seeds) {
  // 5 cm cells (code 53), the second map shifted by 10 cm and turned by 0.05 rad, the third at
  // 4 cm cells (code 39) on a larger grid.
  const std::string a = GridBytes(40, 40, 53, 126, 126, 128);
  const std::string b = GridBytes(40, 40, 53, 128, 126, 130);
  const std::string c = GridBytes(50, 50, 39, 126, 124, 128);
  seeds->Add(std::string(1, '\x01') + a + b + c);
  seeds->Add(std::string(1, '\x00') + a + b);
  seeds->Add(std::string(1, '\x00') + a + a);
  // The second map at each absurd cell size, far out or turned by a NaN-free extreme.
  for (uint8_t res : {250, 251, 252, 253, 254})
    seeds->Add(std::string(1, '\x01') + a + GridBytes(40, 40, res, 126, 126, 128) + c);
  seeds->Add(std::string(1, '\x00') + a + GridBytes(40, 40, 53, 252, 253, 0));
}
