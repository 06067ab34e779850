#include "omni/sim/world.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace omni::sim {

World World::BuiltIn() {
  constexpr double kWall = 2.5;  // wall height
  constexpr double kT = 0.15;    // wall thickness
  std::vector<Box> b;
  auto wall = [&](double x0, double y0, double x1, double y1) {
    b.push_back({x0, y0, x1, y1, 0.0, kWall});
  };
  // Outer walls of the 20 x 14 m floor.
  wall(0, 0, 20, kT);
  wall(0, 14 - kT, 20, 14);
  wall(0, 0, kT, 14);
  wall(20 - kT, 0, 20, 14);
  // Inner room [5, 15] x [4.5, 9.5], doorways at x 9.0-10.4 (south) and 11.0-12.4 (north),
  // and one at y 6.3-7.7 on the west side.
  wall(5, 4.5, 9.0, 4.5 + kT);
  wall(10.4, 4.5, 15, 4.5 + kT);
  wall(5, 9.5 - kT, 11.0, 9.5);
  wall(12.4, 9.5 - kT, 15, 9.5);
  wall(5, 4.5, 5 + kT, 6.3);
  wall(5, 7.7, 5 + kT, 9.5);
  wall(15 - kT, 4.5, 15, 9.5);
  // Alcoves: short partitions from the outer walls into the corridor.
  for (double x : {5.0, 10.0, 15.0}) {
    wall(x, 0, x + kT, 1.6);
    wall(x, 12.4, x + kT, 14);
  }
  wall(0, 7.0, 1.4, 7.0 + kT);
  wall(18.6, 5.0, 20, 5.0 + kT);
  // Pillars and cabinets (seen by the lidar at any mounting height up to 1.2 m).
  b.push_back({7.3, 11.9, 7.7, 12.3, 0.0, kWall});
  b.push_back({12.3, 1.9, 12.7, 2.3, 0.0, kWall});
  b.push_back({6.0, 7.0, 7.0, 8.8, 0.0, 1.2});    // inside the room
  b.push_back({13.0, 5.2, 14.6, 5.8, 0.0, 1.2});  // inside the room
  b.push_back({16.4, 12.5, 17.6, 13.8, 0.0, 1.2});
  b.push_back({0.2, 2.0, 0.8, 3.4, 0.0, 1.2});
  // Low obstacles (0.12 m): below a lidar plane at 0.3 m, visible to the depth camera only.
  b.push_back({7.8, 1.7, 8.4, 2.2, 0.0, 0.12});
  b.push_back({16.0, 8.0, 16.5, 8.6, 0.0, 0.12});
  b.push_back({3.2, 9.8, 3.8, 10.3, 0.0, 0.12});
  return World(std::move(b));
}

Result<World> World::Load(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const std::exception& e) {
    return MakeError(ErrorCode::kParse, path + ": " + e.what());
  }
  if (!root.IsMap()) return MakeError(ErrorCode::kParse, path + ": expected a map with 'boxes'");
  for (const auto& kv : root) {
    if (!kv.first.IsScalar())
      return MakeError(ErrorCode::kInvalidArgument, path + ": a key that is not a name");
    const std::string key = kv.first.as<std::string>();
    if (key != "boxes")
      return MakeError(ErrorCode::kInvalidArgument,
                       path + ": key '" + key + "' is not a known option (misspelled?)");
  }
  const YAML::Node list = root["boxes"];
  if (!list || !list.IsSequence() || list.size() == 0)
    return MakeError(ErrorCode::kInvalidArgument, path + ": 'boxes' must be a non-empty list");
  std::vector<Box> boxes;
  for (size_t i = 0; i < list.size(); ++i) {
    const YAML::Node e = list[i];
    const std::string where = path + ": boxes[" + std::to_string(i) + "]";
    if (!e.IsSequence() || e.size() != 6)
      return MakeError(ErrorCode::kInvalidArgument, where + " must be [x0, y0, x1, y1, z0, z1]");
    double v[6];
    for (size_t k = 0; k < 6; ++k) {
      try {
        v[k] = e[k].as<double>();
      } catch (const std::exception&) {
        return MakeError(ErrorCode::kInvalidArgument, where + " holds a non-number");
      }
      if (!std::isfinite(v[k]))
        return MakeError(ErrorCode::kInvalidArgument, where + " holds a non-finite number");
    }
    if (!(v[0] < v[2] && v[1] < v[3] && v[4] < v[5] && v[4] >= 0))
      return MakeError(ErrorCode::kInvalidArgument,
                       where + " needs x0 < x1, y0 < y1 and 0 <= z0 < z1");
    boxes.push_back({v[0], v[1], v[2], v[3], v[4], v[5]});
  }
  // The ground-truth map is drawn at 5 cm in the mappers' (turned) frame: a world wider and
  // deeper than 800 m together would be over 2^28 cells (a box 4 km out asked for 6.4 GB).
  double x0 = boxes[0].x0, y0 = boxes[0].y0, x1 = boxes[0].x1, y1 = boxes[0].y1;
  for (const Box& b : boxes) {
    x0 = std::min(x0, b.x0);
    y0 = std::min(y0, b.y0);
    x1 = std::max(x1, b.x1);
    y1 = std::max(y1, b.y1);
  }
  if ((x1 - x0) + (y1 - y0) > kMaxWorldSpanM)
    return MakeError(ErrorCode::kInvalidArgument,
                     path + ": the boxes span " + std::to_string(x1 - x0) + " x " +
                         std::to_string(y1 - y0) + " m; width + depth must be at most " +
                         std::to_string(static_cast<int>(kMaxWorldSpanM)) + " m");
  return World(std::move(boxes));
}

double World::Cast(const Vec3& o, const Vec3& d, double t_max) const {
  double best = t_max;
  bool hit = false;
  if (d.z < 0 && o.z > 0) {  // the floor
    const double t = -o.z / d.z;
    if (t < best) {
      best = t;
      hit = true;
    }
  }
  const double inf = std::numeric_limits<double>::infinity();
  const double ix = d.x != 0 ? 1.0 / d.x : inf, iy = d.y != 0 ? 1.0 / d.y : inf,
               iz = d.z != 0 ? 1.0 / d.z : inf;
  auto slab = [](double o0, double inv, double lo, double hi, double* t0, double* t1) {
    if (std::isinf(inv)) return o0 >= lo && o0 <= hi;  // parallel: inside the slab or never
    double a = (lo - o0) * inv, b = (hi - o0) * inv;
    if (a > b) std::swap(a, b);
    *t0 = std::max(*t0, a);
    *t1 = std::min(*t1, b);
    return *t0 <= *t1;
  };
  for (const Box& b : boxes_) {
    double t0 = 0, t1 = best;
    if (!slab(o.x, ix, b.x0, b.x1, &t0, &t1)) continue;
    if (!slab(o.y, iy, b.y0, b.y1, &t0, &t1)) continue;
    if (!slab(o.z, iz, b.z0, b.z1, &t0, &t1)) continue;
    if (t0 < best) {
      best = t0;
      hit = true;
    }
  }
  return hit ? best : -1.0;
}

bool World::Free(double x, double y, double radius, double clearance_m) const {
  for (const Box& b : boxes_) {
    if (b.z1 <= clearance_m) continue;
    const double dx = std::max({b.x0 - x, 0.0, x - b.x1});
    const double dy = std::max({b.y0 - y, 0.0, y - b.y1});
    if (dx * dx + dy * dy < radius * radius) return false;
  }
  return true;
}

}  // namespace omni::sim
