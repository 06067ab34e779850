// omni-bench-trajectory: what the mappers' TRAJECTORY_PG / TRAJECTORY_RBPF messages cost after
// hours of mapping. A recorded path (`index timestamp x y theta`) is repeated until it spans
// --hours, then sent through bus::ToTrajectoryMessage as the mappers do: thinned within its
// tolerances (bus::TrajectoryThinning), beside the whole path and beside the every-k-th cap the
// messages used before thinning. For each it prints the poses and bytes of one message, the time
// to make it (median of --repeat) and how far the receivers' interpolation between the poses sent
// lands from the full path (position, heading; the worst over every input pose).
//
// usage: omni-bench-trajectory [--hours H] [--repeat N] [--out DIR] [TRAJECTORY.txt ...]
//   writes DIR/trajectory.jsonl (default out/bench), one row per input and way of sending;
//   default inputs: out/sim/{posegraph,rbpf}/trajectory.txt (./omni demo writes them), else
//   the intel-raw and Freiburg 079 references (OMNI_DATASETS_DIR or the build's default).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "omni/bus/convert.h"
#include "omni/common/geometry.h"
#include "omni/io/trajectory_io.h"

namespace {

struct Stamped {
  int64_t utime;
  omni::Pose2 pose;
};

// The path repeated back to back until it covers `hours`: each copy shifted in time by the
// path's span plus one step and moved rigidly so that it starts where the one before ended (no
// jump at the seams, which no robot makes).
std::vector<Stamped> Tiled(const std::vector<Stamped>& path, double hours) {
  std::vector<Stamped> out;
  if (path.size() < 2) return path;
  const int64_t step = (path.back().utime - path.front().utime) / (int64_t(path.size()) - 1);
  const int64_t period = path.back().utime - path.front().utime + std::max<int64_t>(step, 1);
  const auto want = static_cast<int64_t>(hours * 3600e6);
  omni::Pose2 place;  // where the copy's first pose goes
  place = path.front().pose;
  for (int64_t shift = 0; shift < want; shift += period) {
    const omni::Pose2 move = place * path.front().pose.Inverse();
    for (const Stamped& s : path) {
      if (s.utime - path.front().utime + shift >= want) break;
      out.push_back({s.utime + shift, move * s.pose});
    }
    place = out.back().pose;
  }
  return out;
}

// The worst distance between each input pose and the message interpolated at its time, as the
// OctoMap builder's lookup does (poses outside the message or across a step back are skipped).
void WorstError(const std::vector<Stamped>& path, const omni::trajectory_t& m, double* worst_m,
                double* worst_rad) {
  *worst_m = 0;
  *worst_rad = 0;
  const auto& t = m.pose_utime;
  for (const Stamped& s : path) {
    const auto it = std::lower_bound(t.begin(), t.end(), s.utime);
    if (it == t.end()) continue;
    const auto b = static_cast<size_t>(it - t.begin());
    omni::Pose2 q(m.x_m[b], m.y_m[b], m.yaw_rad[b]);
    if (t[b] != s.utime) {
      if (b == 0) continue;
      const double f =
          static_cast<double>(s.utime - t[b - 1]) / static_cast<double>(t[b] - t[b - 1]);
      q = omni::Interpolate(omni::Pose2(m.x_m[b - 1], m.y_m[b - 1], m.yaw_rad[b - 1]), q, f);
    }
    *worst_m = std::max(*worst_m, std::hypot(q.x - s.pose.x, q.y - s.pose.y));
    *worst_rad = std::max(*worst_rad, std::abs(omni::WrapAngle(q.theta - s.pose.theta)));
  }
}

void Row(std::ofstream& json, const std::string& file, const char* what,
         const std::vector<Stamped>& path, const omni::bus::TrajectoryThinning& th,
         size_t max_poses, int repeat) {
  std::vector<double> ms;
  omni::trajectory_t m;
  for (int r = 0; r < repeat; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    m = omni::bus::ToTrajectoryMessage(path, "map", "bench", th, max_poses);
    ms.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(ms.begin(), ms.end());
  double em = 0, er = 0;
  WorstError(path, m, &em, &er);
  std::printf("  %-34s %8d poses %8.3f MB %8.1f ms   worst %6.3f m %6.4f rad\n", what, m.num_poses,
              static_cast<double>(m.num_poses) * 32 / 1e6, ms[ms.size() / 2], em, er);
  json << "{\"input\": \"" << file << "\", \"message\": \"" << what
       << "\", \"path_poses\": " << path.size() << ", \"poses\": " << m.num_poses
       << ", \"ms\": " << ms[ms.size() / 2] << ", \"worst_m\": " << em << ", \"worst_rad\": " << er
       << "}\n";
}

}  // namespace

int main(int argc, char** argv) {
  double hours = 8;
  int repeat = 3;
  std::vector<std::string> files;
  std::string out_dir = "out/bench";
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--hours" && i + 1 < argc) {
      hours = std::atof(argv[++i]);
    } else if (a == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--out" && i + 1 < argc) {
      out_dir = argv[++i];
    } else if (a == "-h" || a == "--help") {
      std::printf(
          "usage: omni-bench-trajectory [--hours H] [--repeat N] [--out DIR] [TRAJECTORY.txt ...]\n"
          "  One TRAJECTORY_* message after H hours (default 8) of each path repeated: thinned\n"
          "  (shipped), every k-th under the 40,000-pose cap (before) and whole; poses, MB, time\n"
          "  to make (median of N, default 3) and the receivers' worst interpolation error.\n"
          "  Default paths: out/sim/{posegraph,rbpf}/trajectory.txt (./omni demo writes them),\n"
          "  else the intel-raw and Freiburg 079 references. Writes DIR/trajectory.jsonl\n"
          "  (default out/bench).\n");
      return 0;
    } else if (!a.empty() && a[0] == '-') {
      std::fprintf(stderr, "omni-bench-trajectory: unknown option %s\n", a.c_str());
      return 2;
    } else {
      files.push_back(a);
    }
  }
  if (!(hours > 0)) {
    std::fprintf(stderr, "omni-bench-trajectory: --hours must be > 0\n");
    return 2;
  }
  if (files.empty()) {
    const char* env = std::getenv("OMNI_DATASETS_DIR");
    const std::string data = env ? env : OMNI_DEFAULT_DATASETS;
    // The mappers' own output at the scan rate; the datasets' references (sparser, and Freiburg
    // 079's jitters from scan to scan) only without it.
    for (const char* f : {"out/sim/posegraph/trajectory.txt", "out/sim/rbpf/trajectory.txt"})
      if (std::filesystem::exists(f)) files.push_back(f);
    if (files.empty())
      for (const char* f :
           {"/intel-raw/intel.reference.txt", "/slam-noisy-odom/freiburg-079.reference.txt"})
        if (std::filesystem::exists(data + f)) files.push_back(data + f);
    if (files.empty()) {
      std::fprintf(stderr, "omni-bench-trajectory: no datasets in %s and no out/sim; name a file\n",
                   data.c_str());
      return 2;
    }
  }
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  std::ofstream json(std::filesystem::path(out_dir) / "trajectory.jsonl");
  const omni::bus::TrajectoryThinning shipped;
  omni::bus::TrajectoryThinning whole;
  whole.tolerance_m = 0;
  std::printf(
      "one TRAJECTORY_* message after %.1f h of the path repeated (thinned: %.3f m, %.4f rad, "
      "%.1f s gap; cap %zu poses)\n",
      hours, shipped.tolerance_m, shipped.tolerance_rad, shipped.max_gap_us / 1e6,
      omni::bus::kMaxTrajectoryMessagePoses);
  for (const std::string& f : files) {
    auto tr = omni::io::ReadTrajectory(f);
    if (!tr.ok()) {
      std::fprintf(stderr, "omni-bench-trajectory: %s: %s\n", f.c_str(),
                   tr.error().message.c_str());
      return 1;
    }
    std::vector<Stamped> path;
    for (const auto& e : tr->entries) {
      const auto u = static_cast<int64_t>(std::llround(e.timestamp_s * 1e6));
      if (!path.empty() && u <= path.back().utime) continue;  // the mappers send unique stamps
      path.push_back({u, e.pose2()});
    }
    if (path.size() < 2) {
      std::fprintf(stderr, "omni-bench-trajectory: %s: fewer than two poses\n", f.c_str());
      return 1;
    }
    const double rate =
        static_cast<double>(path.size() - 1) / ((path.back().utime - path.front().utime) / 1e6);
    const std::vector<Stamped> long_path = Tiled(path, hours);
    std::printf("%s: %zu poses at %.1f Hz, repeated to %zu\n", f.c_str(), path.size(), rate,
                long_path.size());
    Row(json, f, "the path once, thinned", path, shipped, omni::bus::kMaxTrajectoryMessagePoses,
        repeat);
    Row(json, f, "the path once, whole", path, whole, 0, repeat);
    Row(json, f, "repeated, thinned (shipped)", long_path, shipped,
        omni::bus::kMaxTrajectoryMessagePoses, repeat);
    Row(json, f, "repeated, every k-th (before)", long_path, whole,
        omni::bus::kMaxTrajectoryMessagePoses, repeat);
    Row(json, f, "repeated, whole", long_path, whole, 0, repeat);
  }
  return 0;
}
