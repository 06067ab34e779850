#include "omni/rbpf_mapper/scan_matcher.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace omni::rbpf {

MatchScan MakeMatchScan(const std::vector<Eigen::Vector2d>& points, const std::vector<uint8_t>& hit,
                        const Pose2& sensor_in_base, double res, const MatcherOptions& opt) {
  MatchScan m;
  int valid = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    if (!hit[i]) continue;
    const double r = points[i].norm();
    if (r > opt.max_match_range_m || r < 1e-3) continue;
    const int k = valid++;
    // One free step back along the beam: sqrt(2) cells, as GMapping does.
    const Eigen::Vector2d back = points[i] * (1.0 - std::sqrt(2.0) * res / r);
    const Eigen::Vector2d h = sensor_in_base.Transform(points[i]);
    const Eigen::Vector2d f = sensor_in_base.Transform(back);
    if (k % std::max(1, opt.beam_step) == 0) {
      m.hits.push_back(h);
      m.frees.push_back(f);
    }
    if (k % std::max(1, opt.search_beam_step) == 0) {
      m.coarse_hits.push_back(h);
      m.coarse_frees.push_back(f);
    }
  }
  return m;
}

ScanMatcher::ScanMatcher(const MatcherOptions& options, double resolution_m)
    : opt_(options), table_resolution_m_(resolution_m) {
  const int k = opt_.kernel_cells;
  table_max_d2_ = (k + 1.0) * (k + 1.0) * 2.0 * resolution_m * resolution_m;
  const double inv_score = 1.0 / (2.0 * opt_.sigma_score_m * opt_.sigma_score_m);
  table_.resize(kTable + 1);
  for (int i = 0; i <= kTable; ++i)
    table_[static_cast<size_t>(i)] = std::exp(-(table_max_d2_ * i / kTable) * inv_score);
}

namespace {

inline int64_t FastFloor(double v) {
  const int64_t i = static_cast<int64_t>(v);
  return v < static_cast<double>(i) ? i - 1 : i;
}

// The (2k+1) x (2k+1) neighbourhood of a cell as row bit masks (bit j = column offset j - k),
// when it lies inside one tile; a tile never written reads as all unknown (no bits).
struct BitWindow {
  const TiledGrid::Tile* tile = nullptr;
  int64_t lx = 0, ly = 0;
  uint64_t mask = 0;
  int k = 0;
  bool inside = false;
  BitWindow(const TiledGrid& grid, int64_t x, int64_t y, int kernel) : k(kernel) {
    constexpr int64_t m = TiledGrid::kTileMask;
    lx = x & m;
    ly = y & m;
    if (lx >= k && ly >= k && lx <= m - k && ly <= m - k) {
      inside = true;
      tile = grid.TileAt(x >> TiledGrid::kTileBits, y >> TiledGrid::kTileBits);
      mask = (uint64_t{1} << (2 * k + 1)) - 1;
    }
  }
  uint64_t Occupied(int dy) const {
    return tile ? (tile->occupied_bits[static_cast<size_t>(ly + dy)] >> (lx - k)) & mask : 0;
  }
  uint64_t Free(int dy) const {
    return tile ? (tile->free_bits[static_cast<size_t>(ly + dy)] >> (lx - k)) & mask : 0;
  }
};

}  // namespace

ScoreResult ScanMatcher::Score(const TiledGrid& grid, const Pose2& p, const MatchScan& scan) const {
  ScoreResult out;
  const double c = std::cos(p.theta), s = std::sin(p.theta);
  const double res = grid.resolution(), inv_res = 1.0 / res;
  const double inv_score = 1.0 / (2.0 * opt_.sigma_score_m * opt_.sigma_score_m);
  const double inv_lik = 1.0 / (2.0 * opt_.sigma_likelihood_m * opt_.sigma_likelihood_m);
  const int k = opt_.kernel_cells;
  // exp(-d^2 * inv_score) from the table built for this resolution (else computed).
  const bool use_table = res == table_resolution_m_;
  const double to_index = use_table ? kTable / table_max_d2_ : 0.0;
  out.beams = static_cast<int>(scan.hits.size());
  double score = 0, loglik = 0;
  int matched = 0;
  for (size_t i = 0; i < scan.hits.size(); ++i) {
    const Eigen::Vector2d& h = scan.hits[i];
    const Eigen::Vector2d& f = scan.frees[i];
    const double hx = (p.x + c * h.x() - s * h.y()) * inv_res;
    const double hy = (p.y + s * h.x() + c * h.y()) * inv_res;
    const double fx = (p.x + c * f.x() - s * f.y()) * inv_res;
    const double fy = (p.y + s * f.x() + c * f.y()) * inv_res;
    const int64_t hcx = FastFloor(hx), hcy = FastFloor(hy);
    const int64_t fcx = FastFloor(fx), fcy = FastFloor(fy);
    double best = std::numeric_limits<double>::infinity();
    const BitWindow hw(grid, hcx, hcy, k), fw(grid, fcx, fcy, k);
    if (hw.inside && fw.inside) {
      // Fast path: both neighbourhoods lie inside one tile each; the cells that qualify are
      // the bits set in (occupied around the hit) & (free around the step back).
      for (int dy = -k; dy <= k; ++dy) {
        uint64_t cand = hw.Occupied(dy) & fw.Free(dy);
        while (cand) {
          const int dx = __builtin_ctzll(cand) - k;
          cand &= cand - 1;
          const double ex = static_cast<double>(hcx + dx) + 0.5 - hx;
          const double ey = static_cast<double>(hcy + dy) + 0.5 - hy;
          best = std::min(best, ex * ex + ey * ey);
        }
      }
    } else {
      for (int dy = -k; dy <= k; ++dy)
        for (int dx = -k; dx <= k; ++dx) {
          if (!grid.Occupied(hcx + dx, hcy + dy)) continue;  // as the bit masks say
          if (!grid.Free(fcx + dx, fcy + dy)) continue;
          const double ex = static_cast<double>(hcx + dx) + 0.5 - hx;
          const double ey = static_cast<double>(hcy + dy) + 0.5 - hy;
          best = std::min(best, ex * ex + ey * ey);
        }
    }
    if (best < std::numeric_limits<double>::infinity()) {
      const double d2 = best * res * res;
      ++matched;
      if (use_table) {
        const double idx = std::min(d2 * to_index, static_cast<double>(kTable));
        score += table_[static_cast<size_t>(idx)];
      } else {
        score += std::exp(-d2 * inv_score);
      }
      loglik -= d2 * inv_lik;
    } else {
      loglik += opt_.null_log_likelihood;
    }
  }
  out.score = score;
  out.log_likelihood = loglik;
  out.matched = matched;
  return out;
}

Pose2 ScanMatcher::CorrelativeSearch(const TiledGrid& grid, const Pose2& start,
                                     const MatchScan& scan) const {
  const double res = grid.resolution();
  const int n_xy = static_cast<int>(std::ceil(opt_.search_xy_m / res));
  const int n_t = static_cast<int>(std::ceil(opt_.search_theta_rad / opt_.search_theta_step_rad));
  const size_t nb = scan.coarse_hits.size();
  std::vector<int64_t> hx(nb), hy(nb), fx(nb), fy(nb);
  const int side = 2 * n_xy + 1;
  std::vector<float> acc(static_cast<size_t>(side * side));
  double best_score = -1;
  Pose2 best = start;
  for (int it = -n_t; it <= n_t; ++it) {
    const double th = start.theta + it * opt_.search_theta_step_rad;
    const double c = std::cos(th), s = std::sin(th);
    for (size_t i = 0; i < nb; ++i) {
      const auto& h = scan.coarse_hits[i];
      const auto& f = scan.coarse_frees[i];
      hx[i] = grid.CellX(start.x + c * h.x() - s * h.y());
      hy[i] = grid.CellY(start.y + s * h.x() + c * h.y());
      fx[i] = grid.CellX(start.x + c * f.x() - s * f.y());
      fy[i] = grid.CellY(start.y + s * f.x() + c * f.y());
    }
    std::fill(acc.begin(), acc.end(), 0.f);
    for (size_t i = 0; i < nb; ++i) {
      // Each beam votes for the shifts that put its end point on (or next to) an occupied cell
      // seen from the beam's side; walk the occupied cells of the window once per beam.
      for (int sy = -n_xy - 1; sy <= n_xy + 1; ++sy)
        for (int sx = -n_xy - 1; sx <= n_xy + 1; ++sx) {
          if (!grid.Occupied(hx[i] + sx, hy[i] + sy)) continue;
          if (grid.Free(fx[i] + sx, fy[i] + sy) == false && grid.Known(fx[i] + sx, fy[i] + sy))
            continue;  // seen from behind (occupied or unknown-behind is allowed)
          // Full vote at the exact shift, half to the 4-neighbours.
          for (int k = 0; k < 5; ++k) {
            static const int kdx[5] = {0, 1, -1, 0, 0}, kdy[5] = {0, 0, 0, 1, -1};
            const int ux = sx + kdx[k], uy = sy + kdy[k];
            if (ux < -n_xy || ux > n_xy || uy < -n_xy || uy > n_xy) continue;
            float& a = acc[static_cast<size_t>((uy + n_xy) * side + (ux + n_xy))];
            a += k == 0 ? 1.f : 0.25f;
          }
        }
    }
    for (int uy = -n_xy; uy <= n_xy; ++uy)
      for (int ux = -n_xy; ux <= n_xy; ++ux) {
        // Votes per beam, charged for the distance from the start (aliasing in corridors).
        const Pose2 cand(start.x + ux * res, start.y + uy * res, th);
        const double score =
            acc[static_cast<size_t>((uy + n_xy) * side + (ux + n_xy))] / static_cast<double>(nb) -
            Prior(start, cand);
        if (score > best_score) {
          best_score = score;
          best = Pose2(start.x + ux * res, start.y + uy * res, WrapAngle(th));
        }
      }
  }
  return best;
}

double ScanMatcher::Prior(const Pose2& start, const Pose2& p) const {
  const double dx = p.x - start.x, dy = p.y - start.y, dt = WrapAngle(p.theta - start.theta);
  const double sxy = std::max(opt_.search_xy_m, 1e-3), st = std::max(opt_.search_theta_rad, 1e-3);
  return opt_.prior_weight * ((dx * dx + dy * dy) / (sxy * sxy) + dt * dt / (st * st));
}

ScoreResult ScanMatcher::Refine(const TiledGrid& grid, const MatchScan& scan, Pose2* pose) const {
  // Hill climbing: try a step along each axis both ways, move to the best, halve when stuck.
  Pose2 cur = *pose;
  ScoreResult cur_s = Score(grid, cur, scan);
  double step_xy = opt_.refine_step_xy_m, step_t = opt_.refine_step_theta_rad;
  int halvings = 0;
  int came_by = -1;  // the move that led to `cur` (its opposite leads back to a worse pose)
  while (halvings <= opt_.refine_halvings) {
    Pose2 best = cur;
    ScoreResult best_s = cur_s;
    int best_move = -1;
    const Pose2 moves[6] = {{step_xy, 0, 0},  {-step_xy, 0, 0}, {0, step_xy, 0},
                            {0, -step_xy, 0}, {0, 0, step_t},   {0, 0, -step_t}};
    for (int i = 0; i < 6; ++i) {
      if (came_by >= 0 && i == (came_by ^ 1)) continue;  // moves come in opposite pairs
      const Pose2& m = moves[i];
      const Pose2 cand(cur.x + m.x, cur.y + m.y, WrapAngle(cur.theta + m.theta));
      const ScoreResult s = Score(grid, cand, scan);
      if (s.score > best_s.score) {
        best = cand;
        best_s = s;
        best_move = i;
      }
    }
    if (best_s.score > cur_s.score) {
      cur = best;
      cur_s = best_s;
      came_by = best_move;
    } else {
      came_by = -1;
      step_xy *= 0.5;
      step_t *= 0.5;
      ++halvings;
    }
  }
  *pose = cur;
  return cur_s;
}

MatchResult ScanMatcher::Match(const TiledGrid& grid, const Pose2& start,
                               const MatchScan& scan) const {
  MatchResult r;
  r.pose = start;
  r.score = Refine(grid, scan, &r.pose);
  if (opt_.search_below_fraction > 0 && r.score.fraction() < opt_.search_below_fraction &&
      !scan.coarse_hits.empty()) {
    // Poor local match: search the window, refine its best, keep whichever explains the scan
    // better once the distance from the start is charged.
    r.searched = true;
    Pose2 cand = CorrelativeSearch(grid, start, scan);
    const ScoreResult cs = Refine(grid, scan, &cand);
    const double n = std::max(1, r.score.beams);
    if (cs.score / n - Prior(start, cand) > r.score.score / n - Prior(start, r.pose)) {
      r.pose = cand;
      r.score = cs;
    }
  }
  r.ok = r.score.beams > 0 && r.score.fraction() >= opt_.min_match_fraction;
  return r;
}

}  // namespace omni::rbpf
