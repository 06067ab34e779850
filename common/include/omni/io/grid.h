// 2D occupancy grids: a growable log-odds grid that integrates laser scans (used by the
// odometry mapper and by the SLAM mappers' map renderers), the plain GridMap exchanged on
// the bus, and ROS map_server files (PGM + YAML) and PNG renderings.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "omni/common/geometry.h"
#include "omni/common/result.h"
#include "omni/io/image_io.h"

namespace omni::io {

// Cells row-major, row 0 at origin_y (lowest y), col 0 at origin_x; -1 unknown, 0..100 percent.
struct GridMap {
  double resolution_m = 0.05;
  double origin_x_m = 0;  // lower-left corner of cell (0, 0) in the map frame
  double origin_y_m = 0;
  int width = 0;
  int height = 0;
  std::vector<int8_t> cells;
  int8_t at(int col, int row) const { return cells[static_cast<size_t>(row) * width + col]; }
  int8_t& at(int col, int row) { return cells[static_cast<size_t>(row) * width + col]; }
  bool Contains(int col, int row) const {
    return col >= 0 && row >= 0 && col < width && row < height;
  }
};

// The largest grid any omni process sends on the bus or accepts from it (2^28 cells: a 6.5 km
// square at 0.4 m, 819 m at 5 cm). Producers keep their grids within it; bus::ToGridMessage
// refuses a larger one and bus::FromGridMessage refuses to read or build one.
inline constexpr int64_t kMaxGridCells = int64_t{1} << 28;

struct LogOddsOptions {
  double resolution_m = 0.05;
  float hit_log_odds = 0.85f;   // added at a beam's end point
  float miss_log_odds = -0.4f;  // added along the beam before the end point
  float min_log_odds = -2.0f;   // clamping keeps the map adaptable
  float max_log_odds = 3.5f;
  float max_free_range_m = 0.f;  // > 0: beams without a return clear free space up to this range
  float max_hit_range_m = 1e9f;  // returns beyond this are treated as no return
  // The grid never holds more cells than this (5 bytes each; 64 M cells is 400 m x 400 m at
  // 5 cm): a beam that would grow it further is refused and counted (refused_beams()), so one
  // absurd pose cannot take the machine's memory.
  int64_t max_cells = 64LL << 20;
};

class LogOddsGrid {
 public:
  explicit LogOddsGrid(const LogOddsOptions& options = {});

  // Integrates one scan taken from `sensor_pose` (sensor frame in the map frame). Beams are at
  // angle_min + i * increment (CCW, sensor frame). A range that is non-finite, <= 0, or >=
  // max_range is "no return". Returns the number of beams used.
  int IntegrateScan(const Pose2& sensor_pose, const std::vector<float>& ranges_m,
                    float angle_min_rad, float angle_increment_rad, float max_range_m);
  // The same for a sensor that moved during the scan (a spinning lidar's sweep): beam i is
  // taken from sensor_pose_of_beam(i).
  int IntegrateScan(const std::function<Pose2(size_t)>& sensor_pose_of_beam,
                    const std::vector<float>& ranges_m, float angle_min_rad,
                    float angle_increment_rad, float max_range_m);

  // Occupancy in percent with -1 for never-observed cells, cropped to the observed area.
  GridMap ToGridMap() const;
  size_t allocated_cells() const { return logodds_.size(); }
  // Beams not integrated because the grid would have outgrown `max_cells`.
  int64_t refused_beams() const { return refused_beams_; }
  const LogOddsOptions& options() const { return opt_; }

 private:
  // False (and the grid unchanged) when holding the cell would exceed max_cells.
  bool EnsureContains(int64_t cx, int64_t cy);
  // One beam at map angle `a` from `sensor`, whose cell (sx, sy) the grid already contains;
  // false when the beam marks nothing.
  bool IntegrateBeam(const Pose2& sensor, int64_t sx, int64_t sy, double a, float r,
                     float max_range);
  void Update(int64_t cx, int64_t cy, float delta);

  LogOddsOptions opt_;
  int64_t min_cx_ = 0, min_cy_ = 0;  // cell index of storage (0, 0)
  int64_t w_ = 0, h_ = 0;
  std::vector<float> logodds_;
  std::vector<uint8_t> seen_;
  int64_t refused_beams_ = 0;
};

// map_server form: trinary PGM (0 occupied, 254 free, 205 unknown) + YAML beside it.
// `base_path` without extension: writes base_path.pgm and base_path.yaml.
Status WriteMapServer(const GridMap& map, const std::string& base_path);
// Reads a map_server YAML (with its image) or a bare PGM (resolution 0.05 m, origin 0). A YAML
// origin with a yaw ([x, y, yaw], the grid turned by yaw about its lower-left corner) is
// resampled onto the map frame's axes (AxisAligned).
Result<GridMap> ReadMapServer(const std::string& path);

// A grid whose cell axes are turned by `yaw` (radians) from the map frame's, about its origin
// corner (origin_x_m, origin_y_m), resampled onto a grid along the map frame's axes at the same
// resolution: each new cell takes the value of the source cell under its centre (nearest
// neighbour), -1 where none is. yaw 0 returns the grid as it is. An error when the resolution or
// yaw is not finite, or when the turned grid's bounding box would hold more than 4 times its
// cells plus a million (a long thin grid turned 45 degrees) or more than `max_cells`: it is not
// allocated.
Result<GridMap> AxisAligned(const GridMap& rotated, double yaw,
                            int64_t max_cells = std::numeric_limits<int64_t>::max());

// The grid on cells `factor` times larger (factor >= 1), same origin: each coarse cell takes the
// largest value of the fine cells it covers (occupied over free over unknown), so a wall one fine
// cell thick stays a wall; the last row and column may cover fewer fine cells. For publishing a
// fine map on coarser cells (a quarter of the bytes at factor 2).
GridMap CoarsenGrid(const GridMap& fine, int factor);

struct Polyline {
  std::vector<Pose2> poses;
  std::array<uint8_t, 3> rgb{220, 30, 30};
};
// Renders the map (white free, black occupied, grey unknown) with optional trajectories,
// `scale` pixels per cell, row 0 at the top (north up).
Image RenderGrid(const GridMap& map, const std::vector<Polyline>& trajectories = {}, int scale = 1);

}  // namespace omni::io
