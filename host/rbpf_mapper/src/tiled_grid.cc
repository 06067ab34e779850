#include "omni/rbpf_mapper/tiled_grid.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

namespace omni::rbpf {

TiledGrid::TiledGrid(const GridOptions& options)
    : opt_(options),
      hit_units_(ToUnits(options.hit_log_odds)),
      miss_units_(ToUnits(options.miss_log_odds)),
      min_units_(ToUnits(options.min_log_odds)),
      max_units_(ToUnits(options.max_log_odds)),
      occupied_units_(ToUnits(options.occupied_threshold)),
      free_units_(ToUnits(options.free_threshold)) {
  // int16 cells: ToUnits keeps every option within +-kMaxLogOdds, so the clamp keeps cells in
  // range; an empty range (RbpfOptions::Validate refuses it) becomes the one value min.
  if (max_units_ < min_units_) max_units_ = min_units_;
}

void TiledGrid::EnsureTile(int64_t tx, int64_t ty) {
  if (ntx_ == 0) {
    // First tile: start with a small block around it so early growth is cheap.
    tx0_ = tx - 2;
    ty0_ = ty - 2;
    ntx_ = nty_ = 5;
    tiles_.assign(25, nullptr);
    written_.assign(25, 0);
    return;
  }
  if (tx >= tx0_ && ty >= ty0_ && tx < tx0_ + ntx_ && ty < ty0_ + nty_) return;
  // Grow with a margin of a few tiles on the side that needs it.
  const int64_t margin = 4;
  const int64_t nx0 = std::min(tx0_, tx - (tx < tx0_ ? margin : 0));
  const int64_t ny0 = std::min(ty0_, ty - (ty < ty0_ ? margin : 0));
  const int64_t nx1 = std::max(tx0_ + ntx_, tx + 1 + (tx >= tx0_ + ntx_ ? margin : 0));
  const int64_t ny1 = std::max(ty0_ + nty_, ty + 1 + (ty >= ty0_ + nty_ ? margin : 0));
  std::vector<std::shared_ptr<Tile>> grown(static_cast<size_t>((nx1 - nx0) * (ny1 - ny0)));
  std::vector<uint32_t> grown_written(grown.size(), 0);
  for (int64_t iy = 0; iy < nty_; ++iy)
    for (int64_t ix = 0; ix < ntx_; ++ix) {
      const size_t from = static_cast<size_t>(iy * ntx_ + ix);
      const size_t to = static_cast<size_t>((iy + ty0_ - ny0) * (nx1 - nx0) + (ix + tx0_ - nx0));
      grown[to] = std::move(tiles_[from]);
      grown_written[to] = written_[from];
    }
  tiles_ = std::move(grown);
  written_ = std::move(grown_written);
  tx0_ = nx0;
  ty0_ = ny0;
  ntx_ = nx1 - nx0;
  nty_ = ny1 - ny0;
}

TiledGrid::Tile* TiledGrid::MutableTile(int64_t tx, int64_t ty) {
  EnsureTile(tx, ty);
  const size_t i = static_cast<size_t>((ty - ty0_) * ntx_ + (tx - tx0_));
  auto& slot = tiles_[i];
  if (!slot) {
    slot = std::make_shared<Tile>();
  } else if (slot.use_count() > 1) {
    slot = std::make_shared<Tile>(*slot);  // copy-on-write
  } else {
    // Sole owner: pairs with the release of the last other owner's decrement, so that owner's
    // reads (e.g. while copying) happen before our writes.
    std::atomic_thread_fence(std::memory_order_acquire);
  }
  if (slot->is_packed()) {
    slot->log_odds.resize(kCells);
    Unpack(*slot, slot->log_odds.data());
    std::vector<uint8_t>().swap(slot->packed);
  }
  written_[i] = scans_;
  return slot.get();
}

// Packed form: runs of equal cells in row-major order, each the value (int16, little end first)
// and the run's length as a base-128 varint (one byte below 128, two up to the tile's 4096). A
// tile is mostly runs (unknown, free at the clamp, walls): a real building's tiles pack to
// 1-2 KiB of their 8 KiB in a few microseconds. zlib packs them about half as small again but
// took 4-10 % of the filter's time where these runs take under 2 % (docs/rbpf.md, "Idle tiles
// packed").
void TiledGrid::Pack(Tile* t) {
  std::vector<uint8_t> out;
  out.reserve(1024);
  const int16_t* c = t->log_odds.data();
  for (size_t i = 0; i < kCells;) {
    size_t j = i + 1;
    while (j < kCells && c[j] == c[i]) ++j;
    const auto v = static_cast<uint16_t>(c[i]);
    const size_t len = j - i;
    out.push_back(static_cast<uint8_t>(v & 0xff));
    out.push_back(static_cast<uint8_t>(v >> 8));
    if (len < 128) {
      out.push_back(static_cast<uint8_t>(len));
    } else {
      out.push_back(static_cast<uint8_t>(0x80 | (len & 0x7f)));
      out.push_back(static_cast<uint8_t>(len >> 7));
    }
    i = j;
  }
  if (out.size() >= kCells * sizeof(int16_t)) return;  // no smaller: stays unpacked
  out.shrink_to_fit();
  t->packed = std::move(out);
  std::vector<int16_t>().swap(t->log_odds);
}

void TiledGrid::Unpack(const Tile& t, int16_t* cells) {
  const std::vector<uint8_t>& in = t.packed;
  size_t at = 0, n = 0;
  bool ok = true;
  while (ok && at < in.size()) {
    ok = at + 3 <= in.size();
    if (!ok) break;
    const auto v = static_cast<int16_t>(static_cast<uint16_t>(in[at] | (in[at + 1] << 8)));
    size_t len = in[at + 2];
    at += 3;
    if (len & 0x80) {
      ok = at < in.size();
      if (!ok) break;
      len = (len & 0x7f) | (size_t{in[at]} << 7);
      ++at;
    }
    ok = len > 0 && n + len <= kCells;
    if (ok) std::fill(cells + n, cells + n + len, v);
    n += len;
  }
  if (!ok || n != kCells) {
    // Only memory corruption gets here: the runs are ours and always cover the tile.
    std::fprintf(stderr, "TiledGrid: a packed tile does not unpack (memory corrupted)\n");
    std::abort();
  }
}

size_t TiledGrid::PackIdleTiles() {
  if (opt_.pack_idle_scans <= 0) return 0;
  const uint32_t idle = static_cast<uint32_t>(opt_.pack_idle_scans);
  size_t n = 0;
  for (size_t i = 0; i < tiles_.size(); ++i) {
    auto& slot = tiles_[i];
    if (!slot || slot->is_packed() || scans_ - written_[i] < idle || slot.use_count() != 1)
      continue;
    std::atomic_thread_fence(std::memory_order_acquire);  // as in MutableTile
    Pack(slot.get());
    if (slot->is_packed())
      ++n;
    else
      written_[i] = scans_;  // packs no smaller: tried again after another idle spell
  }
  return n;
}

int32_t TiledGrid::Units(int64_t cx, int64_t cy) const {
  const Tile* t = TileAt(cx >> kTileBits, cy >> kTileBits);
  if (!t) return 0;
  const size_t i = static_cast<size_t>((cy & kTileMask) * kTileSize + (cx & kTileMask));
  if (!t->is_packed()) return t->log_odds[i];
  std::vector<int16_t> cells(kCells);
  Unpack(*t, cells.data());
  return cells[i];
}

void TiledGrid::AddToCell(Tile* t, int64_t cx, int64_t cy, int32_t delta_units) const {
  const int64_t lx = cx & kTileMask, ly = cy & kTileMask;
  int16_t& cell = t->log_odds[static_cast<size_t>(ly * kTileSize + lx)];  // unpacked: written
  int32_t v = std::clamp(int32_t{cell} + delta_units, min_units_, max_units_);
  // Observed cells never read as "unknown": even odds is stored as -1, or as +1 when a one-unit
  // increment came from -1 (which would otherwise hold the cell there for ever).
  if (v == 0) v = delta_units == 1 ? 1 : -1;
  cell = static_cast<int16_t>(v);
  const uint64_t bit = uint64_t{1} << lx;
  uint64_t& occ = t->occupied_bits[static_cast<size_t>(ly)];
  uint64_t& fre = t->free_bits[static_cast<size_t>(ly)];
  occ = v > occupied_units_ ? (occ | bit) : (occ & ~bit);
  fre = v < free_units_ ? (fre | bit) : (fre & ~bit);
  t->known_bits[static_cast<size_t>(ly)] |= bit;
}

void TiledGrid::Update(int64_t cx, int64_t cy, float delta) {
  AddToCell(MutableTile(cx >> kTileBits, cy >> kTileBits), cx, cy, ToUnits(delta));
}

void TiledGrid::IntegrateScan(const Pose2& sensor_pose, const std::vector<Eigen::Vector2d>& points,
                              const std::vector<uint8_t>& hit) {
  ++scans_;
  const int64_t x0 = CellX(sensor_pose.x), y0 = CellY(sensor_pose.y);
  // Cache of the tile being written, so a ray does not look up its tile for every cell.
  int64_t cached_tx = std::numeric_limits<int64_t>::min(), cached_ty = 0;
  Tile* cached = nullptr;
  auto add = [&](int64_t cx, int64_t cy, int32_t delta) {
    const int64_t tx = cx >> kTileBits, ty = cy >> kTileBits;
    if (tx != cached_tx || ty != cached_ty || !cached) {
      cached = MutableTile(tx, ty);
      cached_tx = tx;
      cached_ty = ty;
    }
    AddToCell(cached, cx, cy, delta);
  };
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector2d w = sensor_pose.Transform(points[i]);
    const int64_t x1 = CellX(w.x()), y1 = CellY(w.y());
    // Bresenham from the sensor cell to the end cell (exclusive).
    int64_t x = x0, y = y0;
    const int64_t dx = std::abs(x1 - x0), dy = -std::abs(y1 - y0);
    const int64_t sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1;
    int64_t err = dx + dy;
    while (x != x1 || y != y1) {
      add(x, y, miss_units_);
      const int64_t e2 = 2 * err;
      if (e2 >= dy) {
        err += dy;
        x += sx;
      }
      if (e2 <= dx) {
        err += dx;
        y += sy;
      }
    }
    if (hit[i]) add(x1, y1, hit_units_);
  }
  if (scans_ % 8 == 0) PackIdleTiles();
}

io::GridMap TiledGrid::ToGridMap() const {
  io::GridMap map;
  map.resolution_m = opt_.resolution_m;
  // The observed area from the known bits.
  int64_t min_cx = std::numeric_limits<int64_t>::max(), min_cy = min_cx;
  int64_t max_cx = std::numeric_limits<int64_t>::min(), max_cy = max_cx;
  for (int64_t iy = 0; iy < nty_; ++iy)
    for (int64_t ix = 0; ix < ntx_; ++ix) {
      const Tile* t = tiles_[static_cast<size_t>(iy * ntx_ + ix)].get();
      if (!t) continue;
      for (int r = 0; r < kTileSize; ++r) {
        const uint64_t row = t->known_bits[static_cast<size_t>(r)];
        if (row == 0) continue;
        const int64_t cy = (ty0_ + iy) * kTileSize + r, base = (tx0_ + ix) * kTileSize;
        min_cx = std::min(min_cx, base + __builtin_ctzll(row));
        max_cx = std::max(max_cx, base + 63 - __builtin_clzll(row));
        min_cy = std::min(min_cy, cy);
        max_cy = std::max(max_cy, cy);
      }
    }
  if (min_cx > max_cx) return map;
  map.width = static_cast<int>(max_cx - min_cx + 1);
  map.height = static_cast<int>(max_cy - min_cy + 1);
  map.origin_x_m = static_cast<double>(min_cx) * opt_.resolution_m;
  map.origin_y_m = static_cast<double>(min_cy) * opt_.resolution_m;
  map.cells.assign(static_cast<size_t>(map.width) * map.height, -1);
  std::vector<int16_t> unpacked(kCells);
  for (int64_t iy = 0; iy < nty_; ++iy)
    for (int64_t ix = 0; ix < ntx_; ++ix) {
      const Tile* t = tiles_[static_cast<size_t>(iy * ntx_ + ix)].get();
      if (!t) continue;
      const int16_t* cells = t->log_odds.data();
      if (t->is_packed()) {
        Unpack(*t, unpacked.data());
        cells = unpacked.data();
      }
      for (int r = 0; r < kTileSize; ++r)
        for (int c = 0; c < kTileSize; ++c) {
          const int16_t u = cells[r * kTileSize + c];
          if (u == 0) continue;
          const double l = static_cast<double>(static_cast<float>(u) / kUnitsPerLogOdds);
          const double p = 1.0 - 1.0 / (1.0 + std::exp(l));
          const int64_t col = (tx0_ + ix) * kTileSize + c - min_cx;
          const int64_t row = (ty0_ + iy) * kTileSize + r - min_cy;
          map.at(static_cast<int>(col), static_cast<int>(row)) =
              static_cast<int8_t>(std::lround(100.0 * p));
        }
    }
  return map;
}

size_t TiledGrid::num_tiles() const {
  size_t n = 0;
  for (const auto& t : tiles_) n += t != nullptr;
  return n;
}

size_t TiledGrid::num_packed_tiles() const {
  size_t n = 0;
  for (const auto& t : tiles_) n += t && t->is_packed();
  return n;
}

size_t TiledGrid::num_unique_tiles() const {
  size_t n = 0;
  for (const auto& t : tiles_) n += t && t.use_count() == 1;
  return n;
}

bool TiledGrid::SharesTileWith(const TiledGrid& other, int64_t tx, int64_t ty) const {
  const Tile* a = TileAt(tx, ty);
  return a != nullptr && a == other.TileAt(tx, ty);
}

}  // namespace omni::rbpf
