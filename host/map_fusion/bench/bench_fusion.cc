// omni-bench-fusion (./omni bench fusion): the cost of map_fusion's alignment search, bounded
// (`align.max_cells`, what map_fusion ships) beside unbounded (every occupied cell at every
// level, as before), on the same maps in the same run: each building of
// ../shared/datasets/carmen-corrected mapped from its corrected poses, and a second copy of it
// moved by a known rigid transform (as a mapper that started elsewhere would give it), plus the
// Intel map tiled 3 x 3 (a 90 m floor of real walls: the size where the unbounded search took
// seconds). Prints, per map: occupied cells, search time, the alignment's error against the
// known transform, and the overlap fraction; writes one JSON row per map and mode.
//
// No peer: SLAMfusion's own implementation (paper 003; ROS, OpenCL) is not packaged.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include "omni/common/cli.h"
#include "omni/common/geometry.h"
#include "omni/eval/eval.h"
#include "omni/io/carmen.h"
#include "omni/io/grid.h"
#include "omni/map_fusion/fusion.h"

namespace {

using omni::Pose2;

struct Pair {
  std::string name;
  omni::io::GridMap base, moved;
  Pose2 t;  // a point p of base is at t * p in moved
};

// `t` about the centre of `m` (as map_fusion's search turns a map about its centre): the moved
// copy stays within the search's shift range however far the map lies from its origin.
Pose2 AboutCentre(const omni::io::GridMap& m, const Pose2& t) {
  const Pose2 c(m.origin_x_m + m.width * m.resolution_m / 2,
                m.origin_y_m + m.height * m.resolution_m / 2, 0);
  return c * t * c.Inverse();
}

// The building's map from every fourth scan at its corrected pose, and the same map made at
// poses moved by `t` about the map's centre.
bool MapLog(const std::string& path, const Pose2& t, Pair* out) {
  auto log = omni::io::ReadCarmenLog(path);
  if (!log.ok()) {
    std::cerr << "skipped " << path << ": " << log.error().message << "\n";
    return false;
  }
  for (int pass = 0; pass < 2; ++pass) {
    omni::io::LogOddsGrid g;
    int n = 0;
    for (const auto& r : log->records) {
      if (r.kind != omni::io::CarmenRecord::Kind::kLaser) continue;
      if (++n % 4) continue;
      const auto& l = r.laser;
      g.IntegrateScan(pass == 0 ? l.laser_pose : out->t * l.laser_pose, l.ranges_m, l.angle_min_rad,
                      l.angle_increment_rad, l.max_range_m);
    }
    if (pass == 0) {
      out->base = g.ToGridMap();
      out->t = AboutCentre(out->base, t);
    } else {
      out->moved = g.ToGridMap();
    }
  }
  return true;
}

// `m` repeated k x k times side by side (cells of the later copies win where they overlap).
omni::io::GridMap Tile(const omni::io::GridMap& m, int k) {
  omni::io::GridMap out;
  out.resolution_m = m.resolution_m;
  out.origin_x_m = m.origin_x_m;
  out.origin_y_m = m.origin_y_m;
  out.width = m.width * k;
  out.height = m.height * k;
  out.cells.assign(static_cast<size_t>(out.width) * out.height, -1);
  for (int ty = 0; ty < k; ++ty)
    for (int tx = 0; tx < k; ++tx)
      for (int row = 0; row < m.height; ++row)
        for (int col = 0; col < m.width; ++col) {
          const int8_t v = m.at(col, row);
          if (v >= 0) out.at(tx * m.width + col, ty * m.height + row) = v;
        }
  return out;
}

size_t Occupied(const omni::io::GridMap& m) {
  size_t n = 0;
  for (int8_t v : m.cells) n += omni::eval::NormalizedCell(v) == 1;
  return n;
}

// The largest distance, over points of the base map, between where the alignment puts the moved
// map's copy of a point and the point itself.
double AlignmentError(const Pair& p, const omni::eval::MapAlignment& a) {
  double worst = 0;
  const double x0 = p.base.origin_x_m, y0 = p.base.origin_y_m;
  const double x1 = x0 + p.base.width * p.base.resolution_m;
  const double y1 = y0 + p.base.height * p.base.resolution_m;
  for (const auto& [x, y] :
       {std::pair{x0, y0}, {x1, y0}, {x0, y1}, {x1, y1}, {(x0 + x1) / 2, (y0 + y1) / 2}}) {
    const Eigen::Vector2d q = p.t.Transform({x, y});
    double ax, ay;
    a.Apply(q.x(), q.y(), &ax, &ay);
    worst = std::max(worst, std::hypot(ax - x, ay - y));
  }
  return worst;
}

void Usage(std::FILE* f) {
  std::fprintf(f,
               "usage: omni-bench-fusion [--datasets DIR] [--out FILE] [--max-cells N]\n"
               "  Times map_fusion's alignment search with the shipped bound on the cells it\n"
               "  scores (align.max_cells) beside the unbounded search, on maps of the four\n"
               "  carmen-corrected buildings and the Intel map tiled 3 x 3, each against a copy\n"
               "  moved by a known transform. Writes out/bench/fusion.jsonl by default.\n");
}

}  // namespace

int main(int argc, char** argv) {
  const char* env = std::getenv("OMNI_DATASETS_DIR");
  std::string datasets = env ? env : "../shared/datasets";
  std::string out_path = "out/bench/fusion.jsonl";
  int max_cells = omni::map_fusion::FusionOptions().align.max_cells;
  omni::ArgReader args(argc, argv, "omni-bench-fusion", Usage);
  while (args.Next()) {
    if (args.Is("--datasets")) {
      datasets = args.Value();
    } else if (args.Is("--out")) {
      out_path = args.Value();
    } else if (args.Is("--max-cells")) {
      max_cells = static_cast<int>(args.Integer(1, 100000000));
    } else {
      args.Unknown();
    }
  }
  const Pose2 t(0.6, -0.4, 0.15);  // inside map_fusion's default search (±2 m, ±0.35 rad)
  std::vector<Pair> pairs;
  for (const char* b : {"intel", "aces", "csail", "freiburg-079"}) {
    Pair p;
    p.name = b;
    if (MapLog(datasets + "/carmen-corrected/" + b + "-corrected.log.gz", t, &p))
      pairs.push_back(std::move(p));
  }
  if (pairs.empty()) {
    std::cerr << "omni-bench-fusion: no carmen-corrected log under " << datasets
              << "/carmen-corrected (--datasets DIR)\n";
    return 1;
  }
  if (pairs[0].name == "intel") {
    // The tiled floor: the same transform about the tiled map's own frame.
    Pair big;
    big.name = "intel tiled 3x3";
    big.base = Tile(pairs[0].base, 3);
    big.t = AboutCentre(big.base, t);
    // Rasterise the moved copy from the base through the inverse transform (nearest cell).
    omni::io::GridMap& m = big.moved;
    m = big.base;
    std::fill(m.cells.begin(), m.cells.end(), int8_t{-1});
    const Pose2 inv = big.t.Inverse();
    for (int row = 0; row < m.height; ++row)
      for (int col = 0; col < m.width; ++col) {
        const Eigen::Vector2d q(m.origin_x_m + (col + 0.5) * m.resolution_m,
                                m.origin_y_m + (row + 0.5) * m.resolution_m);
        const Eigen::Vector2d p = inv.Transform(q);
        const int c = static_cast<int>(std::floor((p.x() - m.origin_x_m) / m.resolution_m));
        const int r = static_cast<int>(std::floor((p.y() - m.origin_y_m) / m.resolution_m));
        if (big.base.Contains(c, r)) m.at(col, row) = big.base.at(c, r);
      }
    pairs.push_back(std::move(big));
  }
  std::error_code ec;  // out/bench on a fresh checkout, as the other benches make it
  if (const auto dir = std::filesystem::path(out_path).parent_path(); !dir.empty())
    std::filesystem::create_directories(dir, ec);
  std::ofstream jsonl(out_path);
  if (!jsonl) std::cerr << "omni-bench-fusion: cannot write " << out_path << " (table only)\n";
  std::printf("map_fusion alignment search, full (the default ranges, 6 levels), 2 threads\n");
  std::printf("%-18s %9s | %-28s | %-28s\n", "map", "occupied", "every cell: time, error, ovl",
              ("max_cells " + std::to_string(max_cells) + ": time, error, ovl").c_str());
  for (const Pair& p : pairs) {
    const size_t occ = Occupied(p.moved);
    std::printf("%-18s %9zu", p.name.c_str(), occ);
    for (int bound : {0, max_cells}) {
      omni::eval::MapCompareOptions o = omni::map_fusion::FusionOptions().align;
      o.max_cells = bound;
      o.threads = 2;
      const auto t0 = std::chrono::steady_clock::now();
      const omni::eval::MapAlignment a = omni::eval::AlignMap(p.base, p.moved, o);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      const double err = AlignmentError(p, a);
      const double ovl = a.occupied ? static_cast<double>(a.overlap) / a.occupied : 0.0;
      std::printf(" | %7.3f s %8.3f m %7.3f", s, err, ovl);
      std::fflush(stdout);
      if (jsonl)
        jsonl << "{\"system\":\"omni_map_fusion_align\",\"map\":\"" << p.name
              << "\",\"occupied\":" << occ << ",\"max_cells\":" << bound << ",\"time_s\":" << s
              << ",\"error_m\":" << err << ",\"overlap\":" << ovl << "}\n";
    }
    std::printf("\n");
  }
  std::printf(
      "error: largest distance, over the map's corners and centre, between a point and "
      "its aligned copy (the transform to undo: 0.6 m, -0.4 m, 0.15 rad about the map's "
      "centre)\n");
  return 0;
}
