// Occupancy mapping at raw odometry poses (no correction): the library of the odom_mapper
// process. No LCM here; the process feeds it decoded messages.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "omni/common/config.h"
#include "omni/common/geometry.h"
#include "omni/common/result.h"
#include "omni/common/seq_gaps.h"
#include "omni/common/stamp_order.h"
#include "omni/io/grid.h"

namespace omni::odom_mapper {

struct OdomMapperOptions {
  double resolution_m = 0.05;       // grid cell size
  double max_pose_gap_s = 0.5;      // a scan further than this from any odometry is not mapped
  int min_valid_beams = 10;         // scans with fewer valid beams are rejected
  double max_hit_range_m = 25.0;    // returns beyond this are not trusted as obstacles
  double publish_interval_s = 2.0;  // grid publication period (node)
  // Odometry that moves further than this between two samples jumped (a reset or a corrupt
  // value): the map continues from the last good pose instead (counted as odom_jumps).
  double max_odom_jump_m = 3.0;
  double max_odom_jump_rad = 2.0;
  int64_t max_grid_cells = 64LL << 20;  // the grid's size cap (io::LogOddsOptions::max_cells)
  std::string scan_channel = "LIDAR_SCAN";
  std::string odom_channel = "WHEEL_ODOM";
  std::string grid_channel = "GRID_ODOM";

  // Reads every key above from `reader` (all optional); range errors name the key.
  static Result<OdomMapperOptions> Load(ConfigReader& reader);
};

struct OdomMapperCounters {
  int64_t scans_in = 0;
  int64_t scans_mapped = 0;
  int64_t scans_no_pose = 0;        // no odometry close enough in time
  int64_t scans_too_few_beams = 0;  // empty or mostly invalid
  int64_t scans_bad_geometry = 0;   // NaN or absurd angles, mount pose or range limit
  int64_t invalid_beams = 0;        // NaN/inf/negative ranges
  int64_t odom_in = 0;
  int64_t odom_out_of_order = 0;      // older than the newest odometry: rejected
  int64_t odom_invalid = 0;           // non-finite or absurd pose (PlausibleOdometryPose)
  int64_t odom_jumps = 0;             // jumps between samples, bridged (max_odom_jump_*)
  int64_t time_rebases = 0;           // a future-stamped sample dropped (common/stamp_order.h)
  int64_t beams_beyond_grid_cap = 0;  // not mapped: the grid would outgrow max_grid_cells
  int64_t scans_duplicate = 0;        // same seq and stamp as the scan before: mapped once
  int64_t scans_lost = 0;             // gaps in the driver's scan sequence numbers
  // A spinning lidar's scans (scan_time_s > 0): each beam placed at the odometry pose of its own
  // time, or (no odometry over the whole sweep) the scan mapped at its first beam's pose.
  int64_t sweeps_corrected = 0, sweeps_uncorrected = 0;
};

struct Scan {
  int64_t utime = 0;
  int64_t seq = -1;      // driver sequence number (-1: unknown)
  Pose2 sensor_in_base;  // mounting pose
  float angle_min_rad = 0;
  float angle_increment_rad = 0;
  float range_min_m = 0;  // returns below: the robot's own chassis or mast, no walls
  float range_max_m = 0;
  // Time from the first beam (utime) to the last: a spinning lidar measures its beams one
  // after another while the base moves (0: every beam at utime).
  float scan_time_s = 0;
  std::vector<float> ranges_m;
};

class OdomMapper {
 public:
  explicit OdomMapper(const OdomMapperOptions& options);
  bool AddOdometry(int64_t utime, const Pose2& pose);
  bool AddScan(const Scan& scan);
  io::GridMap Map() const { return grid_.ToGridMap(); }
  struct MappedScan {
    int64_t utime;
    int64_t seq;  // the scan's sequence number (-1 if unknown)
    Pose2 base_pose;
  };
  // Pose of the base at every mapped scan.
  const std::vector<MappedScan>& trajectory() const { return trajectory_; }
  const OdomMapperCounters& counters() const { return counters_; }

 private:
  OdomMapperOptions opt_;
  io::LogOddsGrid grid_;
  StampedBuffer<Pose2> odom_;
  std::vector<MappedScan> trajectory_;
  OdomMapperCounters counters_;
  SeqGaps seq_gaps_;  // scans lost between the driver and us, from their sequence numbers
  int64_t last_scan_utime_ = INT64_MIN;
  void Take(int64_t utime, const Pose2& pose);  // an in-order sample: jump check, buffer
  std::optional<Pose2> last_raw_;  // the newest accepted raw sample, for jump detection
  Pose2 correction_;               // raw odometry -> jump-free odometry
  HeldRun<Pose2> stream_;          // raw samples: older ones held until they re-base or give up
  struct JumpState {
    Pose2 correction, raw;
  };
  StateHistory<JumpState> history_;  // after each taken sample, for a re-base
};

}  // namespace omni::odom_mapper
