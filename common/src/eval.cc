#include "omni/eval/eval.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <random>
#include <thread>
#include <unordered_map>
#include <vector>

#include <Eigen/Geometry>

namespace omni::eval {

int NormalizedCell(int8_t v) {
  if (v < 0) return -1;
  return v > 50 ? 1 : 0;
}

Result<Association> Associate(const io::Trajectory& ref, const io::Trajectory& est,
                              double max_dt_s) {
  Association a;
  if (ref.format == io::Trajectory::Format::kIndexed2D &&
      est.format == io::Trajectory::Format::kIndexed2D) {
    // Index -> entry; an index twice is an error (which one would be meant?).
    auto index = [](const io::Trajectory& t, const char* which,
                    std::unordered_map<int64_t, size_t>* by) -> Status {
      for (size_t i = 0; i < t.entries.size(); ++i)
        if (auto [at, fresh] = by->emplace(t.entries[i].index, i); !fresh)
          return MakeError(ErrorCode::kInvalidArgument,
                           std::string("the ") + which + " has index " +
                               std::to_string(t.entries[i].index) + " twice (entries " +
                               std::to_string(at->second + 1) + " and " + std::to_string(i + 1) +
                               ")");
      return Status::Ok();
    };
    std::unordered_map<int64_t, size_t> by_index, ref_seen;
    if (Status s = index(est, "estimate", &by_index); !s.ok()) return s.error();
    if (Status s = index(ref, "reference", &ref_seen); !s.ok()) return s.error();
    for (size_t i = 0; i < ref.entries.size(); ++i) {
      auto it = by_index.find(ref.entries[i].index);
      if (it == by_index.end()) continue;
      a.ref_index.push_back(i);
      a.est_index.push_back(it->second);
    }
  } else {
    std::vector<size_t> order(est.entries.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = i;
    // Stable: estimate poses on one stamp keep their file order.
    std::stable_sort(order.begin(), order.end(), [&](size_t x, size_t y) {
      return est.entries[x].timestamp_s < est.entries[y].timestamp_s;
    });
    std::unordered_map<double, size_t> taken;  // estimate stamp -> reference poses matched to it
    for (size_t i = 0; i < ref.entries.size(); ++i) {
      const double t = ref.entries[i].timestamp_s;
      auto it = std::lower_bound(order.begin(), order.end(), t, [&](size_t k, double v) {
        return est.entries[k].timestamp_s < v;
      });
      size_t best = SIZE_MAX;
      double best_dt = max_dt_s;
      for (auto c : {it, it == order.begin() ? it : it - 1}) {
        if (c == order.end()) continue;
        const double dt = std::fabs(est.entries[*c].timestamp_s - t);
        if (dt <= best_dt) {
          best_dt = dt;
          best = *c;
        }
      }
      if (best == SIZE_MAX) continue;
      const double stamp = est.entries[best].timestamp_s;
      const auto same =
          std::equal_range(order.begin(), order.end(), stamp, [&](const auto& l, const auto& r) {
            using L = std::decay_t<decltype(l)>;
            if constexpr (std::is_same_v<L, double>)
              return l < est.entries[r].timestamp_s;
            else
              return est.entries[l].timestamp_s < r;
          });
      const size_t shared = static_cast<size_t>(same.second - same.first);
      if (shared > 1) {
        ++a.ambiguous;
        size_t& k = taken[stamp];
        best = *(same.first + static_cast<std::ptrdiff_t>(std::min(k, shared - 1)));
        ++k;
      }
      a.ref_index.push_back(i);
      a.est_index.push_back(best);
    }
  }
  if (a.ref_index.empty())
    return MakeError(ErrorCode::kInvalidArgument,
                     "no pose of the estimate matches a pose of the reference (by index, or by "
                     "timestamp within " +
                         std::to_string(max_dt_s) + " s)");
  return a;
}

Result<AteResult> ComputeAte(const io::Trajectory& ref, const io::Trajectory& est, bool se3,
                             double max_dt_s) {
  auto assoc = Associate(ref, est, max_dt_s);
  if (!assoc.ok()) return assoc.error();
  const size_t n = assoc->ref_index.size();
  const int dim = se3 ? 3 : 2;
  Eigen::MatrixXd src(dim, n), dst(dim, n);
  for (size_t k = 0; k < n; ++k) {
    src.col(static_cast<Eigen::Index>(k)) = est.entries[assoc->est_index[k]].position.head(dim);
    dst.col(static_cast<Eigen::Index>(k)) = ref.entries[assoc->ref_index[k]].position.head(dim);
  }
  AteResult r;
  r.ambiguous = assoc->ambiguous;
  r.matched = n;
  r.reference_poses = ref.entries.size();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  if (n >= 2) {
    const Eigen::MatrixXd m = Eigen::umeyama(src, dst, /*with_scaling=*/false);
    T.linear().topLeftCorner(dim, dim) = m.topLeftCorner(dim, dim);
    T.translation().head(dim) = m.topRightCorner(dim, 1);
  } else {
    T.translation().head(dim) = dst.col(0) - src.col(0);
  }
  r.alignment = T;
  double sum2 = 0, sum = 0, rot2 = 0;
  for (size_t k = 0; k < n; ++k) {
    const auto& e = est.entries[assoc->est_index[k]];
    const auto& g = ref.entries[assoc->ref_index[k]];
    Eigen::Vector3d p = T * e.position;
    if (!se3) p.z() = g.position.z();
    const double d = (p - g.position).norm();
    sum2 += d * d;
    sum += d;
    r.max_m = std::max(r.max_m, d);
    const Eigen::Quaterniond q(T.linear() * e.orientation.toRotationMatrix());
    const double ang = q.angularDistance(g.orientation);
    rot2 += ang * ang;
  }
  r.rmse_m = std::sqrt(sum2 / static_cast<double>(n));
  r.mean_m = sum / static_cast<double>(n);
  r.rot_rmse_rad = std::sqrt(rot2 / static_cast<double>(n));
  return r;
}

Result<RpeResult> ComputeRpe(const io::Trajectory& ref, const io::Trajectory& est, int delta,
                             double max_dt_s) {
  if (delta < 1) return MakeError(ErrorCode::kInvalidArgument, "RPE delta must be >= 1");
  auto assoc = Associate(ref, est, max_dt_s);
  if (!assoc.ok()) return assoc.error();
  auto iso = [](const io::TrajectoryEntry& e) {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = e.orientation.toRotationMatrix();
    t.translation() = e.position;
    return t;
  };
  RpeResult r;
  r.ambiguous = assoc->ambiguous;
  r.matched = assoc->ref_index.size();
  r.reference_poses = ref.entries.size();
  double t2 = 0, r2 = 0;
  const size_t n = assoc->ref_index.size();
  for (size_t k = 0; k + static_cast<size_t>(delta) < n; ++k) {
    const size_t j = k + static_cast<size_t>(delta);
    const Eigen::Isometry3d dr =
        iso(ref.entries[assoc->ref_index[k]]).inverse() * iso(ref.entries[assoc->ref_index[j]]);
    const Eigen::Isometry3d de =
        iso(est.entries[assoc->est_index[k]]).inverse() * iso(est.entries[assoc->est_index[j]]);
    const Eigen::Isometry3d err = dr.inverse() * de;
    const double te = err.translation().norm();
    const double re = Eigen::AngleAxisd(err.linear()).angle();
    t2 += te * te;
    r2 += re * re;
    r.trans_max_m = std::max(r.trans_max_m, te);
    r.rot_max_rad = std::max(r.rot_max_rad, re);
    ++r.pairs;
  }
  if (r.pairs == 0) return MakeError(ErrorCode::kInvalidArgument, "too few matched poses for RPE");
  r.trans_rmse_m = std::sqrt(t2 / static_cast<double>(r.pairs));
  r.rot_rmse_rad = std::sqrt(r2 / static_cast<double>(r.pairs));
  return r;
}

namespace {

struct Cell {
  double x, y;  // world coordinates of the cell centre
};

std::vector<Cell> OccupiedCells(const io::GridMap& m) {
  std::vector<Cell> out;
  for (int row = 0; row < m.height; ++row)
    for (int col = 0; col < m.width; ++col)
      if (NormalizedCell(m.at(col, row)) == 1)
        out.push_back({m.origin_x_m + (col + 0.5) * m.resolution_m,
                       m.origin_y_m + (row + 0.5) * m.resolution_m});
  return out;
}

// Reference cells within `tol` of an occupied cell, as a mask over the reference grid.
std::vector<uint8_t> DilatedOccupied(const io::GridMap& m, int tol) {
  std::vector<uint8_t> mask(m.cells.size(), 0);
  for (int row = 0; row < m.height; ++row)
    for (int col = 0; col < m.width; ++col) {
      if (NormalizedCell(m.at(col, row)) != 1) continue;
      for (int dy = -tol; dy <= tol; ++dy)
        for (int dx = -tol; dx <= tol; ++dx)
          if (m.Contains(col + dx, row + dy))
            mask[static_cast<size_t>(row + dy) * m.width + col + dx] = 1;
    }
  return mask;
}

}  // namespace

void MapAlignment::Apply(double x, double y, double* ox, double* oy) const {
  const double c = std::cos(rotation_rad), s = std::sin(rotation_rad);
  const double rx = x - cx_m, ry = y - cy_m;
  *ox = cx_m + c * rx - s * ry + dx_m;
  *oy = cy_m + s * rx + c * ry + dy_m;
}

void MapAlignment::Invert(double x, double y, double* ox, double* oy) const {
  const double c = std::cos(rotation_rad), s = std::sin(rotation_rad);
  const double rx = x - dx_m - cx_m, ry = y - dy_m - cy_m;
  *ox = cx_m + c * rx + s * ry;
  *oy = cy_m - s * rx + c * ry;
}

MapAlignment AlignMap(const io::GridMap& ref, const io::GridMap& est, const MapCompareOptions& opt,
                      const MapAlignment* guess) {
  MapAlignment best;
  best.cx_m = est.origin_x_m + est.width * est.resolution_m / 2;
  best.cy_m = est.origin_y_m + est.height * est.resolution_m / 2;
  double rot = 0, dx = 0, dy = 0;  // the search's centre
  if (guess) {
    // The same transform about this map's centre c': R (p - c') + c' + d' = R (p - c) + c + d
    // gives d' = (I - R)(c - c') + d.
    const double c = std::cos(guess->rotation_rad), s = std::sin(guess->rotation_rad);
    const double ex = guess->cx_m - best.cx_m, ey = guess->cy_m - best.cy_m;
    rot = guess->rotation_rad;
    dx = ex - (c * ex - s * ey) + guess->dx_m;
    dy = ey - (s * ex + c * ey) + guess->dy_m;
  }
  const auto occ = OccupiedCells(est);
  best.occupied = occ.size();
  if (occ.empty() || ref.width <= 0) return best;
  const auto mask = DilatedOccupied(ref, 1);
  // The estimate's occupied cells turned by r about its centre, in reference-cell units from
  // the reference origin: a shift (dx, dy) then only adds dx/res, dy/res to every point.
  const double inv_res = 1.0 / ref.resolution_m;
  auto turn_cells = [&](const std::vector<Cell>& cells, double r, std::vector<double>* u,
                        std::vector<double>* v) {
    const double c = std::cos(r), s = std::sin(r);
    u->resize(cells.size());
    v->resize(cells.size());
    for (size_t i = 0; i < cells.size(); ++i) {
      const double rx = cells[i].x - best.cx_m, ry = cells[i].y - best.cy_m;
      (*u)[i] = (best.cx_m + c * rx - s * ry - ref.origin_x_m) * inv_res;
      (*v)[i] = (best.cy_m + s * rx + c * ry - ref.origin_y_m) * inv_res;
    }
  };
  auto turn = [&](double r, std::vector<double>* u, std::vector<double>* v) {
    turn_cells(occ, r, u, v);
  };
  // The cells the levels before the last score: all, or a fixed random subset of max_cells (a
  // partial Fisher-Yates shuffle with a fixed seed, kept in map order), so that a large map
  // costs the search what a map of max_cells occupied cells would.
  std::vector<Cell> subset;
  if (opt.max_cells > 0 && occ.size() > static_cast<size_t>(opt.max_cells)) {
    std::vector<uint32_t> index(occ.size());
    for (size_t i = 0; i < index.size(); ++i) index[i] = static_cast<uint32_t>(i);
    std::mt19937 rng(12345);
    const size_t k = static_cast<size_t>(opt.max_cells);
    for (size_t i = 0; i < k; ++i) {
      const size_t j = i + static_cast<size_t>(rng() % (index.size() - i));
      std::swap(index[i], index[j]);
    }
    index.resize(k);
    std::sort(index.begin(), index.end());
    subset.reserve(k);
    for (uint32_t i : index) subset.push_back(occ[i]);
  }
  auto count = [&](const std::vector<double>& u, const std::vector<double>& v, double dx,
                   double dy) {
    const double su = dx * inv_res, sv = dy * inv_res;
    size_t hits = 0;
    for (size_t i = 0; i < u.size(); ++i) {
      const int col = static_cast<int>(std::floor(u[i] + su));
      const int row = static_cast<int>(std::floor(v[i] + sv));
      if (ref.Contains(col, row) && mask[static_cast<size_t>(row) * ref.width + col]) ++hits;
    }
    return hits;
  };
  best.rotation_rad = rot;
  best.dx_m = dx;
  best.dy_m = dy;
  {
    std::vector<double> u, v;
    turn(rot, &u, &v);
    best.overlap = count(u, v, dx, dy);
  }
  if (!opt.align) return best;
  // Coarse to fine: each level searches a window around the best so far with a finer step.
  double rot_range = opt.max_rotation_rad, shift_range = opt.max_shift_m;
  const int coarse = std::max(1, opt.coarse_steps), div = std::max(2, opt.refine_divisions);
  double shift_step = std::max(opt.max_shift_m / coarse, ref.resolution_m);
  // A rotation step moves a cell at distance r from the centre by r x step: on a large map a
  // step of range / coarse_steps moves its outer walls by metres, and only the cells near the
  // centre can score at the right rotation, which on a big floor is no basin at all (a 90 m
  // floor was aligned 0.5 m off). So the step also keeps the cells' RMS distance within one
  // shift step.
  double radius2 = 0;
  for (const Cell& c : occ)
    radius2 += (c.x - best.cx_m) * (c.x - best.cx_m) + (c.y - best.cy_m) * (c.y - best.cy_m);
  const double radius = std::sqrt(radius2 / static_cast<double>(occ.size()));
  double rot_step = opt.max_rotation_rad / coarse;
  if (opt.rotation_step_from_extent && radius * rot_step > shift_step)
    rot_step = shift_step / radius;
  // At most kMaxRotationSteps a side, so a wide range on a huge map (±3.2 rad, a 300 m radius)
  // does not take minutes.
  constexpr double kMaxRotationSteps = 128;
  rot_step = std::max({rot_step, opt.max_rotation_rad / kMaxRotationSteps, 1e-3});
  // The best score so far, counted over the cells the current level scores.
  auto score_at_centre = [&](const std::vector<Cell>& cells) {
    std::vector<double> u, v;
    turn_cells(cells, rot, &u, &v);
    return count(u, v, dx, dy);
  };
  size_t best_score = subset.empty() ? best.overlap : score_at_centre(subset);
  const int threads = opt.threads > 0
                          ? opt.threads
                          : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  struct Found {
    size_t score = 0;
    int ix = 0, iy = 0;
    bool any = false;
  };
  for (int level = 0; level < opt.levels; ++level) {
    // Counted steps, not accumulated ones: far from the origin (a grid placed at 1e18 m) a
    // floating `x += step` stops advancing and the search never ends.
    const int nr = static_cast<int>(std::ceil(rot_range / rot_step - 1e-9));
    const int ns = static_cast<int>(std::ceil(shift_range / shift_step - 1e-9));
    // Each rotation's shifts are scored by one thread; the rotations' bests are then taken in
    // order, so the result is the one a single thread finds (the first of equal scores).
    std::vector<Found> found(static_cast<size_t>(2 * nr + 1));
    std::atomic<int> next{0};
    const bool last = level + 1 == opt.levels;
    const std::vector<Cell>& cells = subset.empty() || last ? occ : subset;
    if (last && !subset.empty()) best_score = score_at_centre(occ);  // every cell from here on
    auto work = [&] {
      std::vector<double> u, v;
      for (int k = next++; k < static_cast<int>(found.size()); k = next++) {
        turn_cells(cells, rot + (k - nr) * rot_step, &u, &v);
        Found& f = found[static_cast<size_t>(k)];
        for (int ix = -ns; ix <= ns; ++ix)
          for (int iy = -ns; iy <= ns; ++iy) {
            const size_t sc = count(u, v, dx + ix * shift_step, dy + iy * shift_step);
            if (!f.any || sc > f.score) f = {sc, ix, iy, true};
          }
      }
    };
    const int n_threads = std::min(threads, static_cast<int>(found.size()));
    std::vector<std::thread> pool;
    for (int t = 1; t < n_threads; ++t) pool.emplace_back(work);
    work();
    for (auto& t : pool) t.join();
    double br = rot, bx = dx, by = dy;
    for (size_t k = 0; k < found.size(); ++k)
      if (found[k].score > best_score) {
        best_score = found[k].score;
        br = rot + (static_cast<int>(k) - nr) * rot_step;
        bx = dx + found[k].ix * shift_step;
        by = dy + found[k].iy * shift_step;
      }
    rot = br;
    dx = bx;
    dy = by;
    rot_range = rot_step;
    shift_range = shift_step;
    rot_step = std::max(rot_step / div, 1e-4);
    shift_step = std::max(shift_step / div, ref.resolution_m / 4);
  }
  if (opt.levels <= 0) return best;  // no search: the centre, counted over every cell
  // The levels before the last chose by a subset's score: never end worse, over every cell,
  // than where the search started (maps that already line up stay put).
  if (best_score < best.overlap) return best;
  best.rotation_rad = rot;
  best.dx_m = dx;
  best.dy_m = dy;
  best.overlap = best_score;
  return best;
}

io::GridMap ResampleOnto(const io::GridMap& geometry, const io::GridMap& est,
                         const MapAlignment& a) {
  io::GridMap out;
  out.resolution_m = geometry.resolution_m;
  out.origin_x_m = geometry.origin_x_m;
  out.origin_y_m = geometry.origin_y_m;
  out.width = geometry.width;
  out.height = geometry.height;
  out.cells.assign(geometry.cells.size(), -1);
  // A finer estimate is sampled k x k times per cell and the samples combined by their largest
  // value (occupied over free over unknown): its one-cell-thick walls would otherwise fall
  // between the centres of the coarser cells.
  const int k =
      est.resolution_m < 0.75 * geometry.resolution_m
          ? std::min(16, static_cast<int>(std::lround(geometry.resolution_m / est.resolution_m)))
          : 1;
  for (int row = 0; row < out.height; ++row)
    for (int col = 0; col < out.width; ++col) {
      int8_t v = -1;
      for (int sy = 0; sy < k; ++sy)
        for (int sx = 0; sx < k; ++sx) {
          double ex, ey;
          a.Invert(out.origin_x_m + (col + (sx + 0.5) / k) * out.resolution_m,
                   out.origin_y_m + (row + (sy + 0.5) / k) * out.resolution_m, &ex, &ey);
          const int ec = static_cast<int>(std::floor((ex - est.origin_x_m) / est.resolution_m));
          const int er = static_cast<int>(std::floor((ey - est.origin_y_m) / est.resolution_m));
          if (est.Contains(ec, er)) v = std::max(v, est.at(ec, er));
        }
      out.at(col, row) = v;
    }
  return out;
}

namespace {

// `est` scored on `ref`'s grid, moved by `a`.
MapCompareResult ScoreAligned(const io::GridMap& ref, const io::GridMap& est, const MapAlignment& a,
                              const MapCompareOptions& opt) {
  MapCompareResult res;
  res.rotation_rad = a.rotation_rad;
  res.dx_m = a.dx_m;
  res.dy_m = a.dy_m;
  // For each reference cell, the estimate cell that lands on it.
  const io::GridMap moved = ResampleOnto(ref, est, a);
  double sum2 = 0;
  for (size_t i = 0; i < ref.cells.size(); ++i) {
    const int m = NormalizedCell(moved.cells[i]);
    const int t = NormalizedCell(ref.cells[i]);
    const double d = static_cast<double>(t - m);
    sum2 += d * d;
    if (t != m) ++res.differing_cells;
    ++res.cells;
  }
  res.error = std::sqrt(sum2);
  // Precision / recall of occupied cells with a tolerance.
  const int tol = opt.match_tolerance_cells;
  const auto ref_mask = DilatedOccupied(ref, tol);
  const auto occ = OccupiedCells(est);
  size_t tp_est = 0;
  for (const auto& c : occ) {
    double x, y;
    a.Apply(c.x, c.y, &x, &y);
    const int col = static_cast<int>(std::floor((x - ref.origin_x_m) / ref.resolution_m));
    const int row = static_cast<int>(std::floor((y - ref.origin_y_m) / ref.resolution_m));
    if (ref.Contains(col, row) && ref_mask[static_cast<size_t>(row) * ref.width + col]) ++tp_est;
  }
  res.precision = occ.empty() ? 0 : static_cast<double>(tp_est) / static_cast<double>(occ.size());
  const auto ref_occ = OccupiedCells(ref);
  // The tolerance in the estimate's cells: the same distance as `tol` reference cells.
  const int tol_est =
      est.resolution_m == ref.resolution_m
          ? tol
          : static_cast<int>(std::ceil(tol * ref.resolution_m / est.resolution_m - 1e-9));
  size_t tp_ref = 0;
  for (const auto& c : ref_occ) {
    double ex, ey;
    a.Invert(c.x, c.y, &ex, &ey);
    const int ec = static_cast<int>(std::floor((ex - est.origin_x_m) / est.resolution_m));
    const int er = static_cast<int>(std::floor((ey - est.origin_y_m) / est.resolution_m));
    bool found = false;
    for (int dy = -tol_est; dy <= tol_est && !found; ++dy)
      for (int dx = -tol_est; dx <= tol_est && !found; ++dx)
        if (est.Contains(ec + dx, er + dy) && NormalizedCell(est.at(ec + dx, er + dy)) == 1)
          found = true;
    if (found) ++tp_ref;
  }
  res.recall =
      ref_occ.empty() ? 0 : static_cast<double>(tp_ref) / static_cast<double>(ref_occ.size());
  return res;
}

}  // namespace

MapCompareResult CompareMaps(const io::GridMap& ref, const io::GridMap& est,
                             const MapCompareOptions& opt) {
  const MapAlignment a = AlignMap(ref, est, opt);
  MapCompareResult res = ScoreAligned(ref, est, a, opt);
  if (!opt.align || (a.rotation_rad == 0 && a.dx_m == 0 && a.dy_m == 0)) return res;
  // The search maximises the overlap of occupied cells, which is not the error reported: a map
  // with walls a cell thick on one side, or a few stray cells, gains overlap by moving a cell or
  // half of one (where the rounding of a cell centre on a cell edge decides its neighbour), and
  // every wall then stands off the reference's. The alignment is there to undo a frame
  // difference, so it is kept only when it scores better than the maps as they lie.
  MapCompareOptions as_they_lie = opt;
  as_they_lie.align = false;
  MapCompareResult unmoved = ScoreAligned(ref, est, AlignMap(ref, est, as_they_lie), opt);
  return unmoved.error <= res.error ? unmoved : res;
}

}  // namespace omni::eval
