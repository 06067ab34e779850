// odom_mapper process: LIDAR_SCAN + WHEEL_ODOM -> GRID_ODOM, and map files on exit.

#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/bus/bus.h"
#include "omni/bus/channels.h"
#include "omni/bus/convert.h"
#include "omni/bus/heartbeat.h"
#include "omni/bus/map_save.h"
#include "omni/bus/mapping_health.h"
#include "omni/bus/node_loop.h"
#include "omni/common/cli.h"
#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/common/odometry_restart.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/previous_outputs.h"
#include "omni/io/trajectory_io.h"
#include "omni/laser_scan_t.hpp"
#include "omni/odom_mapper/odom_mapper.h"
#include "omni/odom_mapper/scan_message.h"
#include "omni/odometry_t.hpp"

namespace {

void Usage(std::FILE* f) {
  std::fprintf(f,
               "usage: odom_mapper [--config FILE] [--out DIR] [--url LCM_URL] [--idle-exit S]\n"
               "  Maps LIDAR_SCAN at the WHEEL_ODOM pose of each scan (no correction), publishes\n"
               "  GRID_ODOM and HEARTBEAT, and on SIGINT/SIGTERM (or after S seconds without\n"
               "  messages once data has arrived) writes DIR/odom_map.{pgm,yaml,png},\n"
               "  DIR/odom_trajectory.{txt,png} (default DIR: out/odom); while mapping, on a\n"
               "  MAP_SAVE request (omni save-map) too. DIR is this process's while it runs:\n"
               "  another process writing it is refused.\n");
}

}  // namespace

int main(int argc, char** argv) {
  omni::MapperArgs m;
  m.out = "out/odom";
  omni::ArgReader args(argc, argv, "odom_mapper", Usage);
  while (args.Next()) {
    if (omni::ReadMapperArg(args, &m)) continue;
    args.Unknown();
  }
  std::string config_path = m.config, out_dir = m.out, url = m.url;
  const double idle_exit_s = m.idle_exit_s;
  omni::SetLogProcessName("odom_mapper");
  omni::odom_mapper::OdomMapperOptions opt;
  if (!config_path.empty()) {
    auto reader = omni::ConfigReader::FromFile(config_path);
    if (!reader.ok()) {
      std::fprintf(stderr, "odom_mapper: %s\n", reader.error().message.c_str());
      return 1;
    }
    auto loaded = omni::odom_mapper::OdomMapperOptions::Load(*reader);
    if (!loaded.ok()) {
      std::fprintf(stderr, "odom_mapper: bad config:\n%s\n", loaded.error().message.c_str());
      return 1;
    }
    opt = *loaded;
  }
  // The files write_maps writes (below), moved aside from a previous run.
  const auto out_lock =
      omni::io::ClaimOutputFolder(out_dir, "odom_mapper",
                                  {"odom_map.pgm", "odom_map.yaml", "odom_map.png",
                                   "odom_trajectory.txt", "odom_trajectory.png"});
  if (!out_lock.ok()) {
    std::fprintf(stderr, "odom_mapper: %s\n", out_lock.error().message.c_str());
    return 1;
  }
  auto bus_or = omni::bus::Bus::Create(url);
  if (!bus_or.ok()) {
    std::fprintf(stderr, "odom_mapper: %s\n", bus_or.error().message.c_str());
    return 1;
  }
  auto& bus = **bus_or;
  omni::odom_mapper::OdomMapper mapper(opt);
  omni::SystemClock clock;
  omni::OdometryRestartBridge odom_restarts;  // a restarted base bridge's odometry, laid on
  bus.Subscribe<omni::odometry_t>(opt.odom_channel, [&](const omni::odometry_t& m, int64_t) {
    if (!mapper.AddOdometry(m.utime,
                            odom_restarts.Take(m.seq, omni::Pose2(m.x_m, m.y_m, m.yaw_rad))))
      ++bus.counters().drops;
  });
  bus.Subscribe<omni::laser_scan_t>(opt.scan_channel, [&](const omni::laser_scan_t& m, int64_t) {
    if (!mapper.AddScan(omni::odom_mapper::ScanFromMessage(m))) ++bus.counters().drops;
  });
  omni::bus::Heartbeat hb(&bus, "odom_mapper", &clock);
  const auto& c = mapper.counters();
  hb.AddCounter("scans_in", [&] { return c.scans_in; });
  hb.AddCounter("odom_restarts", [&] { return odom_restarts.restarts(); });
  hb.AddCounter("scans_bad_geometry", [&] { return c.scans_bad_geometry; });
  hb.AddCounter("scans_mapped", [&] { return c.scans_mapped; });
  hb.AddCounter("scans_no_pose", [&] { return c.scans_no_pose; });
  hb.AddCounter("scans_too_few_beams", [&] { return c.scans_too_few_beams; });
  hb.AddCounter("invalid_beams", [&] { return c.invalid_beams; });
  hb.AddCounter("scans_lost", [&] { return c.scans_lost; });
  hb.AddCounter("odom_out_of_order", [&] { return c.odom_out_of_order; });
  hb.AddCounter("odom_invalid", [&] { return c.odom_invalid; });
  hb.AddCounter("odom_jumps", [&] { return c.odom_jumps; });
  hb.AddCounter("time_rebases", [&] { return c.time_rebases; });
  hb.AddCounter("beams_beyond_grid_cap", [&] { return c.beams_beyond_grid_cap; });
  hb.AddCounter("scans_duplicate", [&] { return c.scans_duplicate; });
  hb.AddCounter("sweeps_corrected", [&] { return c.sweeps_corrected; });
  hb.AddCounter("sweeps_uncorrected", [&] { return c.sweeps_uncorrected; });
  hb.SetState(omni::heartbeat_t::STATE_OK, "mapping at raw odometry");
  omni::MappingHealth health;  // DEGRADED while scans come in without odometry
  // DIR/odom_map.{pgm,yaml,png} and DIR/odom_trajectory.{txt,png}, at exit and on a MAP_SAVE
  // request while mapping.
  auto write_maps = [&](const omni::io::GridMap& map, const std::string& dir) -> omni::Status {
    const std::string base = dir + "/odom_map";
    omni::Status s = omni::io::WriteMapServer(map, base);
    if (s.ok()) s = omni::io::WritePng(base + ".png", omni::io::RenderGrid(map, {}, 1));
    omni::io::Polyline line;
    std::vector<omni::io::TrajectoryEntry> entries;
    for (size_t i = 0; i < mapper.trajectory().size(); ++i) {
      const auto& m = mapper.trajectory()[i];
      line.poses.push_back(m.base_pose);
      const int64_t index = m.seq >= 0 ? m.seq : static_cast<int64_t>(i);
      entries.push_back(omni::io::MakeEntry2D(index, omni::UtimeToSeconds(m.utime), m.base_pose));
    }
    // Drawn at 2 pixels per cell up to 4 M cells; beyond, at 1 (the image takes 6 bytes per
    // pixel: a 20 M-cell map at 2x needed about 0.5 GB for it alone).
    const int scale = static_cast<int64_t>(map.width) * map.height <= (int64_t{4} << 20) ? 2 : 1;
    if (s.ok())
      s = omni::io::WritePng(dir + "/odom_trajectory.png",
                             omni::io::RenderGrid(map, {line}, scale));
    if (s.ok())
      s = omni::io::WriteTrajectory2D(
          dir + "/odom_trajectory.txt", entries,
          "scan_seq timestamp x y theta (raw wheel odometry at each mapped scan)");
    return s;
  };
  omni::bus::MapSaveService saver(&bus, "odom_mapper", out_dir, &clock, &hb);
  omni::bus::InstallStopSignals();
  omni::FixMallocThresholds();  // large buffers go back to the system when freed
  LOG_INFO << "listening on " << opt.scan_channel << " + " << opt.odom_channel << " (bus "
           << (url.empty() ? "default" : url) << ")";
  // The callbacks map as messages arrive; the loop only ticks and publishes.
  int64_t last_grid_us = omni::MonotonicMicros();
  omni::bus::NodeLoopOptions loop;
  loop.idle_exit_s = idle_exit_s;
  const omni::bus::LoopEnd end = omni::bus::RunNodeLoop(
      bus, loop, [] { return 0; },
      [&] {
        health.Report(clock.NowUtime(), c.scans_in, c.scans_no_pose,
                      c.scans_too_few_beams + c.scans_bad_geometry, &hb, "mapping at raw odometry");
        hb.Tick();
        saver.Serve([&](const std::string& dir) {
          const auto map = mapper.Map();
          if (map.width == 0)
            return omni::Status(
                omni::MakeError(omni::ErrorCode::kNotFound, "no scan was mapped yet"));
          return write_maps(map, dir);
        });
        const int64_t now = omni::MonotonicMicros();
        if (now - last_grid_us > static_cast<int64_t>(opt.publish_interval_s * 1e6) &&
            c.scans_mapped > 0) {
          omni::bus::PublishGrid(bus, opt.grid_channel, mapper.Map(), clock.NowUtime(), "odom");
          last_grid_us = now;
        }
      });
  LOG_INFO << "stopping (" << omni::bus::LoopEndName(end) << "); writing the map";
  hb.SetState(omni::heartbeat_t::STATE_STOPPING, "writing map");
  hb.Tick(true);
  const auto map = mapper.Map();
  if (map.width == 0) {
    std::fprintf(
        stderr,
        "odom_mapper: no scan was mapped (scans in %lld, without pose %lld, too few beams %lld)\n",
        static_cast<long long>(c.scans_in), static_cast<long long>(c.scans_no_pose),
        static_cast<long long>(c.scans_too_few_beams));
    return omni::bus::NothingToWriteExit(end, c.scans_in);
  }
  omni::bus::PublishGrid(bus, opt.grid_channel, map, clock.NowUtime(), "odom");
  const omni::Status s = write_maps(map, out_dir);
  if (!s.ok()) {
    std::fprintf(stderr, "odom_mapper: %s\n", s.message().c_str());
    return 1;
  }
  std::printf(
      "odom_mapper: mapped %lld of %lld scans received (%lld lost on the bus, %lld without pose, "
      "%lld too few beams, %lld invalid beams, %lld duplicates, %lld decode errors; odometry: "
      "%lld jumps bridged, %lld future stamps dropped; %lld beams beyond the grid's cap); map "
      "%dx%d cells at %.3f m -> %s.{pgm,yaml,png}, %s/odom_trajectory.{txt,png}\n",
      static_cast<long long>(c.scans_mapped), static_cast<long long>(c.scans_in),
      static_cast<long long>(c.scans_lost), static_cast<long long>(c.scans_no_pose),
      static_cast<long long>(c.scans_too_few_beams), static_cast<long long>(c.invalid_beams),
      static_cast<long long>(c.scans_duplicate),
      static_cast<long long>(bus.counters().decode_errors.load()),
      static_cast<long long>(c.odom_jumps), static_cast<long long>(c.time_rebases),
      static_cast<long long>(c.beams_beyond_grid_cap), map.width, map.height, map.resolution_m,
      (out_dir + "/odom_map").c_str(), out_dir.c_str());
  return 0;
}
