// Test helpers of the mapper processes' replay tests: the first scans of a CARMEN log written as
// an LCM log laid out as `omni import carmen` does (odometry on WHEEL_ODOM, scans on LIDAR_SCAN,
// each laser line's own odometry pose published just before its scan), and the ATE of a
// trajectory file against a reference.
#pragma once

#include <cstdint>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omni/bus/convert.h"
#include "omni/eval/eval.h"
#include "omni/io/carmen.h"
#include "omni/io/lcm_log.h"
#include "omni/io/trajectory_io.h"
#include "run.h"

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

// Runs `processes` (command lines, each started in the background) and then `omni-replay LOG
// --speed SPEED` in a private network namespace with loopback multicast (nothing leaves the
// machine), waits for every process and returns the combined output; the exit code is non-zero
// when any of them failed. The script goes to DIR/run.sh.
inline RunResult RunReplayInNetns(const std::string& dir, const std::vector<std::string>& processes,
                                  const std::string& log, const std::string& speed) {
  {
    std::ofstream s(dir + "/run.sh");
    s << "set -u\nip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 3\n"
      << "export LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304'\n"
      << "pids=\"\"\n";
    for (const auto& p : processes) s << p << " & pids=\"$pids $!\"\n";
    s << "sleep 0.5\ntimeout 120 " << Bin("omni-replay") << " " << log << " --speed " << speed
      << "\nrc=$?\nfor p in $pids; do wait $p || rc=$((rc + 1)); done\nexit $rc\n";
  }
  return Run("timeout 250 unshare -n bash " + dir + "/run.sh");
}

}  // namespace omni::testing
