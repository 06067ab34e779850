// omni-import: converts recorded datasets to LCM logs of omni's bus messages.
//   omni-import carmen IN.clf[.gz] OUT.lcmlog
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <numeric>
#include <string>
#include <vector>

#include "omni/bus/channels.h"
#include "omni/bus/convert.h"
#include "omni/io/carmen.h"
#include "omni/io/lcm_log.h"

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni import carmen IN.clf[.gz] OUT.lcmlog\n"
      "  Converts a CARMEN log (FLASER, RLASER, ROBOTLASER1, ODOM lines) into an LCM log:\n"
      "  laser lines -> %s (omni.laser_scan_t), ODOM -> %s (omni.odometry_t),\n"
      "  sorted by timestamp (file order kept for equal timestamps).\n",
      omni::channels::kLidarScan, omni::channels::kWheelOdom);
}

template <class Msg>
std::vector<uint8_t> Encode(const Msg& m) {
  std::vector<uint8_t> buf(static_cast<size_t>(m.getEncodedSize()));
  m.encode(buf.data(), 0, static_cast<int>(buf.size()));
  return buf;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 2 && (!std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h"))) {
    Usage(stdout);
    return 0;
  }
  if (argc != 4 || std::strcmp(argv[1], "carmen") != 0) {
    Usage(stderr);
    return 2;
  }
  const std::string in = argv[2], out = argv[3];
  std::error_code ec;
  if (std::filesystem::equivalent(in, out, ec)) {
    std::fprintf(stderr, "omni import: OUT '%s' is the input file; name another file\n",
                 out.c_str());
    return 2;
  }
  auto log = omni::io::ReadCarmenLog(in);
  if (!log.ok()) {
    std::fprintf(stderr, "omni import: %s\n", log.error().message.c_str());
    return 1;
  }
  if (log->records.empty()) {
    // A file of something else (a trajectory, a g2o graph) has no CARMEN lines: an empty log
    // written and "imported" would only surface later as a mapper with nothing to map.
    std::fprintf(stderr,
                 "omni import: %s holds no FLASER, RLASER, ROBOTLASER1 or ODOM line: not a CARMEN "
                 "log (nothing written)\n",
                 in.c_str());
    return 1;
  }
  std::vector<size_t> order(log->records.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return log->records[a].timestamp_s() < log->records[b].timestamp_s();
  });
  const std::string tmp = out + ".partial";
  // Its folder is made as a recorder would (`out/x.lcmlog` on a fresh checkout); an error making
  // it shows as the writer's.
  if (const auto dir = std::filesystem::path(out).parent_path(); !dir.empty())
    std::filesystem::create_directories(dir, ec);
  auto writer = omni::io::LcmLogWriter::Open(tmp);
  if (!writer.ok()) {
    std::fprintf(stderr, "omni import: %s\n", writer.error().message.c_str());
    return 1;
  }
  int64_t scans = 0, odoms = 0;
  for (size_t i : order) {
    const auto& r = log->records[i];
    omni::Status s;
    if (r.kind == omni::io::CarmenRecord::Kind::kLaser) {
      const auto msg = omni::bus::ToLaserScan(r.laser, scans++);
      const auto buf = Encode(msg);
      s = writer->Write(msg.utime, omni::channels::kLidarScan, buf.data(), buf.size());
    } else {
      const auto msg = omni::bus::ToOdometry(r.odom, odoms++);
      const auto buf = Encode(msg);
      s = writer->Write(msg.utime, omni::channels::kWheelOdom, buf.data(), buf.size());
    }
    if (!s.ok()) {
      std::fprintf(stderr, "omni import: %s\n", s.message().c_str());
      return 1;
    }
  }
  if (auto s = writer->Close(); !s.ok() || std::rename(tmp.c_str(), out.c_str()) != 0) {
    std::fprintf(stderr, "omni import: cannot finish '%s'\n", out.c_str());
    return 1;
  }
  std::printf("imported %s -> %s: %lld laser scans on %s, %lld odometry messages on %s", in.c_str(),
              out.c_str(), static_cast<long long>(scans), omni::channels::kLidarScan,
              static_cast<long long>(odoms), omni::channels::kWheelOdom);
  if (!log->skipped.empty()) {
    std::printf("; skipped other lines:");
    for (const auto& [tag, n] : log->skipped) std::printf(" %s x%zu", tag.c_str(), n);
  }
  std::printf("\n");
  // Stamps that make the log's time meaningless for replay and interpolation: the CSAIL logs
  // have 406 ODOM lines stamped 0 (sorted to 1970, before everything) and their laser lines
  // share two stamps between them (printed with 6 significant digits).
  int64_t zero = 0, repeated_laser = 0, lasers_seen = 0;
  double last_laser = 0;
  for (const auto& r : log->records) {
    if (!(r.timestamp_s() > 0)) ++zero;
    if (r.kind != omni::io::CarmenRecord::Kind::kLaser) continue;
    if (lasers_seen++ > 0 && r.laser.timestamp_s == last_laser) ++repeated_laser;
    last_laser = r.laser.timestamp_s;
  }
  if (zero > 0)
    std::fprintf(stderr,
                 "omni import: warning: %lld lines are stamped 0 or less; sorted by time they come "
                 "before every other line, and replaying or interpolating across them is "
                 "meaningless\n",
                 static_cast<long long>(zero));
  if (lasers_seen > 1 && repeated_laser * 10 > lasers_seen)
    std::fprintf(
        stderr,
        "omni import: warning: %lld of %lld laser lines repeat the stamp of the one before "
        "(a log written with too few digits?): their times say little\n",
        static_cast<long long>(repeated_laser), static_cast<long long>(lasers_seen));
  if (scans == 0)
    std::fprintf(stderr,
                 "omni import: warning: no laser line was read (FLASER, RLASER, ROBOTLASER1); "
                 "RAWLASER lines are not imported, so the log has odometry only and no mapper "
                 "can map it\n");
  return 0;
}
