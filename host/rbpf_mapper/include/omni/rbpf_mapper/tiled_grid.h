// A log-odds occupancy grid made of fixed-size tiles held by shared pointers, so particle maps
// share memory: copying a TiledGrid copies only the tile table (one pointer per tile), and a
// tile is copied the first time a grid writes to it while another grid still holds it
// (copy-on-write). Coordinates: cell (cx, cy) covers [cx*res, (cx+1)*res) x [cy*res, ...) in
// the map frame; the grid grows in any direction as cells are written.
//
// A tile this grid holds alone and has not written for `pack_idle_scans` scans (checked every
// 8th scan, so after 20-27 with the shipped 20) is packed: its log odds are run-length coded
// (1-2 KiB of their 8 KiB on real maps; with the bit masks a tile then takes about 3 KiB instead
// of 9.5) while its bit masks, all the scan matcher reads, stay as they are; the next write
// unpacks it. Packing loses nothing and changes no reading: every accessor answers the same for
// a packed tile as for the unpacked one.
//
// Thread safety: distinct TiledGrid objects may be used from different threads at the same time
// even when they share tiles (a shared tile is never written or packed; the copy and pack
// decisions use the reference count with an acquire fence). One TiledGrid must not be used by
// two threads at once.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "omni/common/geometry.h"
#include "omni/io/grid.h"

namespace omni::rbpf {

// Log odds are stored in thousandths (TiledGrid::kUnitsPerLogOdds), so every value must lie
// within +-30 (RbpfOptions::Validate checks it; TiledGrid clamps what it is given) and is
// rounded to 0.001.
struct GridOptions {
  double resolution_m = 0.05;
  float hit_log_odds = 0.85f;   // added at a beam's end point
  float miss_log_odds = -0.4f;  // added to the cells a beam passes through
  float min_log_odds = -2.0f;   // clamp (keeps the map adaptable)
  float max_log_odds = 3.5f;
  float occupied_threshold = 0.5f;  // log odds above this: occupied (for matching)
  float free_threshold = -0.3f;     // log odds below this: free (for matching)
  // A tile held alone and not written for this many scans is packed (0: never).
  int pack_idle_scans = 20;
};

class TiledGrid {
 public:
  static constexpr int kTileBits = 6;
  static constexpr int kTileSize = 1 << kTileBits;  // cells per tile side
  static constexpr int kTileMask = kTileSize - 1;
  // Log odds are kept as integers in thousandths (kUnitsPerLogOdds): half the memory of floats,
  // and sums of the configured increments are exact. Options are rounded to the unit.
  static constexpr float kUnitsPerLogOdds = 1000.f;
  // The range every option must lie in (RbpfOptions checks it), and the smallest step.
  static constexpr float kMaxLogOdds = 30.f;
  static constexpr float kLogOddsStep = 1.f / kUnitsPerLogOdds;
  static constexpr size_t kCells = size_t{kTileSize} * kTileSize;
  struct Tile {
    // The cells classified for scan matching, one 64-bit word per row (bit c = column c): log
    // odds above occupied_threshold / below free_threshold / observed at all (not 0). Kept in
    // step with the log odds by every write, so a matcher reads a 3x3 neighbourhood from three
    // words instead of nine cells spread over three cache lines, and never needs the log odds.
    std::array<uint64_t, kTileSize> occupied_bits{};
    std::array<uint64_t, kTileSize> free_bits{};
    std::array<uint64_t, kTileSize> known_bits{};
    // Log odds in thousandths, row-major (cell (c, r) at r * kTileSize + c), 0 = never observed:
    // kCells values while unpacked, empty while packed.
    std::vector<int16_t> log_odds = std::vector<int16_t>(kCells, 0);
    std::vector<uint8_t> packed;  // while packed: log_odds as runs (TiledGrid::Pack)
    bool is_packed() const { return log_odds.empty(); }
    // Heap and object bytes (malloc's headers not counted).
    size_t bytes() const {
      return sizeof(Tile) + log_odds.capacity() * sizeof(int16_t) + packed.capacity();
    }
  };
  static_assert(kTileSize == 64, "row bit masks are 64-bit words");

  explicit TiledGrid(const GridOptions& options = {});

  // Cell index of a map-frame point.
  int64_t CellX(double x_m) const { return FloorToCell(x_m); }
  int64_t CellY(double y_m) const { return FloorToCell(y_m); }
  double resolution() const { return opt_.resolution_m; }
  const GridOptions& options() const { return opt_; }

  // Log odds of a cell (0 outside the allocated area and where never observed).
  // (A packed tile is unpacked into a temporary for this, 8 KiB allocated per call: for tests and
  // tools; the matcher reads the bits below, ToGridMap unpacks each tile once.)
  float LogOdds(int64_t cx, int64_t cy) const {
    return static_cast<float>(Units(cx, cy)) / kUnitsPerLogOdds;
  }
  // Log odds above occupied_threshold / below free_threshold / ever observed. A cell never
  // observed is neither occupied nor free, whatever the thresholds.
  bool Occupied(int64_t cx, int64_t cy) const { return Bit(&Tile::occupied_bits, cx, cy); }
  bool Free(int64_t cx, int64_t cy) const { return Bit(&Tile::free_bits, cx, cy); }
  bool Known(int64_t cx, int64_t cy) const { return Bit(&Tile::known_bits, cx, cy); }

  // Adds `delta` to a cell (clamped), copying its tile first if another grid shares it.
  void Update(int64_t cx, int64_t cy, float delta);

  // Integrates one scan: misses along each beam (Bresenham), a hit at each end point.
  // `sensor_pose` is the sensor frame in the map frame; `points` are the beam end points in the
  // sensor frame; `hit[i]` false means "no return" (only free space up to the point).
  void IntegrateScan(const Pose2& sensor_pose, const std::vector<Eigen::Vector2d>& points,
                     const std::vector<uint8_t>& hit);

  // Occupancy in percent, -1 unknown, cropped to the observed area.
  io::GridMap ToGridMap() const;

  // Packs the tiles this grid holds alone and has not written during the last
  // options().pack_idle_scans calls of IntegrateScan (every 8th call of IntegrateScan does this
  // itself); returns how many it packed.
  size_t PackIdleTiles();

  // Memory accounting: tiles this grid references, how many of them it holds alone, how many
  // of them are packed.
  size_t num_tiles() const;
  size_t num_unique_tiles() const;
  size_t num_packed_tiles() const;
  // Appends the tile objects this grid references.
  void CollectTiles(std::vector<const Tile*>* out) const {
    for (const auto& t : tiles_)
      if (t) out->push_back(t.get());
  }
  // Whether this grid and `other` hold the same tile object for tile (tx, ty).
  bool SharesTileWith(const TiledGrid& other, int64_t tx, int64_t ty) const;
  const Tile* TileAt(int64_t tx, int64_t ty) const {
    const int64_t ix = tx - tx0_, iy = ty - ty0_;
    if (ix < 0 || iy < 0 || ix >= ntx_ || iy >= nty_) return nullptr;
    return tiles_[static_cast<size_t>(iy * ntx_ + ix)].get();
  }

 private:
  int64_t FloorToCell(double v) const {
    return static_cast<int64_t>(std::floor(v / opt_.resolution_m));
  }
  Tile* MutableTile(int64_t tx, int64_t ty);
  void AddToCell(Tile* t, int64_t cx, int64_t cy, int32_t delta_units) const;
  int32_t Units(int64_t cx, int64_t cy) const;
  bool Bit(const std::array<uint64_t, kTileSize> Tile::*rows, int64_t cx, int64_t cy) const {
    const Tile* t = TileAt(cx >> kTileBits, cy >> kTileBits);
    return t && (((t->*rows)[static_cast<size_t>(cy & kTileMask)] >> (cx & kTileMask)) & 1) != 0;
  }
  static void Pack(Tile* t);
  static void Unpack(const Tile& t, int16_t* cells);
  // Rounded to the unit and limited to +-30 log odds (NaN: 0).
  static int32_t ToUnits(float log_odds) {
    constexpr int32_t kMaxUnits = static_cast<int32_t>(kMaxLogOdds * kUnitsPerLogOdds);
    if (!(std::fabs(log_odds) <= kMaxLogOdds))
      return std::isnan(log_odds) ? 0 : (log_odds > 0 ? kMaxUnits : -kMaxUnits);
    return static_cast<int32_t>(std::lround(log_odds * kUnitsPerLogOdds));
  }
  void EnsureTile(int64_t tx, int64_t ty);

  GridOptions opt_;
  // The options in units.
  int32_t hit_units_, miss_units_, min_units_, max_units_, occupied_units_, free_units_;
  int64_t tx0_ = 0, ty0_ = 0;  // tile index of tiles_[0]
  int64_t ntx_ = 0, nty_ = 0;
  std::vector<std::shared_ptr<Tile>> tiles_;  // row-major, null = never written
  std::vector<uint32_t> written_;             // per slot of tiles_: scans_ when last written
  uint32_t scans_ = 0;                        // IntegrateScan calls so far
};

}  // namespace omni::rbpf
