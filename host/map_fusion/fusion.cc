#include "omni/map_fusion/fusion.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>

#include "omni/common/json.h"
#include "omni/io/image_io.h"

namespace omni::map_fusion {

Status FusionOptions::ValidateForBus() const {
  if (min_maps > static_cast<int>(grid_channels.size()))
    return MakeError(ErrorCode::kInvalidArgument,
                     "min_maps is " + std::to_string(min_maps) + " but grid_channels lists only " +
                         std::to_string(grid_channels.size()) + ": it could never fuse");
  return Status::Ok();
}

Result<FusionOptions> FusionOptions::Load(ConfigReader& r) {
  FusionOptions o;
  r.Get("grid_channels", &o.grid_channels, Optional());
  // A channel listed twice would give one mapper two votes (and count toward min_maps twice).
  for (size_t i = 0; i < o.grid_channels.size(); ++i)
    for (size_t j = 0; j < i; ++j)
      if (o.grid_channels[i] == o.grid_channels[j])
        r.AddError("grid_channels", "lists " + o.grid_channels[i] + " twice");
  r.Get("fused_channel", &o.fused_channel, Optional(), NonEmpty());
  r.Get("frame", &o.frame, Optional());
  r.Get("fuse_interval_s", &o.fuse_interval_s, Optional(), InRange(0.05, 3600.0));
  r.Get("min_maps", &o.min_maps, Optional(), InRange(1, 64));
  r.Get("max_input_cells", &o.max_input_cells, Optional(),
        InRange<int64_t>(10000, io::kMaxGridCells));
  r.Get("base", &o.base, Optional());
  auto a = r.Section("align");
  a.Get("enabled", &o.align.align, Optional());
  a.Get("max_rotation_rad", &o.align.max_rotation_rad, Optional(), InRange(0.0, 3.2));
  a.Get("max_shift_m", &o.align.max_shift_m, Optional(), InRange(0.0, 100.0));
  a.Get("max_cells", &o.align.max_cells, Optional(), InRange(0, 100000000));
  r.Get("min_overlap_fraction", &o.min_overlap_fraction, Optional(), InRange(0.0, 1.0));
  r.Get("max_conflict_fraction", &o.max_conflict_fraction, Optional(), InRange(0.0, 1.0));
  std::string tie = "occupied";
  r.Get("tie", &tie, Optional(), OneOf({"occupied", "free", "unknown"}));
  o.tie = tie == "free"      ? TieRule::kFree
          : tie == "unknown" ? TieRule::kUnknown
                             : TieRule::kOccupied;
  r.Get("unknown_votes", &o.unknown_votes, Optional());
  if (o.grid_channels.empty()) r.AddError("grid_channels", "must list at least one channel");
  for (const auto& c : o.grid_channels)
    if (c.empty()) r.AddError("grid_channels", "must not contain an empty channel name");
  // Its own output among its inputs: each fusion would vote for the last one, for ever.
  if (std::find(o.grid_channels.begin(), o.grid_channels.end(), o.fused_channel) !=
      o.grid_channels.end())
    r.AddError("fused_channel", o.fused_channel + " is also in grid_channels");
  if (!o.base.empty() &&
      std::find(o.grid_channels.begin(), o.grid_channels.end(), o.base) == o.grid_channels.end())
    r.AddError("base", "must be one of grid_channels (or empty)");
  if (Status s = r.Finish(); !s.ok()) return s.error();
  return o;
}

int VoteCell(const size_t votes[3], TieRule tie, bool* tied) {
  const size_t most = std::max({votes[0], votes[1], votes[2]});
  int winners = 0, winner = -1;
  for (int v = -1; v <= 1; ++v)
    if (votes[v + 1] == most) {
      ++winners;
      winner = v;
    }
  if (tied) *tied = winners > 1;
  if (winners == 1) return winner;
  return tie == TieRule::kOccupied ? 1 : tie == TieRule::kFree ? 0 : -1;
}

namespace {

size_t KnownCells(const io::GridMap& m) {
  return static_cast<size_t>(
      std::count_if(m.cells.begin(), m.cells.end(), [](int8_t v) { return v >= 0; }));
}

bool Consistent(const io::GridMap& m, std::string* why) {
  if (m.width <= 0 || m.height <= 0 ||
      m.cells.size() != static_cast<size_t>(m.width) * static_cast<size_t>(m.height)) {
    *why = "empty or inconsistent grid";
    return false;
  }
  if (!(m.resolution_m > 0) || !std::isfinite(m.resolution_m) || !std::isfinite(m.origin_x_m) ||
      !std::isfinite(m.origin_y_m)) {
    *why = "bad resolution or origin";
    return false;
  }
  return true;
}

// 1 where an occupied cell of `norm` (normalised cells) lies within `r` cells (Chebyshev).
std::vector<uint8_t> NearOccupied(const std::vector<int8_t>& norm, int w, int h, int r) {
  std::vector<uint8_t> rows(norm.size(), 0), out(norm.size(), 0);
  for (int y = 0; y < h; ++y) {
    const size_t row = static_cast<size_t>(y) * static_cast<size_t>(w);
    int last = -(r + 1) - 1;  // column of the last occupied cell seen, left to right
    for (int x = 0; x < w; ++x) {
      if (norm[row + static_cast<size_t>(x)] == 1) last = x;
      if (x - last <= r) rows[row + static_cast<size_t>(x)] = 1;
    }
    last = w + r + 1;  // right to left
    for (int x = w - 1; x >= 0; --x) {
      if (norm[row + static_cast<size_t>(x)] == 1) last = x;
      if (last - x <= r) rows[row + static_cast<size_t>(x)] = 1;
    }
  }
  for (int x = 0; x < w; ++x) {
    int last = -(r + 1) - 1;
    for (int y = 0; y < h; ++y) {
      const size_t c = static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x);
      if (rows[c]) last = y;
      if (y - last <= r) out[c] = 1;
    }
    last = h + r + 1;
    for (int y = h - 1; y >= 0; --y) {
      const size_t c = static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x);
      if (rows[c]) last = y;
      if (last - y <= r) out[c] = 1;
    }
  }
  return out;
}

}  // namespace

bool UsableMap(const io::GridMap& m, std::string* why) {
  std::string reason;
  bool ok = Consistent(m, &reason);
  if (ok && KnownCells(m) == 0) {
    reason = "no known cell";
    ok = false;
  }
  if (why) *why = reason;
  return ok;
}

MapConflicts CountConflicts(const io::GridMap& base, const io::GridMap& moved,
                            int tolerance_cells) {
  MapConflicts c;
  if (moved.width != base.width || moved.height != base.height ||
      moved.cells.size() != base.cells.size() || base.width <= 0 || base.height <= 0 ||
      base.cells.size() != static_cast<size_t>(base.width) * static_cast<size_t>(base.height))
    return c;
  const int r = std::max(0, tolerance_cells);
  std::vector<int8_t> nb(base.cells.size()), nm(moved.cells.size());
  for (size_t i = 0; i < nb.size(); ++i) {
    nb[i] = static_cast<int8_t>(eval::NormalizedCell(base.cells[i]));
    nm[i] = static_cast<int8_t>(eval::NormalizedCell(moved.cells[i]));
  }
  const std::vector<uint8_t> near_b = NearOccupied(nb, base.width, base.height, r);
  const std::vector<uint8_t> near_m = NearOccupied(nm, base.width, base.height, r);
  for (size_t i = 0; i < nb.size(); ++i) {
    if (nb[i] < 0 || nm[i] < 0) continue;  // only where both know the cell
    if (nm[i] == 1) {
      ++c.moved_occupied;
      if (nb[i] == 0 && !near_b[i]) ++c.moved_on_free;
    }
    if (nb[i] == 1) {
      ++c.base_occupied;
      if (nm[i] == 0 && !near_m[i]) ++c.base_on_free;
    }
  }
  c.occupied = c.moved_occupied + c.base_occupied;
  c.conflicts = c.moved_on_free + c.base_on_free;
  return c;
}

Result<FusionResult> Fuse(const std::vector<SourceMap>& maps, const FusionOptions& opt,
                          AlignmentHints* hints, std::vector<SourceReport>* sources) {
  FusionResult res;
  auto fail = [&](const std::string& why) -> Result<FusionResult> {
    if (sources) *sources = res.sources;
    return MakeError(ErrorCode::kUnavailable, why);
  };
  res.sources.resize(maps.size());
  int base = -1;
  for (size_t i = 0; i < maps.size(); ++i) {
    SourceReport& rep = res.sources[i];
    rep.name = maps[i].name;
    if (!UsableMap(maps[i].map, &rep.reason)) continue;
    rep.known_cells = KnownCells(maps[i].map);
    rep.used = true;
    if (!opt.base.empty() ? maps[i].name == opt.base : base < 0) base = static_cast<int>(i);
  }
  if (base < 0)
    return fail(opt.base.empty() ? "no usable map to fuse"
                                 : "the base map '" + opt.base + "' is missing or unusable");
  const io::GridMap& ref = maps[static_cast<size_t>(base)].map;
  res.base = maps[static_cast<size_t>(base)].name;
  if (hints && hints->base != res.base) {
    hints->base = res.base;
    hints->by_name.clear();
  }
  auto fraction = [](const eval::MapAlignment& a) {
    return a.occupied == 0 ? 0.0 : static_cast<double>(a.overlap) / static_cast<double>(a.occupied);
  };
  std::vector<io::GridMap> moved;
  std::vector<std::pair<size_t, size_t>> one_way;  // (source, its index in moved)
  for (size_t i = 0; i < maps.size(); ++i) {
    SourceReport& rep = res.sources[i];
    if (!rep.used) continue;
    if (static_cast<int>(i) == base) {
      rep.alignment = eval::AlignMap(ref, ref, [&] {
        eval::MapCompareOptions o = opt.align;
        o.align = false;  // the identity, with its overlap figures
        return o;
      }());
    } else {
      const eval::MapAlignment* hint = nullptr;
      if (hints && opt.align.align)
        if (auto it = hints->by_name.find(maps[i].name); it != hints->by_name.end())
          hint = &it->second;
      bool tracked = false;
      if (hint) {
        eval::MapCompareOptions near = opt.align;
        near.max_rotation_rad = std::min(opt.align.max_rotation_rad, kTrackRotationRad);
        near.max_shift_m = std::min(opt.align.max_shift_m, kTrackShiftM);
        // 5 values per axis per level, halving: ~125 poses a level instead of ~730 (more
        // rotations on a large map, whose rotation step follows its extent).
        near.coarse_steps = 2;
        near.refine_divisions = 2;
        near.levels = 9;
        rep.alignment = eval::AlignMap(ref, maps[i].map, near, hint);
        const double f = fraction(rep.alignment);
        tracked = f >= opt.min_overlap_fraction && f >= fraction(*hint) - 0.05;
      }
      if (tracked) {
        ++res.alignments_tracked;
      } else {
        rep.alignment = eval::AlignMap(ref, maps[i].map, opt.align);
        ++res.alignments_searched;
      }
    }
    rep.overlap_fraction = fraction(rep.alignment);
    if (static_cast<int>(i) != base && rep.overlap_fraction < opt.min_overlap_fraction) {
      rep.used = false;
      char buf[128];
      std::snprintf(buf, sizeof(buf), "alignment overlap %.2f below min_overlap_fraction %.2f",
                    rep.overlap_fraction, opt.min_overlap_fraction);
      rep.reason = buf;
      if (hints) hints->by_name.erase(maps[i].name);
      continue;
    }
    if (static_cast<int>(i) == base) {
      moved.push_back(ref);
      continue;
    }
    io::GridMap on_base = eval::ResampleOnto(ref, maps[i].map, rep.alignment);
    // The tolerance in the coarser of the two grids' cells (a 5 cm map's wall on a 2.5 cm base
    // may be one base cell thicker or off by one more).
    const double coarser = std::max(ref.resolution_m, maps[i].map.resolution_m);
    const int tolerance = static_cast<int>(std::ceil(
        std::min(1e3, opt.align.match_tolerance_cells * coarser / ref.resolution_m) - 1e-9));
    const MapConflicts mc = CountConflicts(ref, on_base, tolerance);
    rep.conflict_fraction = mc.fraction();
    rep.walls_on_base_free = mc.moved_fraction();
    rep.base_walls_on_free = mc.base_fraction();
    // Misaligned maps conflict both ways (each one's walls across the other's rooms); a map
    // that sees obstacles the base does not (people it saw once, low boxes under the lidar) only
    // one way, and the vote settles those cells when two other maps take part (below).
    if (rep.conflict_fraction > opt.max_conflict_fraction &&
        std::min(rep.walls_on_base_free, rep.base_walls_on_free) >
            0.5 * opt.max_conflict_fraction) {
      rep.used = false;
      char buf[200];
      std::snprintf(buf, sizeof(buf),
                    "conflicts with the base: %.2f of the occupied cells both know lie on the "
                    "other's free space (%.2f of its, %.2f of the base's), above "
                    "max_conflict_fraction %.2f and each way above half of it",
                    rep.conflict_fraction, rep.walls_on_base_free, rep.base_walls_on_free,
                    opt.max_conflict_fraction);
      rep.reason = buf;
      if (hints) hints->by_name.erase(maps[i].name);
      continue;
    }
    if (hints) hints->by_name[maps[i].name] = rep.alignment;
    if (rep.conflict_fraction > opt.max_conflict_fraction) one_way.push_back({i, moved.size()});
    moved.push_back(std::move(on_base));
  }
  // A map let in with one-way conflicts adds walls where the base has floor; only two other
  // maps can outvote them (with one, they tie and the tie rule decides, `occupied` by default).
  if (moved.size() < 3)
    for (auto it = one_way.rbegin(); it != one_way.rend(); ++it) {
      SourceReport& rep = res.sources[it->first];
      rep.used = false;
      char buf[200];
      std::snprintf(buf, sizeof(buf),
                    "conflicts with the base one way: %.2f of its walls on the base's free space "
                    "(above max_conflict_fraction %.2f), and too few other maps to outvote them",
                    rep.walls_on_base_free, opt.max_conflict_fraction);
      rep.reason = buf;
      moved.erase(moved.begin() + static_cast<std::ptrdiff_t>(it->second));
    }
  res.maps_used = moved.size();
  if (static_cast<int>(moved.size()) < opt.min_maps) {
    std::string why;
    for (const auto& q : res.sources)
      if (!q.used) why += "; " + q.name + ": " + q.reason;
    return fail("only " + std::to_string(moved.size()) + " usable map(s), min_maps is " +
                std::to_string(opt.min_maps) + why);
  }
  res.fused = ref;  // the base's grid, every cell decided below
  std::fill(res.fused.cells.begin(), res.fused.cells.end(), int8_t{-1});
  for (size_t c = 0; c < ref.cells.size(); ++c) {
    size_t votes[3] = {0, 0, 0};
    for (const auto& m : moved) {
      const int v = eval::NormalizedCell(m.cells[c]);
      if (v < 0 && !opt.unknown_votes) continue;
      ++votes[v + 1];
    }
    const size_t voters = votes[0] + votes[1] + votes[2];
    if (voters == 0) continue;  // nobody knows it: unknown
    bool tied = false;
    const int v = VoteCell(votes, opt.tie, &tied);
    if (tied)
      ++res.ties;
    else if (votes[v + 1] == voters)
      ++res.unanimous;
    else
      ++res.majority;
    res.fused.cells[c] = static_cast<int8_t>(v < 0 ? -1 : v == 0 ? 0 : 100);
  }
  if (sources) *sources = res.sources;
  return res;
}

std::string ReportJson(const FusionResult& r) {
  // Names are the channels or, offline, the files' paths: escaped, and of any length.
  std::string s =
      "{\"base\": \"" + JsonEscape(r.base) + "\", \"maps_used\": " + std::to_string(r.maps_used) +
      ", \"unanimous\": " + std::to_string(r.unanimous) +
      ", \"majority\": " + std::to_string(r.majority) + ", \"ties\": " + std::to_string(r.ties) +
      ", \"width\": " + std::to_string(r.fused.width) +
      ", \"height\": " + std::to_string(r.fused.height) + ", \"sources\": [";
  for (size_t i = 0; i < r.sources.size(); ++i) {
    const SourceReport& q = r.sources[i];
    char nums[512];
    std::snprintf(nums, sizeof(nums),
                  "\"rotation_rad\": %.5f, \"dx_m\": %.4f, \"dy_m\": %.4f, "
                  "\"overlap_fraction\": %.4f, \"conflict_fraction\": %.4f, "
                  "\"walls_on_base_free\": %.4f, \"base_walls_on_free\": %.4f, "
                  "\"known_cells\": %zu}",
                  q.alignment.rotation_rad, q.alignment.dx_m, q.alignment.dy_m, q.overlap_fraction,
                  q.conflict_fraction, q.walls_on_base_free, q.base_walls_on_free, q.known_cells);
    s += std::string(i ? ", " : "") + "{\"name\": \"" + JsonEscape(q.name) +
         "\", \"used\": " + (q.used ? "true" : "false") + ", \"reason\": \"" +
         JsonEscape(q.reason) + "\", " + nums;
  }
  return s + "]}";
}

Status WriteFusionOutputs(const FusionResult& r, const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  const std::string base = dir + "/fused_map";
  Status s = io::WriteMapServer(r.fused, base);
  if (s.ok()) s = io::WritePng(base + ".png", io::RenderGrid(r.fused, {}, 1));
  if (!s.ok()) return s;
  // Written beside and renamed over, so a kill mid-write leaves the previous report whole.
  const std::string json = dir + "/fusion.json", tmp = json + ".tmp";
  std::FILE* f = std::fopen(tmp.c_str(), "w");
  if (!f) return MakeError(ErrorCode::kUnavailable, "cannot write " + tmp);
  const bool written = std::fprintf(f, "%s\n", ReportJson(r).c_str()) >= 0;
  if (std::fclose(f) != 0 || !written || std::rename(tmp.c_str(), json.c_str()) != 0)
    return MakeError(ErrorCode::kIo, "cannot write " + json);
  return Status::Ok();
}

}  // namespace omni::map_fusion
