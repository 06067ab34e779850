// The built-in simulator's world: a floor (z = 0) and axis-aligned boxes (walls, pillars,
// cabinets, and low obstacles under the lidar's plane that only the depth camera sees, the case
// of paper 003). Rays are cast against them exactly (slab test), so the simulated sensors see
// the same geometry from every viewpoint.
#pragma once

#include <string>
#include <vector>

#include "omni/common/result.h"

namespace omni::sim {

struct Box {
  double x0, y0, x1, y1;  // footprint, metres, world frame (x0 < x1, y0 < y1)
  double z0, z1;          // bottom and top, metres above the floor
};

struct Vec3 {
  double x = 0, y = 0, z = 0;
};

class World {
 public:
  World() = default;
  explicit World(std::vector<Box> boxes) : boxes_(std::move(boxes)) {}

  // A 20 m x 14 m floor: outer walls, an inner room with two doorways and a corridor loop
  // around it, alcoves, pillars, cabinets, and boxes 0.12 m tall beside the corridor.
  static World BuiltIn();
  // The same form from YAML: `boxes: [[x0, y0, x1, y1, z0, z1], ...]`; errors name the entry.
  // The boxes' footprint may span at most kMaxWorldSpanM (width + depth).
  static Result<World> Load(const std::string& path);
  static constexpr double kMaxWorldSpanM = 800.0;

  // Distance t >= 0 along o + t * d (d need not be unit length: t is in units of |d|) to the
  // first box face or the floor, or a negative value when nothing is hit before t_max.
  double Cast(const Vec3& o, const Vec3& d, double t_max) const;
  // True when a disc of `radius` at (x, y) touches no box that rises above `clearance_m`.
  bool Free(double x, double y, double radius, double clearance_m = 0.0) const;

  const std::vector<Box>& boxes() const { return boxes_; }

 private:
  std::vector<Box> boxes_;
};

}  // namespace omni::sim
