#include "omni/octomap_builder/repose.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace omni::octo {

void ThinPoints(const std::vector<Eigen::Vector3f>& points, const std::vector<uint32_t>* colors,
                double leaf_m, std::vector<Eigen::Vector3f>* points_out,
                std::vector<uint32_t>* colors_out) {
  points_out->clear();
  if (colors_out) colors_out->clear();
  const bool with_colors = colors && colors_out && colors->size() == points.size();
  struct Cell {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    int n = 0;
    uint32_t color = 0;
  };
  std::unordered_map<uint64_t, size_t> index;  // cube key -> position in `cells`
  std::vector<Cell> cells;
  const double inv = 1.0 / leaf_m;
  constexpr int64_t kHalf = int64_t{1} << 20;  // 21 bits per axis
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points[i];
    if (!p.allFinite()) continue;
    const double fx = std::floor(p.x() * inv), fy = std::floor(p.y() * inv),
                 fz = std::floor(p.z() * inv);
    if (std::abs(fx) >= kHalf || std::abs(fy) >= kHalf || std::abs(fz) >= kHalf) continue;
    const auto k = [](double f) {
      return static_cast<uint64_t>(static_cast<int64_t>(f) + kHalf) & 0x1fffff;
    };
    const uint64_t key = k(fx) | (k(fy) << 21) | (k(fz) << 42);
    auto [it, added] = index.emplace(key, cells.size());
    if (added) cells.emplace_back();
    Cell& c = cells[it->second];
    c.sum += p.cast<double>();
    ++c.n;
    if (with_colors && c.color == 0) c.color = (*colors)[i];
  }
  points_out->reserve(cells.size());
  if (with_colors) colors_out->reserve(cells.size());
  for (const Cell& c : cells) {
    points_out->push_back((c.sum / c.n).cast<float>());
    if (with_colors) colors_out->push_back(c.color);
  }
}

int64_t KeepPoints(const std::vector<Eigen::Vector3f>& points, const std::vector<uint32_t>* colors,
                   double ray_cut_m, std::vector<KeptPoint>* out,
                   std::vector<uint32_t>* colors_out) {
  out->clear();
  out->reserve(points.size());
  const bool with_colors = colors && colors_out && colors->size() == points.size();
  if (colors_out) {
    colors_out->clear();
    if (with_colors) colors_out->reserve(points.size());
  }
  // A shortened point is at least kKeptPointMaxM from the camera (less a rounding), so it stays
  // beyond a cut of at most kKeptPointCutM and inserts the same ray: free cells, no hit.
  const bool shorten = ray_cut_m > 0 && ray_cut_m <= kKeptPointCutM;
  const auto mm = [](float v) {
    const long r = std::lround(static_cast<double>(v) * 1000.0);
    return static_cast<int16_t>(std::clamp<long>(r, -32767, 32767));
  };
  int64_t dropped = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    Eigen::Vector3f p = points[i];
    if (!p.allFinite()) {  // before the max: Eigen's maxCoeff may pass over a NaN
      ++dropped;
      continue;
    }
    const float far = p.cwiseAbs().maxCoeff();
    if (far > static_cast<float>(kKeptPointMaxM)) {
      if (!shorten) {
        ++dropped;
        continue;
      }
      p *= static_cast<float>(kKeptPointMaxM) / far;  // beyond the cut either way: same ray
    }
    out->push_back(KeptPoint{mm(p.x()), mm(p.y()), mm(p.z())});
    if (with_colors) colors_out->push_back((*colors)[i]);
  }
  return dropped;
}

std::vector<Eigen::Vector3f> Keyframe::Points() const {
  std::vector<Eigen::Vector3f> metres;
  metres.reserve(points.size());
  for (const KeptPoint& p : points)
    metres.emplace_back(static_cast<float>(p.x_mm) * 1e-3f, static_cast<float>(p.y_mm) * 1e-3f,
                        static_cast<float>(p.z_mm) * 1e-3f);
  return metres;
}

double KeyframeRadius(const std::vector<Eigen::Vector3f>& points_camera, const CameraMount& mount,
                      double max_range_m) {
  const Eigen::Isometry3f base_from_camera = MountToIsometry(mount).cast<float>();
  double r = 0;
  for (const auto& p : points_camera) {
    const Eigen::Vector3f b = base_from_camera * p;
    r = std::max(r, std::hypot(static_cast<double>(b.x()), static_cast<double>(b.y())));
  }
  if (max_range_m > 0) r = std::min(r, std::hypot(mount.x_m, mount.y_m) + max_range_m);
  return r;
}

double PoseShift(const Pose2& a, const Pose2& b, double radius_m) {
  const double dtheta = std::abs(WrapAngle(b.theta - a.theta));
  return std::hypot(b.x - a.x, b.y - a.y) + 2 * std::sin(dtheta / 2) * radius_m;
}

bool TrajectoryLookup::At(int64_t utime, int64_t max_gap_us, Pose2* out) const {
  if (poses_.empty() || utime < poses_.front().first || utime > poses_.back().first) return false;
  const auto it =
      std::lower_bound(poses_.begin(), poses_.end(), utime,
                       [](const std::pair<int64_t, Pose2>& p, int64_t t) { return p.first < t; });
  if (it->first == utime) {
    *out = it->second;
    return true;
  }
  const auto& b = *it;
  const auto& a = *(it - 1);  // utime > front: there is one before
  if (b.first - a.first > max_gap_us) return false;
  const double f = static_cast<double>(utime - a.first) / static_cast<double>(b.first - a.first);
  *out = Interpolate(a.second, b.second, f);
  return true;
}

}  // namespace omni::octo
