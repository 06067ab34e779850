#include "omni/io/grid.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include <yaml-cpp/yaml.h>

namespace omni::io {

LogOddsGrid::LogOddsGrid(const LogOddsOptions& options) : opt_(options) {}

bool LogOddsGrid::EnsureContains(int64_t cx, int64_t cy) {
  if (w_ > 0 && cx >= min_cx_ && cy >= min_cy_ && cx < min_cx_ + w_ && cy < min_cy_ + h_)
    return true;
  // Cells this far out (|index| > 2^40) cannot be held anyway; keeps the arithmetic in range.
  constexpr int64_t kFar = int64_t{1} << 40;
  if (cx > kFar || cx < -kFar || cy > kFar || cy < -kFar) return false;
  constexpr int64_t kChunk = 64;
  auto floor_chunk = [](int64_t v) {
    return (v >= 0 ? v / kChunk : (v - kChunk + 1) / kChunk) * kChunk;
  };
  int64_t nx0, ny0, nx1, ny1;
  if (w_ == 0) {
    nx0 = floor_chunk(cx) - kChunk;
    ny0 = floor_chunk(cy) - kChunk;
    nx1 = floor_chunk(cx) + 2 * kChunk;
    ny1 = floor_chunk(cy) + 2 * kChunk;
  } else {
    // Grow by at least half the current size on the side that overflows, so a map that keeps
    // expanding is copied O(log n) times, not once per chunk.
    const int64_t gx = std::max<int64_t>(kChunk, floor_chunk(w_ / 2)),
                  gy = std::max<int64_t>(kChunk, floor_chunk(h_ / 2));
    nx0 = cx < min_cx_ ? std::min(min_cx_ - gx, floor_chunk(cx) - kChunk) : min_cx_;
    ny0 = cy < min_cy_ ? std::min(min_cy_ - gy, floor_chunk(cy) - kChunk) : min_cy_;
    nx1 = cx >= min_cx_ + w_ ? std::max(min_cx_ + w_ + gx, floor_chunk(cx) + 2 * kChunk)
                             : min_cx_ + w_;
    ny1 = cy >= min_cy_ + h_ ? std::max(min_cy_ + h_ + gy, floor_chunk(cy) + 2 * kChunk)
                             : min_cy_ + h_;
  }
  // In doubles: far cells would overflow the product.
  auto too_big = [&](int64_t w, int64_t h) {
    return static_cast<double>(w) * static_cast<double>(h) > static_cast<double>(opt_.max_cells);
  };
  if (w_ > 0 && too_big(nx1 - nx0, ny1 - ny0)) {
    // The usual growth would pass the cap: grow only as far as the cell needs.
    nx0 = std::min(min_cx_, floor_chunk(cx));
    ny0 = std::min(min_cy_, floor_chunk(cy));
    nx1 = std::max(min_cx_ + w_, floor_chunk(cx) + kChunk);
    ny1 = std::max(min_cy_ + h_, floor_chunk(cy) + kChunk);
  }
  const int64_t nw = nx1 - nx0, nh = ny1 - ny0;
  if (too_big(nw, nh)) return false;
  std::vector<float> lo(static_cast<size_t>(nw * nh), 0.f);
  std::vector<uint8_t> seen(static_cast<size_t>(nw * nh), 0);
  for (int64_t y = 0; y < h_; ++y)
    for (int64_t x = 0; x < w_; ++x) {
      const size_t src = static_cast<size_t>(y * w_ + x);
      const size_t dst = static_cast<size_t>((y + min_cy_ - ny0) * nw + (x + min_cx_ - nx0));
      lo[dst] = logodds_[src];
      seen[dst] = seen_[src];
    }
  logodds_.swap(lo);
  seen_.swap(seen);
  min_cx_ = nx0;
  min_cy_ = ny0;
  w_ = nw;
  h_ = nh;
  return true;
}

void LogOddsGrid::Update(int64_t cx, int64_t cy, float delta) {
  const size_t i = static_cast<size_t>((cy - min_cy_) * w_ + (cx - min_cx_));
  logodds_[i] = std::clamp(logodds_[i] + delta, opt_.min_log_odds, opt_.max_log_odds);
  seen_[i] = 1;
}

namespace {
// The cell holding coordinate v; false when v is not finite or absurdly far (so the cast to an
// integer stays defined).
bool CellOf(double v, double res, int64_t* cell) {
  const double c = std::floor(v / res);
  if (!(std::abs(c) < 1e12)) return false;
  *cell = static_cast<int64_t>(c);
  return true;
}
}  // namespace

int LogOddsGrid::IntegrateScan(const Pose2& sensor_pose, const std::vector<float>& ranges,
                               float angle_min, float angle_inc, float max_range) {
  const double res = opt_.resolution_m;
  int64_t sx = 0, sy = 0;
  if (!CellOf(sensor_pose.x, res, &sx) || !CellOf(sensor_pose.y, res, &sy) ||
      !EnsureContains(sx, sy)) {
    refused_beams_ += static_cast<int64_t>(ranges.size());
    return 0;
  }
  int used = 0;
  for (size_t i = 0; i < ranges.size(); ++i) {
    const double a = sensor_pose.theta + angle_min + static_cast<double>(i) * angle_inc;
    used += IntegrateBeam(sensor_pose, sx, sy, a, ranges[i], max_range) ? 1 : 0;
  }
  return used;
}

int LogOddsGrid::IntegrateScan(const std::function<Pose2(size_t)>& sensor_pose_of_beam,
                               const std::vector<float>& ranges, float angle_min, float angle_inc,
                               float max_range) {
  const double res = opt_.resolution_m;
  int used = 0;
  for (size_t i = 0; i < ranges.size(); ++i) {
    const Pose2 sensor = sensor_pose_of_beam(i);
    int64_t sx = 0, sy = 0;
    if (!CellOf(sensor.x, res, &sx) || !CellOf(sensor.y, res, &sy) || !EnsureContains(sx, sy)) {
      ++refused_beams_;
      continue;
    }
    const double a = sensor.theta + angle_min + static_cast<double>(i) * angle_inc;
    used += IntegrateBeam(sensor, sx, sy, a, ranges[i], max_range) ? 1 : 0;
  }
  return used;
}

bool LogOddsGrid::IntegrateBeam(const Pose2& sensor, int64_t sx, int64_t sy, double a, float r,
                                float max_range) {
  const double res = opt_.resolution_m;
  const bool hit = std::isfinite(r) && r > 0.f && r < max_range && r <= opt_.max_hit_range_m;
  float len = r;
  if (!hit) {
    if (opt_.max_free_range_m <= 0.f) return false;
    len = opt_.max_free_range_m;
  }
  const double ex = sensor.x + len * std::cos(a);
  const double ey = sensor.y + len * std::sin(a);
  int64_t tx = 0, ty = 0;
  if (!CellOf(ex, res, &tx) || !CellOf(ey, res, &ty) || !EnsureContains(tx, ty)) {
    ++refused_beams_;
    return false;
  }
  // Bresenham from the sensor cell to the end cell; every cell before the end is free.
  int64_t x = sx, y = sy;
  const int64_t dx = std::abs(tx - sx), dy = -std::abs(ty - sy);
  const int64_t stx = sx < tx ? 1 : -1, sty = sy < ty ? 1 : -1;
  int64_t err = dx + dy;
  while (!(x == tx && y == ty)) {
    Update(x, y, opt_.miss_log_odds);
    const int64_t e2 = 2 * err;
    if (e2 >= dy) {
      err += dy;
      x += stx;
    }
    if (e2 <= dx) {
      err += dx;
      y += sty;
    }
  }
  if (hit) Update(tx, ty, opt_.hit_log_odds);
  return true;
}

GridMap LogOddsGrid::ToGridMap() const {
  GridMap m;
  m.resolution_m = opt_.resolution_m;
  int64_t x0 = w_, y0 = h_, x1 = -1, y1 = -1;
  for (int64_t y = 0; y < h_; ++y)
    for (int64_t x = 0; x < w_; ++x)
      if (seen_[static_cast<size_t>(y * w_ + x)]) {
        x0 = std::min(x0, x);
        y0 = std::min(y0, y);
        x1 = std::max(x1, x);
        y1 = std::max(y1, y);
      }
  if (x1 < 0) return m;
  // One cell of margin around the observed area.
  x0 = std::max<int64_t>(0, x0 - 1);
  y0 = std::max<int64_t>(0, y0 - 1);
  x1 = std::min<int64_t>(w_ - 1, x1 + 1);
  y1 = std::min<int64_t>(h_ - 1, y1 + 1);
  m.width = static_cast<int>(x1 - x0 + 1);
  m.height = static_cast<int>(y1 - y0 + 1);
  m.origin_x_m = static_cast<double>(min_cx_ + x0) * opt_.resolution_m;
  m.origin_y_m = static_cast<double>(min_cy_ + y0) * opt_.resolution_m;
  m.cells.assign(static_cast<size_t>(m.width) * m.height, -1);
  for (int y = 0; y < m.height; ++y)
    for (int x = 0; x < m.width; ++x) {
      const size_t i = static_cast<size_t>((y + y0) * w_ + (x + x0));
      if (!seen_[i]) continue;
      const double p = 1.0 - 1.0 / (1.0 + std::exp(static_cast<double>(logodds_[i])));
      m.at(x, y) = static_cast<int8_t>(std::lround(p * 100.0));
    }
  return m;
}

namespace {
constexpr double kOccupiedThresh = 0.65;
constexpr double kFreeThresh = 0.196;
}  // namespace

Status WriteMapServer(const GridMap& map, const std::string& base_path) {
  Image im = Image::Make(map.width, map.height, 1, 205);
  for (int row = 0; row < map.height; ++row)
    for (int col = 0; col < map.width; ++col) {
      const int v = map.at(col, row);
      uint16_t px = 205;
      if (v >= 0) {
        const double p = v / 100.0;
        if (p > kOccupiedThresh)
          px = 0;
        else if (p < kFreeThresh)
          px = 254;
      }
      im.at(col, map.height - 1 - row) = px;
    }
  if (Status s = WritePgm(base_path + ".pgm", im); !s.ok()) return s;
  const std::string yaml = base_path + ".yaml";
  std::ofstream out(yaml + ".tmp");
  if (!out) return MakeError(ErrorCode::kIo, "cannot write '" + yaml + ".tmp'");
  out << "image: " << std::filesystem::path(base_path + ".pgm").filename().string() << "\n"
      << "resolution: " << map.resolution_m << "\n"
      << "origin: [" << map.origin_x_m << ", " << map.origin_y_m << ", 0.0]\n"
      << "negate: 0\noccupied_thresh: " << kOccupiedThresh << "\nfree_thresh: " << kFreeThresh
      << "\n";
  out.close();
  if (!out || std::rename((yaml + ".tmp").c_str(), yaml.c_str()) != 0)
    return MakeError(ErrorCode::kIo, "cannot write '" + yaml + "'");
  return Status::Ok();
}

Result<GridMap> AxisAligned(const GridMap& g, double yaw, int64_t max_cells) {
  if (!std::isfinite(yaw) || !std::isfinite(g.resolution_m) || !(g.resolution_m > 0))
    return MakeError(ErrorCode::kInvalidArgument, "grid turn or resolution is not finite");
  if (yaw == 0.0 || g.width == 0 || g.height == 0) return g;
  const double c = std::cos(yaw), s = std::sin(yaw), res = g.resolution_m;
  const double w = g.width * res, h = g.height * res;
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  for (const auto& [u, v] : {std::pair<double, double>{0, 0}, {w, 0}, {0, h}, {w, h}}) {
    const double x = g.origin_x_m + c * u - s * v, y = g.origin_y_m + s * u + c * v;
    x0 = std::min(x0, x);
    y0 = std::min(y0, y);
    x1 = std::max(x1, x);
    y1 = std::max(y1, y);
  }
  GridMap out;
  out.resolution_m = res;
  out.origin_x_m = x0;
  out.origin_y_m = y0;
  const double cols = std::ceil((x1 - x0) / res - 1e-9), rows = std::ceil((y1 - y0) / res - 1e-9);
  const double cells = static_cast<double>(g.width) * g.height;
  if (!(cols * rows <= 4.0 * cells + 1e6) || !(cols * rows <= static_cast<double>(max_cells)))
    return MakeError(ErrorCode::kInvalidArgument,
                     "a " + std::to_string(g.width) + " x " + std::to_string(g.height) +
                         " grid turned by " + std::to_string(yaw) +
                         " rad would need too large an axis-aligned grid (" +
                         std::to_string(static_cast<int64_t>(cols)) + " x " +
                         std::to_string(static_cast<int64_t>(rows)) + ")");
  out.width = static_cast<int>(cols);
  out.height = static_cast<int>(rows);
  out.cells.assign(static_cast<size_t>(out.width) * out.height, -1);
  for (int row = 0; row < out.height; ++row)
    for (int col = 0; col < out.width; ++col) {
      // This cell's centre in the source grid's own axes, metres from its origin corner.
      const double dx = x0 + (col + 0.5) * res - g.origin_x_m;
      const double dy = y0 + (row + 0.5) * res - g.origin_y_m;
      const double u = c * dx + s * dy, v = -s * dx + c * dy;
      const int sc = static_cast<int>(std::floor(u / res)),
                sr = static_cast<int>(std::floor(v / res));
      if (g.Contains(sc, sr)) out.at(col, row) = g.at(sc, sr);
    }
  return out;
}

GridMap CoarsenGrid(const GridMap& fine, int factor) {
  if (factor <= 1) return fine;
  GridMap out;
  out.resolution_m = fine.resolution_m * factor;
  out.origin_x_m = fine.origin_x_m;
  out.origin_y_m = fine.origin_y_m;
  out.width = (fine.width + factor - 1) / factor;
  out.height = (fine.height + factor - 1) / factor;
  out.cells.assign(static_cast<size_t>(out.width) * out.height, -1);
  for (int row = 0; row < fine.height; ++row)
    for (int col = 0; col < fine.width; ++col) {
      int8_t& c = out.at(col / factor, row / factor);
      c = std::max(c, fine.at(col, row));
    }
  return out;
}

Result<GridMap> ReadMapServer(const std::string& path) {
  GridMap m;
  double yaw = 0;
  std::string image_path = path;
  double occ_th = kOccupiedThresh, free_th = kFreeThresh;
  bool negate = false;
  const std::string ext = std::filesystem::path(path).extension().string();
  if (ext == ".yaml" || ext == ".yml") {
    try {
      YAML::Node y = YAML::LoadFile(path);
      if (!y["image"] || !y["resolution"] || !y["origin"])
        return MakeError(ErrorCode::kParse, path + ": map YAML needs image, resolution and origin");
      image_path = y["image"].as<std::string>();
      if (!std::filesystem::path(image_path).is_absolute())
        image_path = (std::filesystem::path(path).parent_path() / image_path).string();
      m.resolution_m = y["resolution"].as<double>();
      m.origin_x_m = y["origin"][0].as<double>();
      m.origin_y_m = y["origin"][1].as<double>();
      if (y["origin"].size() > 2) yaw = y["origin"][2].as<double>();
      if (!std::isfinite(m.origin_x_m) || !std::isfinite(m.origin_y_m) || !std::isfinite(yaw))
        return MakeError(ErrorCode::kParse, path + ": origin must be finite");
      if (y["occupied_thresh"]) occ_th = y["occupied_thresh"].as<double>();
      if (y["free_thresh"]) free_th = y["free_thresh"].as<double>();
      if (y["negate"]) negate = y["negate"].as<int>() != 0;
    } catch (const YAML::Exception& e) {
      return MakeError(ErrorCode::kParse, path + ": " + e.what());
    }
    if (!(std::isfinite(m.resolution_m) && m.resolution_m > 0))
      return MakeError(ErrorCode::kParse, path + ": resolution must be a finite number > 0");
    if (!(occ_th >= 0 && occ_th <= 1 && free_th >= 0 && free_th <= occ_th))
      return MakeError(ErrorCode::kParse,
                       path + ": thresholds must satisfy 0 <= free_thresh <= occupied_thresh <= 1");
  }
  auto im = ReadPnm(image_path);
  if (!im.ok()) return im.error();
  m.width = im->width;
  m.height = im->height;
  m.cells.assign(static_cast<size_t>(m.width) * m.height, -1);
  for (int y = 0; y < im->height; ++y)
    for (int x = 0; x < im->width; ++x) {
      double v = 0;
      for (int c = 0; c < im->channels; ++c) v += im->at(x, y, c);
      v /= im->channels * static_cast<double>(im->max_value);
      const double occ = negate ? v : 1.0 - v;
      int8_t cell = -1;
      if (occ > occ_th)
        cell = 100;
      else if (occ < free_th)
        cell = 0;
      m.at(x, m.height - 1 - y) = cell;
    }
  auto aligned = AxisAligned(m, yaw);
  if (!aligned.ok()) return MakeError(ErrorCode::kParse, path + ": " + aligned.error().message);
  return aligned;
}

Image RenderGrid(const GridMap& map, const std::vector<Polyline>& trajectories, int scale) {
  scale = std::max(1, scale);
  Image im = Image::Make(map.width * scale, map.height * scale, 3, 0);
  for (int row = 0; row < map.height; ++row)
    for (int col = 0; col < map.width; ++col) {
      const int v = map.at(col, row);
      const uint16_t g = v < 0 ? 205 : static_cast<uint16_t>(255 - (v * 255) / 100);
      for (int dy = 0; dy < scale; ++dy)
        for (int dx = 0; dx < scale; ++dx)
          for (int c = 0; c < 3; ++c)
            im.at(col * scale + dx, (map.height - 1 - row) * scale + dy, c) = g;
    }
  auto to_px = [&](const Pose2& p, double* px, double* py) {
    *px = (p.x - map.origin_x_m) / map.resolution_m * scale;
    *py = (map.height * scale) - (p.y - map.origin_y_m) / map.resolution_m * scale;
  };
  for (const auto& t : trajectories) {
    for (size_t i = 1; i < t.poses.size(); ++i) {
      double x0, y0, x1, y1;
      to_px(t.poses[i - 1], &x0, &y0);
      to_px(t.poses[i], &x1, &y1);
      const int steps =
          static_cast<int>(std::ceil(std::max(std::fabs(x1 - x0), std::fabs(y1 - y0)))) + 1;
      for (int s = 0; s <= steps; ++s) {
        const double f = static_cast<double>(s) / steps;
        const int x = static_cast<int>(x0 + f * (x1 - x0)),
                  y = static_cast<int>(y0 + f * (y1 - y0));
        if (x < 0 || y < 0 || x >= im.width || y >= im.height) continue;
        for (int c = 0; c < 3; ++c) im.at(x, y, c) = t.rgb[static_cast<size_t>(c)];
      }
    }
  }
  return im;
}

}  // namespace omni::io
