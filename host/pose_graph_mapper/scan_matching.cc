#include "omni/pose_graph_mapper/scan_matching.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include <Eigen/Dense>

namespace omni::pgm {
namespace {

// out item j = elementwise max of in items j .. j + k - 1, for j in [0, n_out); an item is
// `width` consecutive floats and `in` holds n_out + k - 1 items (overwritten). Doubling: after
// the pass with step p every item holds the max of 2p items, so width k costs about log2(k) + 1
// maxima per value instead of k.
void SlidingMax(float* in, int n_out, int k, int width, float* out) {
  const size_t n_in = static_cast<size_t>(n_out + k - 1) * width;
  // Item j + p starts p * width floats after item j: each pass is one flat, vectorisable loop.
  size_t p = 1;
  for (; 2 * p <= static_cast<size_t>(k); p *= 2) {
    const size_t off = p * width, end = n_in - 2 * off + width;
    for (size_t t = 0; t < end; ++t) in[t] = std::max(in[t], in[t + off]);
  }
  const size_t off = (static_cast<size_t>(k) - p) * width, n = static_cast<size_t>(n_out) * width;
  for (size_t t = 0; t < n; ++t) out[t] = std::max(in[t], in[t + off]);
}

// Whether the first and last row and column of a w x h row-major grid are all 0.
bool BorderIsZero(const std::vector<float>& g, int w, int h) {
  for (int x = 0; x < w; ++x)
    if (g[static_cast<size_t>(x)] != 0.f || g[static_cast<size_t>(h - 1) * w + x] != 0.f)
      return false;
  for (int y = 0; y < h; ++y)
    if (g[static_cast<size_t>(y) * w] != 0.f || g[static_cast<size_t>(y) * w + w - 1] != 0.f)
      return false;
  return true;
}

}  // namespace

LikelihoodField::LikelihoodField(const std::vector<Eigen::Vector2d>& points,
                                 const LikelihoodFieldOptions& o)
    : points_(points), res_(o.resolution_m), k_(std::max(1, o.coarse_cells)) {
  if (points.empty()) return;
  Eigen::Vector2d lo = points.front(), hi = points.front();
  bool finite = true;
  for (const auto& p : points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
    finite = finite && p.allFinite();
  }
  // A submap no lidar sees (keyframe estimates gone astray): an empty field, so no match, rather
  // than an allocation of whatever size the points span.
  const Eigen::Vector2d cells = (hi - lo + Eigen::Vector2d::Constant(2 * o.margin_m)) / res_;
  if (!finite || !cells.allFinite() ||
      cells.x() * cells.y() > static_cast<double>(kMaxFieldCells)) {
    points_.clear();
    return;
  }
  origin_ = lo - Eigen::Vector2d::Constant(o.margin_m);
  w_ = static_cast<int>(std::ceil(cells.x())) + 1;
  h_ = static_cast<int>(std::ceil(cells.y())) + 1;
  fine_.assign(static_cast<size_t>(w_) * h_, 0.f);
  const int rc = static_cast<int>(std::ceil(3 * o.sigma_m / res_));
  const double inv2s2 = 1.0 / (2 * o.sigma_m * o.sigma_m);
  // The Gaussian is separable: exp(-(dx^2 + dy^2) / 2s^2) = exp(-dx^2 / 2s^2) exp(-dy^2 / 2s^2),
  // so each point needs 2 (2 rc + 1) exponentials instead of (2 rc + 1)^2.
  std::vector<double> gx(2 * rc + 1), gy(2 * rc + 1);
  for (const auto& p : points) {
    const Eigen::Vector2i c = Cell(p);
    for (int d = -rc; d <= rc; ++d) {
      const double dx = origin_.x() + res_ * (c.x() + d + 0.5) - p.x();
      const double dy = origin_.y() + res_ * (c.y() + d + 0.5) - p.y();
      gx[static_cast<size_t>(d + rc)] = std::exp(-dx * dx * inv2s2);
      gy[static_cast<size_t>(d + rc)] = std::exp(-dy * dy * inv2s2);
    }
    for (int dy = -rc; dy <= rc; ++dy) {
      const int y = c.y() + dy;
      if (y < 0 || y >= h_) continue;
      float* row = &fine_[static_cast<size_t>(y) * w_];
      const double g = gy[static_cast<size_t>(dy + rc)];
      for (int dx = -rc; dx <= rc; ++dx) {
        const int x = c.x() + dx;
        if (x < 0 || x >= w_) continue;
        row[x] = std::max(row[x], static_cast<float>(g * gx[static_cast<size_t>(dx + rc)]));
      }
    }
  }
  // Max-pooling, separably: first along x, then along y, each a sliding maximum of width k over
  // a zero-padded copy (pooled(ix, iy) for ix in [-k, w), iy in [-k, h)).
  const int pw = w_ + k_, ph = h_ + k_;
  // Rows of the x-pooled field, with k zero rows above and k - 1 below for the y pass. Working
  // memory as large as the field, kept by the thread between fields: allocated per field it
  // would be a fresh mapping (page-faulted in) every time (omni/common/malloc_setup.h).
  static thread_local std::vector<float> rows, line;
  rows.assign(static_cast<size_t>(h_ + 2 * k_ - 1) * pw, 0.f);
  line.assign(static_cast<size_t>(w_ + 2 * k_ - 1), 0.f);
  for (int y = 0; y < h_; ++y) {
    std::fill(line.begin(), line.end(), 0.f);  // SlidingMax overwrites its input
    std::copy(fine_.begin() + static_cast<std::ptrdiff_t>(y) * w_,
              fine_.begin() + static_cast<std::ptrdiff_t>(y + 1) * w_, line.begin() + k_);
    SlidingMax(line.data(), pw, k_, 1, &rows[static_cast<size_t>(y + k_) * pw]);
  }
  pooled_.assign(static_cast<size_t>(pw) * ph, 0.f);
  SlidingMax(rows.data(), ph, k_, pw, pooled_.data());
  // A field over a large submap (up to kMaxFieldCells) does not keep its working memory.
  constexpr size_t kKeepFloats = size_t{4} << 20;  // 16 MB
  if (rows.capacity() > kKeepFloats) std::vector<float>().swap(rows);
  zero_border_ = BorderIsZero(fine_, w_, h_) && BorderIsZero(pooled_, pw, ph);
}

Eigen::Vector2i LikelihoodField::Cell(const Eigen::Vector2d& p) const {
  return {static_cast<int>(std::floor((p.x() - origin_.x()) / res_)),
          static_cast<int>(std::floor((p.y() - origin_.y()) / res_))};
}

float LikelihoodField::Fine(int ix, int iy) const {
  if (ix < 0 || iy < 0 || ix >= w_ || iy >= h_) return 0.f;
  return fine_[static_cast<size_t>(iy) * w_ + ix];
}

float LikelihoodField::Pooled(int ix, int iy) const {
  const int px = ix + k_, py = iy + k_;
  const int pw = w_ + k_, ph = h_ + k_;
  if (px < 0 || py < 0 || px >= pw || py >= ph) return 0.f;
  return pooled_[static_cast<size_t>(py) * pw + px];
}

double LikelihoodField::Interpolated(const Eigen::Vector2d& p) const {
  if (w_ == 0) return 0;
  const double fx = (p.x() - origin_.x()) / res_ - 0.5, fy = (p.y() - origin_.y()) / res_ - 0.5;
  const int x0 = static_cast<int>(std::floor(fx)), y0 = static_cast<int>(std::floor(fy));
  const double ax = fx - x0, ay = fy - y0;
  if (x0 >= 0 && y0 >= 0 && x0 + 1 < w_ && y0 + 1 < h_) {
    const float* f = &fine_[static_cast<size_t>(y0) * w_ + x0];
    return (1 - ay) * ((1 - ax) * f[0] + ax * f[1]) + ay * ((1 - ax) * f[w_] + ax * f[w_ + 1]);
  }
  return (1 - ay) * ((1 - ax) * Fine(x0, y0) + ax * Fine(x0 + 1, y0)) +
         ay * ((1 - ax) * Fine(x0, y0 + 1) + ax * Fine(x0 + 1, y0 + 1));
}

namespace {
// Catmull-Rom weights of the four samples around a point at fraction t past the second.
inline void CubicWeights(double t, double w[4]) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = 0.5 * (-t3 + 2 * t2 - t);
  w[1] = 0.5 * (3 * t3 - 5 * t2 + 2);
  w[2] = 0.5 * (-3 * t3 + 4 * t2 + t);
  w[3] = 0.5 * (t3 - t2);
}
}  // namespace

double LikelihoodField::InterpolatedCubic(const Eigen::Vector2d& p) const {
  if (w_ == 0) return 0;
  const double fx = (p.x() - origin_.x()) / res_ - 0.5, fy = (p.y() - origin_.y()) / res_ - 0.5;
  const int x0 = static_cast<int>(std::floor(fx)), y0 = static_cast<int>(std::floor(fy));
  double wx[4], wy[4];
  CubicWeights(fx - x0, wx);
  CubicWeights(fy - y0, wy);
  double s = 0;
  if (x0 >= 1 && y0 >= 1 && x0 + 2 < w_ && y0 + 2 < h_) {
    const float* f = &fine_[static_cast<size_t>(y0 - 1) * w_ + (x0 - 1)];
    for (int j = 0; j < 4; ++j, f += w_)
      s += wy[j] * (wx[0] * f[0] + wx[1] * f[1] + wx[2] * f[2] + wx[3] * f[3]);
    return s;
  }
  for (int j = 0; j < 4; ++j)
    for (int i = 0; i < 4; ++i) s += wy[j] * wx[i] * Fine(x0 - 1 + i, y0 - 1 + j);
  return s;
}

namespace {
// The mean of one of the field's interpolants over the query placed at `pose`.
template <double (LikelihoodField::*Interp)(const Eigen::Vector2d&) const>
double MeanAt(const LikelihoodField& field, const std::vector<Eigen::Vector2d>& query,
              const Pose2& pose) {
  if (query.empty()) return 0;
  const double c = std::cos(pose.theta), sn = std::sin(pose.theta);
  double s = 0;
  for (const auto& p : query)
    s += (field.*Interp)({pose.x + c * p.x() - sn * p.y(), pose.y + sn * p.x() + c * p.y()});
  return s / static_cast<double>(query.size());
}
}  // namespace

double ScoreAt(const LikelihoodField& field, const std::vector<Eigen::Vector2d>& query,
               const Pose2& pose) {
  return MeanAt<&LikelihoodField::Interpolated>(field, query, pose);
}

Pose2 RefinePointToLine(const std::vector<Eigen::Vector2d>& reference,
                        const std::vector<Eigen::Vector2d>& query, const Pose2& start,
                        double pair_distance_m, int iterations) {
  Pose2 pose = start;
  if (reference.size() < 2) return pose;
  const double max_d2 = pair_distance_m * pair_distance_m;
  for (int it = 0; it < iterations; ++it) {
    Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
    Eigen::Vector3d g = Eigen::Vector3d::Zero();
    int pairs = 0;
    const double c = std::cos(pose.theta), s = std::sin(pose.theta);
    for (const auto& p : query) {
      const Eigen::Vector2d q = pose.Transform(p);
      // The two nearest reference points span the local surface line.
      double d1 = max_d2, d2 = max_d2;
      int i1 = -1, i2 = -1;
      for (size_t i = 0; i < reference.size(); ++i) {
        const double d = (reference[i] - q).squaredNorm();
        if (d < d1) {
          d2 = d1;
          i2 = i1;
          d1 = d;
          i1 = static_cast<int>(i);
        } else if (d < d2) {
          d2 = d;
          i2 = static_cast<int>(i);
        }
      }
      if (i1 < 0 || i2 < 0) continue;
      const Eigen::Vector2d t = reference[i2] - reference[i1];
      if (t.squaredNorm() < 1e-8) continue;
      const Eigen::Vector2d n = Eigen::Vector2d(-t.y(), t.x()).normalized();
      const double r = n.dot(q - reference[i1]);
      const Eigen::Vector2d dq(-s * p.x() - c * p.y(), c * p.x() - s * p.y());  // d q / d theta
      const Eigen::Vector3d j(n.x(), n.y(), n.dot(dq));
      h += j * j.transpose();
      g += j * r;
      ++pairs;
    }
    if (pairs < 10) return start;
    const Eigen::Vector3d step = -(h + 1e-9 * Eigen::Matrix3d::Identity()).ldlt().solve(g);
    pose = Pose2(pose.x + step.x(), pose.y + step.y(), WrapAngle(pose.theta + step.z()));
    if (step.head<2>().norm() < 1e-5 && std::abs(step.z()) < 1e-6) break;
  }
  return pose;
}

namespace {

// Offsets from the search's guess the polish may reach: the window plus one grid step.
struct PolishBox {
  Pose2 guess;
  double x_m, y_m, theta_rad;
  bool Contains(double dx, double dy, double dth) const {
    return std::abs(dx) <= x_m && std::abs(dy) <= y_m && std::abs(dth) <= theta_rad;
  }
};

// Coordinate hill climb on the interpolated score, steps halved 6 times; returns the score.
// Moves that would leave `box` are not taken: without the bound the climb could follow a slope
// far outside the searched window (seen on a sparse log: 0.35 rad off a 0.17 rad window, onto a
// wrong optimum) and return an answer the search never vetted.

double HillClimb(const LikelihoodField& field, const std::vector<Eigen::Vector2d>& query,
                 double sxy, double sth, const PolishBox& box, bool cubic, Pose2* pose) {
  auto score_at = [&](const Pose2& p) {
    // SearchWindow::cubic_polish: the Catmull-Rom interpolant instead of the bilinear one.
    return cubic ? MeanAt<&LikelihoodField::InterpolatedCubic>(field, query, p)
                 : ScoreAt(field, query, p);
  };
  double score = score_at(*pose);
  // Offsets from the guess are tracked unwrapped so the angle bound holds across +-pi.
  double ox = pose->x - box.guess.x, oy = pose->y - box.guess.y;
  double oth = WrapAngle(pose->theta - box.guess.theta);
  for (int level = 0; level < 6; ++level) {
    bool improved = true;
    while (improved) {
      improved = false;
      const Pose2 moves[6] = {{sxy, 0, 0},  {-sxy, 0, 0}, {0, sxy, 0},
                              {0, -sxy, 0}, {0, 0, sth},  {0, 0, -sth}};
      for (const auto& m : moves) {
        if (!box.Contains(ox + m.x, oy + m.y, oth + m.theta)) continue;
        const Pose2 cand(pose->x + m.x, pose->y + m.y, WrapAngle(pose->theta + m.theta));
        const double s = score_at(cand);
        if (s > score) {
          score = s;
          *pose = cand;
          ox += m.x;
          oy += m.y;
          oth += m.theta;
          improved = true;
        }
      }
    }
    sxy /= 2;
    sth /= 2;
  }
  return score;
}

// Sum of base[i] over the offsets, in four partial sums: one running sum would make every
// addition wait for the previous one.
double SumAt(const float* base, const std::vector<int>& offsets) {
  double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
  const size_t n = offsets.size(), n4 = n & ~size_t{3};
  const int* o = offsets.data();
  for (size_t i = 0; i < n4; i += 4) {
    s0 += base[o[i]];
    s1 += base[o[i + 1]];
    s2 += base[o[i + 2]];
    s3 += base[o[i + 3]];
  }
  for (size_t i = n4; i < n; ++i) s0 += base[o[i]];
  return (s0 + s1) + (s2 + s3);
}

struct Block {
  float bound;
  int a, bx, by;  // rotation index, first translation cell of the block
};

}  // namespace

MatchResult MatchScan(const LikelihoodField& field, const std::vector<Eigen::Vector2d>& query,
                      const Pose2& guess, const SearchWindow& win) {
  MatchResult out;
  out.pose = guess;
  if (query.empty() || field.empty()) return out;
  const double res = field.resolution();
  const int k = field.coarse_cells();
  const int nx = static_cast<int>(std::ceil(win.x_m / res));
  const int ny = static_cast<int>(std::ceil(win.y_m / res));
  const double astep = win.angle_step_rad;
  const int na = static_cast<int>(std::ceil(win.theta_rad / astep));
  const double inv_n = 1.0 / static_cast<double>(query.size());

  // Fine scores are also taken up to r cells beyond the window (covariance, polish starts).
  const int r = 4;
  // Cells of the rotated query at the guess' translation, one set per rotation, split for the
  // inner loops: points that stay inside the grid for every translation the search can ask for
  // are kept as flat array offsets (no bounds checks), the others as cells (checked lookups).
  struct Rotation {
    std::vector<int> fine_in, pooled_in;
    std::vector<Eigen::Vector2i> fine_out, pooled_out;
  };
  const int fw = field.width(), fh = field.height();
  const int pw = field.pooled_width(), ph = field.pooled_height();
  const float* fine = field.fine_data();
  const float* pooled = field.pooled_data();
  std::vector<Rotation> rots(static_cast<size_t>(2 * na + 1));
  for (int a = -na; a <= na; ++a) {
    const Pose2 rot(guess.x, guess.y, guess.theta + a * astep);
    Rotation& rc = rots[static_cast<size_t>(a + na)];
    rc.fine_in.reserve(query.size());
    rc.pooled_in.reserve(query.size());
    for (const auto& p : query) {
      const Eigen::Vector2i c = field.Cell(rot.Transform(p));
      // A point outside the grid for every translation always scores 0 and is dropped.
      const int fx = c.x(), fy = c.y();
      if (fx - nx - r >= 0 && fx + nx + r < fw && fy - ny - r >= 0 && fy + ny + r < fh)
        rc.fine_in.push_back(fy * fw + fx);
      else if (fx + nx + r >= 0 && fx - nx - r < fw && fy + ny + r >= 0 && fy - ny - r < fh)
        rc.fine_out.push_back(c);
      const int px = fx + k, py = fy + k;  // pooled storage coordinates
      if (px - nx >= 0 && px + nx < pw && py - ny >= 0 && py + ny < ph)
        rc.pooled_in.push_back(py * pw + px);
      else if (px + nx >= 0 && px - nx < pw && py + ny >= 0 && py - ny < ph)
        rc.pooled_out.push_back({px, py});
    }
  }
  // Points that may leave the grid: a lookup clamped to the grid reads its zero border when
  // there is one (branch-free), otherwise the lookup is checked.
  const bool clamp = field.zero_border();
  auto sum_out = [clamp](const float* grid, int w, int h, const std::vector<Eigen::Vector2i>& pts,
                         int bx, int by) {
    double s = 0;
    if (clamp) {
      double s1 = 0;
      const size_t n = pts.size();
      size_t i = 0;
      for (; i + 1 < n; i += 2) {
        const int x0 = std::clamp(pts[i].x() + bx, 0, w - 1);
        const int y0 = std::clamp(pts[i].y() + by, 0, h - 1);
        const int x1 = std::clamp(pts[i + 1].x() + bx, 0, w - 1);
        const int y1 = std::clamp(pts[i + 1].y() + by, 0, h - 1);
        s += grid[static_cast<size_t>(y0) * w + x0];
        s1 += grid[static_cast<size_t>(y1) * w + x1];
      }
      if (i < n)
        s += grid[static_cast<size_t>(std::clamp(pts[i].y() + by, 0, h - 1)) * w +
                  std::clamp(pts[i].x() + bx, 0, w - 1)];
      return s + s1;
    }
    for (const auto& c : pts) {
      const int x = c.x() + bx, y = c.y() + by;
      if (x >= 0 && x < w && y >= 0 && y < h) s += grid[static_cast<size_t>(y) * w + x];
    }
    return s;
  };
  auto fine_score = [&](int a, int bx, int by) {
    const Rotation& rc = rots[static_cast<size_t>(a + na)];
    const float* base = fine + (static_cast<std::ptrdiff_t>(by) * fw + bx);
    const double s = SumAt(base, rc.fine_in) + sum_out(fine, fw, fh, rc.fine_out, bx, by);
    ++out.evaluated;
    return s * inv_n;
  };
  auto bound = [&](int a, int bx, int by) {
    const Rotation& rc = rots[static_cast<size_t>(a + na)];
    const float* base = pooled + (static_cast<std::ptrdiff_t>(by) * pw + bx);
    const double s = SumAt(base, rc.pooled_in) + sum_out(pooled, pw, ph, rc.pooled_out, bx, by);
    return s * inv_n;
  };

  std::vector<Block> blocks;
  blocks.reserve(static_cast<size_t>(2 * na + 1) * static_cast<size_t>((2 * nx) / k + 1) *
                 static_cast<size_t>((2 * ny) / k + 1));
  for (int a = -na; a <= na; ++a)
    for (int bx = -nx; bx <= nx; bx += k)
      for (int by = -ny; by <= ny; by += k)
        blocks.push_back({static_cast<float>(bound(a, bx, by)), a, bx, by});
  out.bounded = static_cast<long>(blocks.size());
  // Best bound first. Blocks bounded below min_score are never refined by the first pass, so
  // only the others are sorted now; the rest is sorted if the second-best pass reaches it.
  auto by_bound = [](const Block& l, const Block& r) { return l.bound > r.bound; };
  const auto low = std::partition(blocks.begin(), blocks.end(), [&](const Block& b) {
    return static_cast<double>(b.bound) >= win.min_score;
  });
  std::sort(blocks.begin(), low, by_bound);
  bool low_sorted = low == blocks.end();

  // Best fine candidate: refine blocks while their bound can still beat it.
  double best = -1;
  int ba = 0, bbx = 0, bby = 0;
  for (const auto& b : blocks) {
    if (b.bound <= best || b.bound < win.min_score) break;
    for (int x = b.bx; x < std::min(b.bx + k, nx + 1); ++x)
      for (int y = b.by; y < std::min(b.by + k, ny + 1); ++y) {
        const double s = fine_score(b.a, x, y);
        if (s > best) {
          best = s;
          ba = b.a;
          bbx = x;
          bby = y;
        }
      }
  }
  if (best < win.min_score || best < 0) {
    out.below_min_score = true;
    return out;
  }
  out.on_window_edge = std::abs(ba) == na || std::abs(bbx) == nx || std::abs(bby) == ny;
  // Best candidate "elsewhere": same search restricted to candidates far from the best.
  auto far = [&](int a, int x, int y) {
    return std::hypot((x - bbx) * res, (y - bby) * res) > win.ambiguity_xy_m ||
           std::abs(a - ba) * astep > win.ambiguity_theta_rad;
  };
  double second = 0;
  for (auto it = blocks.begin(); it != blocks.end(); ++it) {
    if (it == low && !low_sorted) {
      std::sort(low, blocks.end(), by_bound);
      low_sorted = true;
    }
    const Block& b = *it;
    if (b.bound <= second) break;
    for (int x = b.bx; x < std::min(b.bx + k, nx + 1); ++x)
      for (int y = b.by; y < std::min(b.by + k, ny + 1); ++y)
        if (far(b.a, x, y)) second = std::max(second, fine_score(b.a, x, y));
  }
  out.second_score = second;

  // Covariance from the good candidates around the optimum.
  double wsum = 0;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  Eigen::Matrix3d m2 = Eigen::Matrix3d::Zero();
  const double n = static_cast<double>(query.size());
  // Per rotation, the best translation in the window: nearby optima the polish starts from.
  struct Start {
    double s;
    int a, x, y;
  };
  std::vector<Start> starts;
  for (int a = std::max(-na, ba - r); a <= std::min(na, ba + r); ++a) {
    Start top{-1, a, 0, 0};
    for (int x = bbx - r; x <= bbx + r; ++x)
      for (int y = bby - r; y <= bby + r; ++y) {
        const double s = fine_score(a, x, y);
        // Polish starts inside the window only (the climb is bounded to it as well).
        if (std::abs(x) <= nx && std::abs(y) <= ny && s > top.s) top = {s, a, x, y};
        const double w = std::exp(win.covariance_kappa * n * (s - best));
        const Eigen::Vector3d d((x - bbx) * res, (y - bby) * res, (a - ba) * astep);
        wsum += w;
        mean += w * d;
        m2 += w * d * d.transpose();
      }
    if (top.s >= best - win.polish_score_gap) starts.push_back(top);
  }
  mean /= wsum;
  out.covariance = m2 / wsum - mean * mean.transpose();
  out.covariance.diagonal() += Eigen::Vector3d(res * res / 12, res * res / 12, astep * astep / 12);

  // Continuous polish (hill climb on the interpolated field) from the discrete optimum and from
  // the best translation of each nearby rotation that scores almost as well: the grid can put
  // its optimum next to the wrong one of two close optima.
  Pose2 pose = guess;
  double score = -1;
  const PolishBox box{guess, nx * res + res, ny * res + res, na * astep + astep};
  for (const Start& st : starts) {
    Pose2 p(guess.x + st.x * res, guess.y + st.y * res, WrapAngle(guess.theta + st.a * astep));
    const double s = HillClimb(field, query, res / 2, astep / 2, box, win.cubic_polish, &p);
    if (s > score) {
      score = s;
      pose = p;
    }
  }
  // The score the thresholds are set for: bilinear, as in the search.
  if (win.cubic_polish) score = ScoreAt(field, query, pose);
  if (win.icp_polish) {
    const Pose2 icp = RefinePointToLine(field.points(), query, pose, win.icp_pair_m);
    const Pose2 moved = pose.Between(icp);
    if (std::hypot(moved.x, moved.y) <= win.icp_max_shift_m &&
        std::abs(moved.theta) <= win.icp_max_turn_rad) {
      pose = icp;
      score = ScoreAt(field, query, pose);
    }
  }
  out.pose = pose;
  out.score = score;
  int inliers = 0;
  for (const auto& p : query)
    if (field.Interpolated(pose.Transform(p)) >= win.inlier_likelihood) ++inliers;
  out.inlier_fraction = inliers * inv_n;
  return out;
}

}  // namespace omni::pgm
