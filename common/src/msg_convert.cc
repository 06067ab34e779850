#include "omni/bus/convert.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <zlib.h>

#include "omni/bus/bus.h"
#include "omni/common/geometry.h"
#include "omni/common/log.h"
#include "omni/common/time.h"

namespace omni::bus {

omni::laser_scan_t ToLaserScan(const io::CarmenLaser& l, int64_t seq) {
  omni::laser_scan_t s;
  s.utime = SecondsToUtime(l.timestamp_s);
  s.seq = seq;
  s.frame = "laser";
  const Pose2 mount = l.robot_pose.Between(l.laser_pose);
  s.sensor_x_m = mount.x;
  s.sensor_y_m = mount.y;
  s.sensor_yaw_rad = mount.theta;
  s.angle_min_rad = l.angle_min_rad;
  s.angle_increment_rad = l.angle_increment_rad;
  s.scan_time_s = 0.f;
  s.range_min_m = 0.f;
  s.range_max_m = l.max_range_m;
  s.num_ranges = static_cast<int32_t>(l.ranges_m.size());
  s.ranges_m.resize(l.ranges_m.size());
  for (size_t i = 0; i < l.ranges_m.size(); ++i) {
    const float r = l.ranges_m[i];
    s.ranges_m[i] = (std::isfinite(r) && r > 0.f && r < l.max_range_m)
                        ? r
                        : std::numeric_limits<float>::quiet_NaN();
  }
  s.num_intensities = 0;
  return s;
}

omni::odometry_t ToOdometry(const io::CarmenOdom& o, int64_t seq) {
  omni::odometry_t m{};
  m.utime = SecondsToUtime(o.timestamp_s);
  m.seq = seq;
  m.frame = "odom";
  m.child_frame = "base";
  m.x_m = o.pose.x;
  m.y_m = o.pose.y;
  m.yaw_rad = WrapAngle(o.pose.theta);
  m.vx_m_s = o.tv_m_s;
  m.vy_m_s = 0;
  m.omega_rad_s = o.rv_rad_s;
  for (int i = 0; i < 9; ++i) {
    m.pose_covariance[i] = 0;
    m.twist_covariance[i] = 0;
  }
  m.pose_covariance[0] = -1;  // CARMEN logs carry no covariance
  m.twist_covariance[0] = -1;
  return m;
}

Result<omni::occupancy_grid_t> ToGridMessage(const io::GridMap& map, int64_t utime,
                                             const std::string& source, bool raw) {
  const int64_t claimed = static_cast<int64_t>(map.width) * map.height;
  if (claimed > io::kMaxGridCells)
    return MakeError(ErrorCode::kOutOfRange,
                     "grid from '" + source + "': " + std::to_string(map.width) + " x " +
                         std::to_string(map.height) + " cells is more than a grid message " +
                         "carries (io::kMaxGridCells, 2^28); not sent");
  if (map.width < 0 || map.height < 0 || claimed != static_cast<int64_t>(map.cells.size()))
    return MakeError(ErrorCode::kInvalidArgument, "grid from '" + source +
                                                      "': " + std::to_string(map.cells.size()) +
                                                      " cells for " + std::to_string(map.width) +
                                                      " x " + std::to_string(map.height));
  omni::occupancy_grid_t g;
  g.utime = utime;
  g.frame = "map";
  g.source = source;
  g.resolution_m = static_cast<float>(map.resolution_m);
  g.origin_x_m = map.origin_x_m;
  g.origin_y_m = map.origin_y_m;
  g.origin_yaw_rad = 0;
  g.width = map.width;
  g.height = map.height;
  g.num_cells = static_cast<int32_t>(map.cells.size());
  const auto* cells = reinterpret_cast<const uint8_t*>(map.cells.data());
  g.encoding = omni::occupancy_grid_t::ENCODING_RAW;
  g.data.assign(cells, cells + map.cells.size());
  if (!raw && !map.cells.empty()) {
    uLongf zlen = compressBound(static_cast<uLong>(map.cells.size()));
    std::vector<uint8_t> z(zlen);
    // Level 1: a 1600 x 1400 grid in about 7 ms, 20x smaller; higher levels gain 1.5x at 3x
    // the time. Should zlib fail, the cells go out raw.
    if (compress2(z.data(), &zlen, cells, static_cast<uLong>(map.cells.size()), 1) == Z_OK) {
      z.resize(zlen);
      g.encoding = omni::occupancy_grid_t::ENCODING_ZLIB;
      g.data = std::move(z);
    }
  }
  g.num_bytes = static_cast<int32_t>(g.data.size());
  return g;
}

bool PublishGrid(Bus& bus, const std::string& channel, const io::GridMap& map, int64_t utime,
                 const std::string& source, const std::string& frame) {
  auto msg = ToGridMessage(map, utime, source);
  if (!msg.ok()) {
    static std::atomic<int64_t> refused{0};
    const int64_t n = ++refused;
    if (n % 100 == 1) {
      LOG_WARN << msg.error().message << " (" << n << " grids refused so far)";
    }
    ++bus.counters().publish_errors;
    return false;
  }
  msg->frame = frame;
  return bus.Publish(channel, *msg);
}

Result<io::GridMap> FromGridMessage(const omni::occupancy_grid_t& g) {
  if (!(g.resolution_m > 0) || !std::isfinite(g.resolution_m) || g.width < 0 || g.height < 0 ||
      static_cast<int64_t>(g.width) * g.height != g.num_cells ||
      g.num_bytes != static_cast<int32_t>(g.data.size()))
    return MakeError(ErrorCode::kInvalidArgument,
                     "occupancy grid from '" + g.source + "': inconsistent size or resolution");
  if (g.num_cells > io::kMaxGridCells)
    return MakeError(ErrorCode::kInvalidArgument, "occupancy grid from '" + g.source +
                                                      "': " + std::to_string(g.num_cells) +
                                                      " cells is more than any map here (2^28)");
  // A map origin beyond 1000 km is no robot's map: refused like a non-finite one.
  if (!std::isfinite(g.origin_x_m) || !std::isfinite(g.origin_y_m) ||
      !std::isfinite(g.origin_yaw_rad) || std::abs(g.origin_x_m) > 1e6 ||
      std::abs(g.origin_y_m) > 1e6)
    return MakeError(ErrorCode::kInvalidArgument,
                     "occupancy grid from '" + g.source + "': non-finite or absurd origin");
  io::GridMap m;
  m.resolution_m = g.resolution_m;
  m.origin_x_m = g.origin_x_m;
  m.origin_y_m = g.origin_y_m;
  m.width = g.width;
  m.height = g.height;
  const size_t n = static_cast<size_t>(g.num_cells);
  if (g.encoding == omni::occupancy_grid_t::ENCODING_RAW) {
    if (g.data.size() != n)
      return MakeError(ErrorCode::kInvalidArgument,
                       "occupancy grid from '" + g.source + "': " + std::to_string(g.data.size()) +
                           " raw bytes for " + std::to_string(n) + " cells");
    m.cells.assign(g.data.begin(), g.data.end());
  } else if (g.encoding == omni::occupancy_grid_t::ENCODING_ZLIB) {
    // Deflate expands at most 1032:1 (zlib FAQ), so a few bytes claiming a huge grid are
    // refused before an n-byte buffer is allocated for them.
    if (n / 1032 > g.data.size())
      return MakeError(ErrorCode::kInvalidArgument,
                       "occupancy grid from '" + g.source + "': " + std::to_string(g.data.size()) +
                           " zlib bytes cannot inflate to " + std::to_string(n) +
                           " cells (deflate's limit is 1032:1)");
    m.cells.resize(n);
    uLongf len = static_cast<uLongf>(n);
    const int rc = uncompress(reinterpret_cast<Bytef*>(m.cells.data()), &len, g.data.data(),
                              static_cast<uLong>(g.data.size()));
    // Z_BUF_ERROR: more than num_cells bytes, or a stream cut short; Z_DATA_ERROR: corrupt.
    if (rc != Z_OK || len != n)
      return MakeError(
          ErrorCode::kInvalidArgument,
          "occupancy grid from '" + g.source + "': the zlib data " +
              (rc == Z_OK
                   ? "inflates to " + std::to_string(len) + " bytes, not " + std::to_string(n)
                   : std::string("does not inflate (zlib error ") + std::to_string(rc) + ")"));
  } else {
    return MakeError(ErrorCode::kInvalidArgument, "occupancy grid from '" + g.source +
                                                      "': unknown encoding " +
                                                      std::to_string(int{g.encoding}));
  }
  // A grid turned in its frame (origin_yaw_rad) is resampled onto the frame's axes.
  auto aligned = io::AxisAligned(m, g.origin_yaw_rad, io::kMaxGridCells);
  if (!aligned.ok())
    return MakeError(ErrorCode::kInvalidArgument,
                     "occupancy grid from '" + g.source + "': " + aligned.error().message);
  return aligned;
}

namespace {

// One greedy pass: from each kept pose, reach as far ahead as the poses in between are
// reproduced by interpolation within the tolerances and the stamps keep rising within the gap.
// With a `limit`, gives up (false) as soon as more than `limit` poses are kept.
bool ThinPass(const omni::trajectory_t& m, double tol_m, double tol_rad, int64_t max_gap_us,
              size_t limit, std::vector<size_t>* keep) {
  const std::vector<int64_t>& t = m.pose_utime;
  const size_t n = t.size();
  auto pose = [&m](size_t i) { return Pose2(m.x_m[i], m.y_m[i], m.yaw_rad[i]); };
  // Only called with t[b] > t[a], so the unsigned difference is exact.
  auto since = [&t](size_t a, size_t b) {
    return static_cast<uint64_t>(t[b]) - static_cast<uint64_t>(t[a]);
  };
  auto reproduced = [&](size_t a, size_t b) {
    const Pose2 pa = pose(a), pb = pose(b);
    const auto span = static_cast<double>(since(a, b));
    for (size_t i = a + 1; i < b; ++i) {
      const Pose2 q = Interpolate(pa, pb, static_cast<double>(since(a, i)) / span);
      if (!(std::hypot(q.x - m.x_m[i], q.y - m.y_m[i]) <= tol_m) ||
          !(std::abs(WrapAngle(q.theta - m.yaw_rad[i])) <= tol_rad))
        return false;  // also for a NaN
    }
    return true;
  };
  keep->clear();
  if (n == 0) return true;
  keep->push_back(0);
  size_t a = 0;
  while (a + 1 < n) {
    size_t j = a + 1;
    while (j + 1 < n && t[j] > t[a] && t[j + 1] > t[j] &&
           (max_gap_us <= 0 || since(a, j + 1) <= static_cast<uint64_t>(max_gap_us)) &&
           reproduced(a, j + 1))
      ++j;
    keep->push_back(j);
    if (limit > 0 && keep->size() > limit) return false;
    a = j;
  }
  return true;
}

}  // namespace

int ThinTrajectoryMessage(omni::trajectory_t* m, const TrajectoryThinning& thinning,
                          size_t max_poses) {
  const size_t n = m->pose_utime.size();
  if (m->x_m.size() != n || m->y_m.size() != n || m->yaw_rad.size() != n) return 0;
  std::vector<size_t> keep;
  int doublings = 0;
  double tol_m = thinning.tolerance_m, tol_rad = thinning.tolerance_rad;
  if (tol_m > 0 && tol_rad > 0 && n > 2) {
    // The gap alone keeps at least span / max_gap poses: if that is over the cap, no tolerance
    // makes the path fit, and one whole pass feeds the every-k-th fallback.
    const std::vector<int64_t>& t = m->pose_utime;
    const double span_us = static_cast<double>(t.back()) - static_cast<double>(t.front());
    const bool may_fit =
        max_poses == 0 || thinning.max_gap_us <= 0 ||
        span_us / static_cast<double>(thinning.max_gap_us) < static_cast<double>(max_poses);
    const size_t limit = may_fit ? max_poses : 0;
    constexpr double kMaxTolerance = 0.64;  // m and rad: beyond it a path is not worth sending
    constexpr int kMaxDoublings = 8;
    bool fitted = ThinPass(*m, tol_m, tol_rad, thinning.max_gap_us, limit, &keep);
    while (!fitted && doublings < kMaxDoublings &&
           (tol_m < kMaxTolerance || tol_rad < kMaxTolerance)) {
      tol_m = std::min(2 * tol_m, std::max(tol_m, kMaxTolerance));
      tol_rad = std::min(2 * tol_rad, std::max(tol_rad, kMaxTolerance));
      ++doublings;
      fitted = ThinPass(*m, tol_m, tol_rad, thinning.max_gap_us, limit, &keep);
    }
    if (!fitted) ThinPass(*m, tol_m, tol_rad, thinning.max_gap_us, 0, &keep);  // all of it
  } else {
    keep.resize(n);
    for (size_t i = 0; i < n; ++i) keep[i] = i;
  }
  if (max_poses > 0 && keep.size() > max_poses) {
    // Every k-th of the thinned poses, counted from the newest so that it is one of them, and
    // the first (room for it: k is taken for max_poses - 1).
    const size_t room = max_poses > 1 ? max_poses - 1 : 1;
    const size_t k = (keep.size() + room - 1) / room;
    std::vector<size_t> strided;
    strided.reserve(keep.size() / k + 2);
    for (size_t i = 0; i < keep.size(); ++i)
      if (i == 0 || (keep.size() - 1 - i) % k == 0) strided.push_back(keep[i]);
    if (max_poses == 1) strided.erase(strided.begin());  // only the newest fits
    keep.swap(strided);
    doublings = -1;
  }
  if (keep.size() == n) return doublings;
  for (size_t out = 0; out < keep.size(); ++out) {
    const size_t i = keep[out];
    m->pose_utime[out] = m->pose_utime[i];
    m->x_m[out] = m->x_m[i];
    m->y_m[out] = m->y_m[i];
    m->yaw_rad[out] = m->yaw_rad[i];
  }
  m->pose_utime.resize(keep.size());
  m->x_m.resize(keep.size());
  m->y_m.resize(keep.size());
  m->yaw_rad.resize(keep.size());
  m->num_poses = static_cast<int32_t>(keep.size());
  return doublings;
}

}  // namespace omni::bus
