// Test helpers of the mapper processes' replay tests: the first scans of a CARMEN log written as
// an LCM log laid out as `omni import carmen` does (odometry on WHEEL_ODOM, scans on LIDAR_SCAN,
// each laser line's own odometry pose published just before its scan), and the ATE of a
// trajectory file against a reference.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/bus/convert.h"
#include "omni/eval/eval.h"
#include "omni/io/carmen.h"
#include "omni/io/lcm_log.h"
#include "omni/io/trajectory_io.h"

namespace omni::testing {

inline void WriteCarmenPrefixLog(const std::string& clf, const std::string& out, size_t scans) {
  auto log = io::ReadCarmenLog(clf);
  ASSERT_TRUE(log.ok()) << log.error().message;
  auto w = io::LcmLogWriter::Open(out);
  ASSERT_TRUE(w.ok());
  int64_t seq = 0, oseq = 0;
  auto put = [&](const auto& msg, const std::string& channel, int64_t utime) {
    std::vector<uint8_t> buf(static_cast<size_t>(msg.getEncodedSize()));
    msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
    ASSERT_TRUE(w->Write(utime, channel, buf.data(), buf.size()).ok());
  };
  for (const auto& r : log->records) {
    if (r.kind == io::CarmenRecord::Kind::kOdom) {
      const auto m = bus::ToOdometry(r.odom, oseq++);
      put(m, "WHEEL_ODOM", m.utime);
      continue;
    }
    io::CarmenOdom o;
    o.timestamp_s = r.laser.timestamp_s;
    o.pose = r.laser.robot_pose;
    const auto om = bus::ToOdometry(o, oseq++);
    put(om, "WHEEL_ODOM", om.utime);
    const auto m = bus::ToLaserScan(r.laser, seq);
    put(m, "LIDAR_SCAN", m.utime);
    if (static_cast<size_t>(++seq) >= scans) break;
  }
  ASSERT_TRUE(w->Close().ok());
}

// ATE RMSE in metres of `est_path` against `ref_path` (1e9 when either is unreadable or they
// share no stamps); `matched` gets the number of matched poses.
inline double AteRmse(const std::string& ref_path, const std::string& est_path, size_t* matched) {
  auto ref = io::ReadTrajectory(ref_path);
  auto est = io::ReadTrajectory(est_path);
  if (!ref.ok() || !est.ok()) return 1e9;
  auto ate = eval::ComputeAte(*ref, *est);
  if (!ate.ok()) return 1e9;
  *matched = ate->matched;
  return ate->rmse_m;
}

}  // namespace omni::testing
