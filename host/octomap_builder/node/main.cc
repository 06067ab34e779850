// octomap_builder process: DEPTH + POSE_<source> -> OCTOMAP, GRID_OCTO; map files at an
// interval and on exit.
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "omni/bus/map_save.h"
#include "omni/bus/node_loop.h"
#include "omni/common/cli.h"
#include "omni/common/log.h"
#include "omni/common/malloc_setup.h"
#include "omni/heartbeat_t.hpp"
#include "omni/io/previous_outputs.h"
#include "omni/octomap_builder/depth_io.h"
#include "omni/octomap_builder/octomap_node.h"

namespace {

volatile std::sig_atomic_t g_stop = 0;
volatile std::sig_atomic_t g_write_cloud = 0;
void OnSignal(int) { g_stop = 1; }
void OnCloudRequest(int) { g_write_cloud = 1; }

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: octomap_builder [--config FILE] [--out DIR] [--url LCM_URL] [--idle-exit S]\n"
      "  Inserts DEPTH frames, posed by the 2D SLAM's POSE_<source> (interpolated, camera\n"
      "  mount from the config), into an OctoMap; publishes OCTOMAP and GRID_OCTO and a\n"
      "  HEARTBEAT with frame counters; writes DIR/map.{bt,ot}, DIR/grid.{pgm,yaml,png},\n"
      "  DIR/view.png (with color.enabled also DIR/map_color.ot, a ColorOcTree coloured from\n"
      "  the RGB frames, and DIR/view_color.png) every save interval, on a MAP_SAVE request\n"
      "  (omni save-map) and on SIGINT/SIGTERM (or after S seconds without messages once data\n"
      "  has arrived). Default config: config/octomap_builder.yaml in the current folder, else\n"
      "  in the checkout this binary was built in; DIR overrides output.dir.\n");
}

}  // namespace

int main(int argc, char** argv) {
  omni::MapperArgs m;
  m.out = "";
  omni::ArgReader args(argc, argv, "octomap_builder", Usage);
  while (args.Next()) {
    if (omni::ReadMapperArg(args, &m)) continue;
    args.Unknown();
  }
  std::string config_path = m.config, out_dir = m.out, url = m.url;
  if (config_path.empty()) {
    // The shipped file, from the current folder (a checkout) or else from the checkout this
    // binary was built from, so it starts from any folder.
    namespace fs = std::filesystem;
    const fs::path rel = "config/octomap_builder.yaml";
    const fs::path shipped = fs::path(OMNI_SOURCE_DIR) / rel;
    std::error_code ec;
    config_path = fs::exists(rel, ec) || !fs::exists(shipped, ec) ? rel.string() : shipped.string();
  }
  const double idle_exit_s = m.idle_exit_s;
  omni::SetLogProcessName("octomap_builder");
  auto opt = omni::octo::OctomapBuilderOptions::LoadFile(config_path);
  if (!opt.ok()) {
    std::fprintf(stderr, "octomap_builder: bad config:\n%s\n", opt.error().message.c_str());
    return 1;
  }
  if (!out_dir.empty()) opt->out_dir = out_dir;
  const auto out_lock = omni::io::ClaimOutputFolder(opt->out_dir, "octomap_builder",
                                                    omni::octo::OctomapNode::OutputFiles());
  if (!out_lock.ok()) {
    std::fprintf(stderr, "octomap_builder: %s\n", out_lock.error().message.c_str());
    return 1;
  }
  auto bus_or = omni::bus::Bus::Create(url);
  if (!bus_or.ok()) {
    std::fprintf(stderr, "octomap_builder: %s\n", bus_or.error().message.c_str());
    return 1;
  }
  omni::SystemClock clock;
  omni::octo::OctomapNode node(bus_or->get(), *opt, &clock);
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  omni::bus::AlsoStopOnHangup(OnSignal);  // and SIGPIPE ignored (node_loop.h)
  omni::FixMallocThresholds();            // large buffers go back to the system when freed
  std::signal(SIGUSR1, OnCloudRequest);
  omni::bus::MapSaveService saver(bus_or->get(), "octomap_builder", opt->out_dir, &clock,
                                  &node.heartbeat());
  LOG_INFO << "listening on " << opt->depth_channel << " + " << opt->PoseChannel()
           << (opt->color ? " + " + opt->color_channel : std::string())
           << (opt->repose.enabled ? " + " + opt->TrajectoryChannel() + " (repose)"
                                   : std::string());
  int64_t last_msg_us = 0;
  while (!g_stop) {
    int r = (*bus_or)->HandleTimeout(50);
    // Take what else is waiting (one message per call) before the tick inserts frames or runs a
    // rebuild slice, so a slice follows every burst rather than every message.
    for (int i = 0; r > 0 && i < 20; ++i) {
      const int more = (*bus_or)->HandleTimeout(0);
      if (more <= 0) {
        if (more < 0) r = more;
        break;
      }
    }
    if (r < 0 && !g_stop) {
      LOG_WARN << "bus ended or failed; writing the map";
      break;
    }
    const int64_t now = omni::MonotonicMicros();
    if (r > 0) last_msg_us = now;
    node.Tick(now);
    saver.Serve([&](const std::string& dir) { return node.SaveOutputs(dir); });
    if (g_write_cloud) {
      g_write_cloud = 0;
      if (!opt->keep_cloud) {
        LOG_WARN << "SIGUSR1: no cloud kept (set output.keep_cloud: true)";
      } else {
        const auto cloud = node.pipeline().builder().AggregateCloud();
        omni::Status s = omni::octo::WritePcd(opt->out_dir + "/map.pcd", cloud, true);
        if (s.ok()) {
          LOG_INFO << "wrote " << cloud.size() << " points to " << opt->out_dir << "/map.pcd";
        } else {
          LOG_WARN << s.message();
        }
      }
    }
    if (idle_exit_s > 0 && last_msg_us > 0 &&
        now - last_msg_us > static_cast<int64_t>(idle_exit_s * 1e6))
      break;
  }
  node.heartbeat().SetState(omni::heartbeat_t::STATE_STOPPING, "writing map");
  node.heartbeat().Tick(true);
  node.Tick(omni::MonotonicMicros());
  const auto& pc = node.pipeline().poser_counters();
  const auto& c = node.pipeline().counters();
  // No more input: frames still waiting for a pose are counted as dropped without one (they
  // used to vanish uncounted), those waiting for a colour partner go in with what has come.
  node.pipeline().FinishInput();
  // A rebuild asked for or under way: the saved map is at the newest trajectory. A rebuild of a
  // large store takes tens of seconds (past a supervisor's stop grace), so the live tree is
  // written before it.
  omni::Status s = omni::Status::Ok();
  if (opt->repose.enabled && c.frames_inserted > 0) {
    s = node.SaveOutputs();
    if (!s.ok()) {
      LOG_WARN << s.message();
    }
  }
  node.pipeline().FinishRepose();
  s = node.SaveOutputs();
  std::printf(
      "octomap_builder: %lld frames in (%lld lost before arriving), %lld posed, %lld inserted, "
      "%lld dropped without pose, %lld dropped (queue), %lld out of order, %lld decode errors -> "
      "%s/map.{bt,ot}\n",
      static_cast<long long>(pc.frames_in), static_cast<long long>(node.depth_frames_lost()),
      static_cast<long long>(pc.frames_posed), static_cast<long long>(c.frames_inserted),
      static_cast<long long>(pc.frames_dropped_no_pose),
      static_cast<long long>(pc.frames_dropped_queue),
      static_cast<long long>(pc.frames_out_of_order + pc.poses_out_of_order),
      static_cast<long long>(node.depth_decode_errors()), opt->out_dir.c_str());
  if (opt->color)
    std::printf(
        "octomap_builder: %lld colour frames in, %lld frames coloured, %lld uncoloured, %lld "
        "colour errors -> %s/map_color.ot\n",
        static_cast<long long>(c.color_frames_in), static_cast<long long>(c.frames_colored),
        static_cast<long long>(c.frames_uncolored),
        static_cast<long long>(node.color_decode_errors() + c.color_invalid), opt->out_dir.c_str());
  if (opt->repose.enabled)
    std::printf(
        "octomap_builder: repose: %lld trajectories (%lld rejected), %lld keyframes (%lld "
        "points; %lld retired as revisited), %lld rebuilds (the last %.2f s, for a shift of %.3f "
        "m)%s\n",
        static_cast<long long>(c.trajectories_in + node.trajectories_rejected()),
        static_cast<long long>(c.trajectories_invalid + node.trajectories_rejected()),
        static_cast<long long>(c.keyframes), static_cast<long long>(c.keyframe_points),
        static_cast<long long>(c.keyframes_retired), static_cast<long long>(c.rebuilds_done),
        c.last_rebuild_us * 1e-6, c.last_rebuild_shift_mm * 1e-3,
        c.repose_stopped ? "; stopped at repose.max_points" : "");
  if (c.frames_inserted == 0) {  // a stop with nothing mapped is no failure; no empty map
    std::printf("octomap_builder: %s\n", s.message().c_str());
    return 0;
  }
  if (!s.ok()) {
    std::fprintf(stderr, "octomap_builder: %s\n", s.message().c_str());
    return 1;
  }
  return 0;
}
