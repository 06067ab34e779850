// map_fusion process: GRID_PG + GRID_RBPF + GRID_OCTO (configurable) -> GRID_FUSED, and the fused
// map on exit; or, with --fuse, the same fusion of map files without the bus.

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/bus/map_save.h"
#include "omni/bus/node_loop.h"
#include "omni/common/cli.h"
#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/io/previous_outputs.h"
#include "omni/map_fusion/map_fusion_node.h"

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: map_fusion [--config FILE] [--out DIR] [--url LCM_URL] [--idle-exit S]\n"
      "       map_fusion --fuse MAP.yaml MAP.yaml [MAP.yaml...] [--base N] [--out DIR]\n"
      "                  [--config FILE]\n"
      "  SLAMfusion: aligns the mappers' occupancy grids onto one (rotation + translation,\n"
      "  coarse-to-fine) and decides each cell by majority vote, ties by the `tie` rule.\n"
      "  On the bus: fuses the latest GRID_PG, GRID_RBPF and GRID_OCTO (config: grid_channels)\n"
      "  every fuse_interval_s when one changed, publishes GRID_FUSED and HEARTBEAT, and on\n"
      "  SIGINT/SIGTERM (or after S idle seconds) writes DIR/fused_map.{pgm,yaml,png} and\n"
      "  DIR/fusion.json (alignment and vote counts per map; default DIR: out/fusion); on a\n"
      "  MAP_SAVE request (omni save-map) fuses and writes them while running. DIR is this\n"
      "  process's while it runs: another process writing it is refused.\n"
      "  --fuse: the same on ROS map_server files (e.g. the mappers' map.yaml); --base N: the\n"
      "  N-th file (1-based) is the base, the others are aligned onto it (default: the first).\n");
}

int Fail(const std::string& msg) {
  std::fprintf(stderr, "map_fusion: %s\n", msg.c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  omni::MapperArgs m;
  m.out = "out/fusion";
  std::vector<std::string> files;
  bool offline = false;
  int base_index = 0;
  omni::ArgReader args(argc, argv, "map_fusion", Usage);
  while (args.Next()) {
    if (omni::ReadMapperArg(args, &m)) continue;
    if (args.Is("--base")) {
      base_index = static_cast<int>(args.Integer(1, 1000));
    } else if (args.Is("--fuse")) {
      offline = true;
    } else if (offline && !args.arg().empty() && args.arg()[0] != '-') {
      files.push_back(args.arg());
    } else {
      args.Unknown();
    }
  }
  if (base_index > 0 && !offline)
    args.Fail("--base N chooses among --fuse's files; on the bus, set base: in the config");
  std::string config_path = m.config, out_dir = m.out, url = m.url;
  const double idle_exit_s = m.idle_exit_s;
  omni::SetLogProcessName("map_fusion");
  omni::map_fusion::FusionOptions opt;
  if (!config_path.empty()) {
    auto reader = omni::ConfigReader::FromFile(config_path);
    if (!reader.ok()) return Fail(reader.error().message);
    auto loaded = omni::map_fusion::FusionOptions::Load(*reader);
    if (!loaded.ok()) return Fail("bad config:\n" + loaded.error().message);
    opt = *loaded;
  }
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) return Fail("cannot create output folder '" + out_dir + "': " + ec.message());
  // Held to the end, offline too: a fusion written into a running process's folder would mix.
  const auto out_lock = omni::io::OutputFolderLock::Take(out_dir, "map_fusion");
  if (!out_lock.ok()) return Fail(out_lock.error().message);

  if (offline) {
    if (files.size() < 2) {
      std::fprintf(stderr, "map_fusion: --fuse needs at least two map files\n");
      return 2;
    }
    if (base_index < 0 || base_index > static_cast<int>(files.size())) {
      std::fprintf(stderr, "map_fusion: --base must be between 1 and %zu\n", files.size());
      return 2;
    }
    std::vector<omni::map_fusion::SourceMap> maps;
    for (const auto& f : files) {
      auto m = omni::io::ReadMapServer(f);
      if (!m.ok()) return Fail(m.error().message);
      maps.push_back({f, std::move(*m)});
    }
    opt.base = base_index > 0 ? files[static_cast<size_t>(base_index - 1)] : "";
    auto r = omni::map_fusion::Fuse(maps, opt);
    if (!r.ok()) return Fail(r.error().message);
    const std::string base = out_dir + "/fused_map";
    if (const omni::Status s = omni::map_fusion::WriteFusionOutputs(*r, out_dir); !s.ok())
      return Fail(s.message());
    for (const auto& src : r->sources)
      std::printf(
          "map_fusion: %s: %s, rotation %.4f rad, shift (%.3f, %.3f) m, overlap %.2f, conflicts "
          "%.3f (its walls on the base's free space %.3f, the base's on its %.3f)%s%s\n",
          src.name.c_str(), src.used ? "used" : "left out", src.alignment.rotation_rad,
          src.alignment.dx_m, src.alignment.dy_m, src.overlap_fraction, src.conflict_fraction,
          src.walls_on_base_free, src.base_walls_on_free, src.reason.empty() ? "" : ": ",
          src.reason.c_str());
    std::printf(
        "map_fusion: fused %zu maps onto %s: %zu cells unanimous, %zu by majority, %zu ties -> "
        "%s.{pgm,yaml,png}, %s/fusion.json\n",
        r->maps_used, r->base.c_str(), r->unanimous, r->majority, r->ties, base.c_str(),
        out_dir.c_str());
    return 0;
  }

  if (omni::Status s = opt.ValidateForBus(); !s.ok()) return Fail("bad config: " + s.message());
  omni::io::MovePreviousRunAside(out_dir, omni::map_fusion::MapFusionNode::OutputFiles());
  auto bus_or = omni::bus::Bus::Create(url);
  if (!bus_or.ok()) return Fail(bus_or.error().message);
  auto& bus = **bus_or;
  omni::SystemClock clock;
  omni::map_fusion::MapFusionNode node(&bus, opt, &clock);
  omni::bus::InstallStopSignals();
  omni::FixMallocThresholds();  // large buffers go back to the system when freed
  std::string chans;
  for (const auto& c : opt.grid_channels) chans += (chans.empty() ? "" : " + ") + c;
  LOG_INFO << "listening on " << chans << " (bus " << (url.empty() ? "default" : url) << ")";
  omni::bus::MapSaveService saver(&bus, "map_fusion", out_dir, &clock, &node.heartbeat());
  omni::bus::NodeLoopOptions loop;
  loop.idle_exit_s = idle_exit_s;
  const omni::bus::LoopEnd end = omni::bus::RunNodeLoop(
      bus, loop, [] { return 0; },
      [&] {
        node.Tick();
        saver.Serve([&](const std::string& dir) { return node.WriteOutputs(dir); });
      });
  LOG_INFO << "stopping (" << omni::bus::LoopEndName(end) << "); fusing and writing the map";
  node.SetStopping();  // a fusion still running is finished (and published), heartbeating
  node.heartbeat().Tick(true);
  const omni::Status s = node.WriteOutputs(out_dir);
  if (!s.ok() && omni::bus::NothingToWriteExit(end, node.grids_in()) == 0) {
    std::fprintf(stderr, "map_fusion: %s (grids in %lld, rejected %lld); stopped before a fusion\n",
                 s.message().c_str(), static_cast<long long>(node.grids_in()),
                 static_cast<long long>(node.grids_rejected()));
    return 0;
  }
  if (!s.ok())
    return Fail(s.message() + " (grids in " + std::to_string(node.grids_in()) + ", rejected " +
                std::to_string(node.grids_rejected()) + ")");
  const auto& r = *node.last();
  std::printf(
      "map_fusion: %lld grids in (%lld rejected, %lld decode errors), %lld fusions (%lld failed); "
      "last: %zu maps onto %s (%zu unanimous, %zu majority, %zu ties) -> %s/fused_map."
      "{pgm,yaml,png}, %s/fusion.json\n",
      static_cast<long long>(node.grids_in()), static_cast<long long>(node.grids_rejected()),
      static_cast<long long>(bus.counters().decode_errors.load()),
      static_cast<long long>(node.fusions()), static_cast<long long>(node.fusion_failures()),
      r.maps_used, r.base.c_str(), r.unanimous, r.majority, r.ties, out_dir.c_str(),
      out_dir.c_str());
  return 0;
}
