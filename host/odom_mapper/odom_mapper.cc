#include "omni/odom_mapper/odom_mapper.h"

#include <cmath>

#include "omni/common/scan_checks.h"

namespace omni::odom_mapper {

Result<OdomMapperOptions> OdomMapperOptions::Load(ConfigReader& r) {
  OdomMapperOptions o;
  r.Get("resolution_m", &o.resolution_m, Optional(), InRange(0.005, 1.0));
  r.Get("max_pose_gap_s", &o.max_pose_gap_s, Optional(), InRange(0.0, 10.0));
  r.Get("min_valid_beams", &o.min_valid_beams, Optional(), InRange(1, 100000));
  r.Get("max_hit_range_m", &o.max_hit_range_m, Optional(), InRange(0.1, 1000.0));
  r.Get("publish_interval_s", &o.publish_interval_s, Optional(), InRange(0.05, 3600.0));
  r.Get("max_odom_jump_m", &o.max_odom_jump_m, Optional(), Positive<double>());
  r.Get("max_odom_jump_rad", &o.max_odom_jump_rad, Optional(), Positive<double>());
  r.Get("max_grid_cells", &o.max_grid_cells, Optional(),
        InRange<int64_t>(int64_t{1} << 16, io::kMaxGridCells));
  r.Get("scan_channel", &o.scan_channel, Optional(), NonEmpty());
  r.Get("odom_channel", &o.odom_channel, Optional(), NonEmpty());
  r.Get("grid_channel", &o.grid_channel, Optional(), NonEmpty());
  if (Status s = r.Finish(); !s.ok()) return s.error();
  return o;
}

namespace {
io::LogOddsOptions GridOptions(const OdomMapperOptions& o) {
  io::LogOddsOptions g;
  g.resolution_m = o.resolution_m;
  g.max_hit_range_m = static_cast<float>(o.max_hit_range_m);
  g.max_cells = o.max_grid_cells;
  return g;
}
}  // namespace

OdomMapper::OdomMapper(const OdomMapperOptions& options)
    : opt_(options), grid_(GridOptions(options)), odom_(100000) {}

bool OdomMapper::AddOdometry(int64_t utime, const Pose2& pose) {
  ++counters_.odom_in;
  if (!PlausibleOdometryPose(pose)) {
    ++counters_.odom_invalid;
    return false;
  }
  // Older samples are held; a run of them re-bases the stream: the newest samples were stamped
  // in the future (or the clock went back), so they are dropped and the jump bridge is put
  // back as it was before them.
  const auto rebase = [this](int64_t from) {
    ++counters_.time_rebases;
    odom_.DropFrom(from);
    if (const auto s = history_.Restore(from)) {
      correction_ = s->correction;
      last_raw_ = s->raw;
    }
  };
  const auto take = [this](int64_t t, const Pose2& p) { Take(t, p); };
  if (stream_.Add(utime, pose, rebase, take) == StampOrder::Verdict::kOld) {
    ++counters_.odom_out_of_order;
    return false;
  }
  return true;
}

void OdomMapper::Take(int64_t utime, const Pose2& pose) {
  if (last_raw_) {
    const Pose2 d = last_raw_->Between(pose);
    if (std::hypot(d.x, d.y) > opt_.max_odom_jump_m || std::abs(d.theta) > opt_.max_odom_jump_rad) {
      // A reset or a corrupt value: the map continues from the last good pose.
      ++counters_.odom_jumps;
      correction_ = (correction_ * *last_raw_) * pose.Inverse();
    }
  }
  last_raw_ = pose;
  odom_.Insert(utime, correction_ * pose);
  history_.Push(utime, {correction_, pose});
}

bool OdomMapper::AddScan(const Scan& scan) {
  ++counters_.scans_in;
  if (scan.seq > 0 && scan.seq == seq_gaps_.newest() && scan.utime == last_scan_utime_) {
    ++counters_.scans_duplicate;  // the same scan again (a repeating driver or bridge)
    return false;
  }
  last_scan_utime_ = scan.utime;
  seq_gaps_.Add(scan.seq);
  counters_.scans_lost = seq_gaps_.lost();
  int valid = 0;
  std::vector<float> ranges(scan.ranges_m.size());
  for (size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const float r = scan.ranges_m[i];
    if (std::isfinite(r) && r > 0.f && r >= scan.range_min_m) {
      ranges[i] = r;
      if (r < ScanRangeLimit(scan.range_max_m)) ++valid;
    } else if (std::isfinite(r) && r > 0.f) {
      ranges[i] = std::nanf("");  // below range_min: no return, as the SLAM mappers take it
    } else {
      if (!std::isnan(r) || std::signbit(r)) ++counters_.invalid_beams;  // inf / negative
      ranges[i] = std::nanf("");
    }
  }
  if (valid < opt_.min_valid_beams || !std::isfinite(scan.angle_increment_rad)) {
    ++counters_.scans_too_few_beams;
    return false;
  }
  // As the SLAM mappers check it: NaN or absurd angles, mount pose or range limit are never
  // mapped (they were counted as mapped, their beams as beyond the grid's cap).
  if (!PlausibleScanGeometry(scan.angle_min_rad, scan.angle_increment_rad, scan.ranges_m.size(),
                             scan.range_max_m, scan.sensor_in_base)) {
    ++counters_.scans_bad_geometry;
    return false;
  }
  const auto pose = odom_.At(scan.utime, static_cast<int64_t>(opt_.max_pose_gap_s * 1e6));
  if (!pose) {
    ++counters_.scans_no_pose;
    return false;
  }
  // A sweep: beam i at utime + i / (n - 1) * scan_time_s, from the odometry pose of that time
  // (the odometry is there up to about the end of the sweep when the scan arrives; a beam up to
  // one odometry period past the newest sample takes the newest).
  const size_t n = ranges.size();
  std::vector<Pose2> beam_pose;
  if (scan.scan_time_s > 0 && scan.scan_time_s <= 1.f && n > 1) {  // (NaN fails the first)
    constexpr int64_t kSlackUs = 20000;
    beam_pose.reserve(n);
    for (size_t i = 0; i < n; ++i) {
      const int64_t t = scan.utime + static_cast<int64_t>(std::llround(scan.scan_time_s * 1e6 *
                                                                       static_cast<double>(i) /
                                                                       static_cast<double>(n - 1)));
      const auto p = odom_.At(t, kSlackUs);
      if (!p) {
        beam_pose.clear();
        break;
      }
      beam_pose.push_back(*p * scan.sensor_in_base);
    }
    ++(beam_pose.empty() ? counters_.sweeps_uncorrected : counters_.sweeps_corrected);
  }
  const int64_t refused = grid_.refused_beams();
  if (beam_pose.empty()) {
    grid_.IntegrateScan(*pose * scan.sensor_in_base, ranges, scan.angle_min_rad,
                        scan.angle_increment_rad, ScanRangeLimit(scan.range_max_m));
  } else {
    grid_.IntegrateScan([&](size_t i) { return beam_pose[i]; }, ranges, scan.angle_min_rad,
                        scan.angle_increment_rad, ScanRangeLimit(scan.range_max_m));
  }
  counters_.beams_beyond_grid_cap += grid_.refused_beams() - refused;
  trajectory_.push_back({scan.utime, scan.seq, *pose});
  ++counters_.scans_mapped;
  return true;
}

}  // namespace omni::odom_mapper
