// A recorded log as the inputs of a 2D SLAM run: laser scans, wheel odometry and the gyro's yaw
// rate, in file order, from a CARMEN log (.clf/.log, optionally gzip) or an LCM log of omni's
// messages (recognised by its sync word). The offline SLAM runners share it.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "omni/common/geometry.h"
#include "omni/common/result.h"
#include "omni/io/lcm_log.h"

namespace omni::bus {

struct SlamScan {
  int64_t utime = 0;
  Pose2 sensor_in_base;
  float angle_min_rad = 0;
  float angle_increment_rad = 0;
  std::optional<float> range_min_m;  // absent: the log does not say (CARMEN)
  float range_max_m = 0;
  std::vector<float> ranges_m;
  float scan_time_s = 0;      // first to last beam (a spinning lidar's sweep); 0: one instant
  std::optional<Pose2> odom;  // the base's odometry pose at the scan, when the line carries it
};

struct SlamLogChannels {
  std::string scan = "LIDAR_SCAN";
  std::string odom = "WHEEL_ODOM";
  std::string imu = "IMU";
};

struct SlamLogHandlers {
  std::function<bool(const SlamScan&)> scan;  // false stops the reading
  std::function<void(int64_t utime, const Pose2& pose)> odom;
  std::function<void(int64_t utime, double yaw_rate_rad_s)> imu;  // may be empty
};

struct SlamLogResult {
  int64_t decode_errors = 0;  // LCM events on a SLAM channel that did not decode (skipped)
  std::map<std::string, int64_t> decode_errors_by_channel;
  std::string stopped_early;   // a truncated LCM log: where and why the reading stopped
  uint64_t skipped_bytes = 0;  // corrupt LCM log bytes skipped to the next event's sync word
  // LCM logs: a scan with the seq and stamp of the one before (a repeating driver or bridge) is
  // passed on once, as the live mappers do; gaps in seq count scans lost before the log.
  int64_t scans_repeated = 0;
  int64_t scans_lost = 0;
};

bool IsLcmLogFile(const std::string& path);

// Tells stderr, as `program`, where a read of `input` stopped early and how many corrupt bytes it
// skipped (events lost), so no offline run loses data without a word.
void ReportSlamLogProblems(const char* program, const std::string& input, const SlamLogResult& r);

// Reads `path` and calls the handlers in file order, except that an LCM log's scan is handed
// over once odometry at or after its sweep's last beam has been, as the live mappers' queues do
// (the sample covering it may come just after the scan); it is not held for odometry more than
// 0.5 s past the newest, nor 0.5 s before the latest scan, nor behind 64 others, nor past an
// older odometry stamp (a clock set back), nor past the log's end. An unreadable file or a
// bad CARMEN line is an error. Inside an LCM log a corrupt region is skipped to the next event
// (counted in `skipped_bytes`: the events in it are lost, callers must say so) and a truncated
// last event ends the reading (said in `stopped_early`); a read that fails is an error.
Result<SlamLogResult> ReadSlamLog(const std::string& path, const SlamLogChannels& channels,
                                  const SlamLogHandlers& handlers);
// The same on an LCM log already open (any seekable stream, LcmLogReader::FromStream).
Result<SlamLogResult> ReadSlamLcmLog(io::LcmLogReader reader, const SlamLogChannels& channels,
                                     const SlamLogHandlers& handlers);

}  // namespace omni::bus
