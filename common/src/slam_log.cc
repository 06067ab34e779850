#include "omni/bus/slam_log.h"

#include <cmath>
#include <cstdio>
#include <deque>
#include <fstream>

#include "omni/bus/bus.h"
#include "omni/bus/convert.h"
#include "omni/common/seq_gaps.h"
#include "omni/common/time.h"
#include "omni/imu_t.hpp"
#include "omni/io/carmen.h"
#include "omni/io/lcm_log.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odometry_t.hpp"

namespace omni::bus {

bool IsLcmLogFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char b[4] = {0, 0, 0, 0};
  in.read(reinterpret_cast<char*>(b), 4);
  return in.gcount() == 4 && b[0] == 0xED && b[1] == 0xA1 && b[2] == 0xDA && b[3] == 0x01;
}

void ReportSlamLogProblems(const char* program, const std::string& input, const SlamLogResult& r) {
  if (!r.stopped_early.empty())
    std::fprintf(stderr, "%s: %s (stopping there)\n", program, r.stopped_early.c_str());
  if (r.skipped_bytes > 0)
    std::fprintf(stderr,
                 "%s: warning: %llu corrupt bytes of %s skipped (the events in them are lost; "
                 "stats.json skipped_bytes)\n",
                 program, static_cast<unsigned long long>(r.skipped_bytes), input.c_str());
  for (const auto& [channel, n] : r.decode_errors_by_channel)
    std::fprintf(stderr,
                 "%s: warning: %lld messages on %s did not decode (another message type, or "
                 "truncated) and were skipped (stats.json decode_errors)\n",
                 program, static_cast<long long>(n), channel.c_str());
  if (r.scans_repeated > 0)
    std::fprintf(stderr, "%s: %lld repeated scans (same seq and stamp) used once\n", program,
                 static_cast<long long>(r.scans_repeated));
  if (r.scans_lost > 0)
    std::fprintf(stderr, "%s: warning: %lld scans missing from the log (gaps in seq)\n", program,
                 static_cast<long long>(r.scans_lost));
}

namespace {

// Scans held for the odometry of their sweep's end, in file order (ReadLcm).
class ScanHold {
 public:
  explicit ScanHold(const SlamLogHandlers& h) : h_(h) {}
  // Hands odometry over. A sample older than the latest (a clock set back, or a stale one) first
  // hands over every scan held, which came before it, as the live node does (the mapper decides
  // about a step back from the scans it has); then the scans it covers follow it. False when
  // the scan handler asked to stop.
  bool Odometry(int64_t utime, const Pose2& pose) {
    if (have_odom_ && utime < newest_odom_ && !Release(true)) return false;
    h_.odom(utime, pose);
    have_odom_ = true;
    newest_odom_ = utime;  // the latest (after a step back, the new clock's)
    return Release(false);
  }
  // False when the scan handler asked to stop.
  bool Add(SlamScan s) {
    // The latest stamp, not the largest: a future one holds nothing up for long.
    newest_scan_ = s.utime;
    held_.push_back(std::move(s));
    return Release(false);
  }
  // Hands over the scans that are due (all with `all`); false when the handler asked to stop.
  bool Release(bool all) {
    while (!held_.empty() && (all || Due(held_.front()))) {
      SlamScan s = std::move(held_.front());
      held_.pop_front();
      if (!h_.scan(s)) return false;
    }
    return true;
  }

 private:
  // A lidar's scan message comes at the end of its sweep, and the odometry sample covering that
  // end may come just after it: the mapper could not undo the sweep's motion. A scan waits for
  // odometry at or after its end, as the live mappers' queues make it; not when there is no
  // odometry, when its end is more than kMaxWaitUs past the newest odometry (a stamp in the
  // future) or kMaxWaitUs before the latest scan's stamp (the odometry stopped: the mapper
  // decides), or behind kMaxHeld others.
  bool Due(const SlamScan& s) const {
    static constexpr int64_t kMaxWaitUs = 500000;
    static constexpr size_t kMaxHeld = 64;
    if (!have_odom_ || held_.size() > kMaxHeld) return true;
    // (Stamps may be anything a log holds: a sum that overflows is far from any odometry.)
    int64_t end = 0, ahead = 0, behind = 0;
    if (__builtin_add_overflow(s.utime, std::llround(s.scan_time_s * 1e6), &end) ||
        __builtin_sub_overflow(end, newest_odom_, &ahead) ||
        __builtin_sub_overflow(newest_scan_, end, &behind))
      return true;
    return ahead <= 0 || ahead > kMaxWaitUs || behind > kMaxWaitUs;
  }
  const SlamLogHandlers& h_;
  std::deque<SlamScan> held_;
  bool have_odom_ = false;
  int64_t newest_odom_ = 0, newest_scan_ = 0;
};

Result<SlamLogResult> ReadLcm(io::LcmLogReader* reader, const SlamLogChannels& channels,
                              const SlamLogHandlers& handlers) {
  SlamLogResult out;
  io::LcmLogEvent ev;
  int64_t last_seq = -1, last_utime = 0;
  SeqGaps gaps;
  ScanHold hold(handlers);
  bool go_on = true;
  for (;;) {
    auto more = reader->Next(&ev, /*resync=*/true);
    if (!more.ok()) {
      // A truncated last event ends the reading; a failed read is an error (the rest of the log
      // is there, unread).
      if (!reader->truncated_tail()) return more.error();
      out.stopped_early = more.error().message;
      break;
    }
    if (!*more) break;
    const int size = static_cast<int>(ev.data.size());
    if (ev.channel == channels.scan) {
      omni::laser_scan_t m;
      if (omni::bus::DecodeMessage(&m, ev.data.data(), size) < 0) {
        ++out.decode_errors;
        ++out.decode_errors_by_channel[ev.channel];
        continue;
      }
      if (last_seq >= 0 && m.seq == last_seq && m.utime == last_utime) {
        ++out.scans_repeated;
        continue;
      }
      gaps.Add(m.seq);
      out.scans_lost = gaps.lost();
      if (m.seq >= 0) last_seq = m.seq;
      last_utime = m.utime;
      SlamScan s;
      s.utime = m.utime;
      s.sensor_in_base = Pose2(m.sensor_x_m, m.sensor_y_m, m.sensor_yaw_rad);
      s.angle_min_rad = m.angle_min_rad;
      s.angle_increment_rad = m.angle_increment_rad;
      s.range_min_m = m.range_min_m;
      s.range_max_m = m.range_max_m;
      s.ranges_m = std::move(m.ranges_m);
      s.scan_time_s = SweepTime(m.scan_time_s);
      if (!(go_on = hold.Add(std::move(s)))) break;
    } else if (ev.channel == channels.odom) {
      omni::odometry_t m;
      if (omni::bus::DecodeMessage(&m, ev.data.data(), size) < 0) {
        ++out.decode_errors;
        ++out.decode_errors_by_channel[ev.channel];
        continue;
      }
      if (!(go_on = hold.Odometry(m.utime, Pose2(m.x_m, m.y_m, m.yaw_rad)))) break;
    } else if (handlers.imu && ev.channel == channels.imu) {
      omni::imu_t m;
      if (omni::bus::DecodeMessage(&m, ev.data.data(), size) < 0) {
        ++out.decode_errors;
        ++out.decode_errors_by_channel[ev.channel];
        continue;
      }
      handlers.imu(m.utime, m.angular_velocity_rad_s[2]);
    }
  }
  if (go_on) hold.Release(true);  // the log ended: nothing more will cover them
  out.skipped_bytes = reader->skipped_bytes();
  return out;
}

Result<SlamLogResult> ReadCarmen(const std::string& path, const SlamLogHandlers& handlers) {
  auto log = io::ReadCarmenLog(path);
  if (!log.ok()) return log.error();
  for (const auto& rec : log->records) {
    if (rec.kind == io::CarmenRecord::Kind::kOdom) {
      handlers.odom(SecondsToUtime(rec.odom.timestamp_s), rec.odom.pose);
      continue;
    }
    const auto& l = rec.laser;
    SlamScan s;
    s.utime = SecondsToUtime(l.timestamp_s);
    s.sensor_in_base = l.robot_pose.Between(l.laser_pose);
    s.angle_min_rad = l.angle_min_rad;
    s.angle_increment_rad = l.angle_increment_rad;
    s.range_max_m = l.max_range_m;
    s.ranges_m = l.ranges_m;
    s.odom = l.robot_pose;
    if (!handlers.scan(s)) break;
  }
  return SlamLogResult{};
}

}  // namespace

Result<SlamLogResult> ReadSlamLog(const std::string& path, const SlamLogChannels& channels,
                                  const SlamLogHandlers& handlers) {
  if (!IsLcmLogFile(path)) return ReadCarmen(path, handlers);
  auto reader = io::LcmLogReader::Open(path);
  if (!reader.ok()) return reader.error();
  return ReadLcm(&*reader, channels, handlers);
}

Result<SlamLogResult> ReadSlamLcmLog(io::LcmLogReader reader, const SlamLogChannels& channels,
                                     const SlamLogHandlers& handlers) {
  return ReadLcm(&reader, channels, handlers);
}

}  // namespace omni::bus
