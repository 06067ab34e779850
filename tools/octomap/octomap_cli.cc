// omni-octomap: `./omni octomap build INPUT --out DIR [--resolution M] ...`
//
// INPUT is either an LCM log (DEPTH frames posed by POSE_<source>, as the octomap_builder
// process would see them) or a folder of depth images with camera poses (the layout of
// ../shared/datasets/rgbd/*: depth/N.png|pgm for N = 1.., pose.txt "tx ty tz qx qy qz qw"
// camera-to-world per line; intrinsics and depth scale as options or in INPUT/intrinsics.yaml).
// Writes DIR/map.bt, DIR/map.ot, DIR/grid.{pgm,yaml,png}, DIR/view.png (and DIR/map.pcd
// with --pcd). With --color (or color.enabled in the config) also DIR/map_color.ot, a
// ColorOcTree coloured from color/N.png (registered to the depth image) or the log's RGB
// frames, and DIR/view_color.png.
//
// `./omni octomap extract LOG --out DIR` takes the newest readable OCTOMAP and OCTOMAP_COLOR
// messages out of a recorded LCM log (lcm-logger on the robot) and writes them as map files.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/color_image_t.hpp"
#include "omni/common/config.h"
#include "omni/common/time.h"
#include "omni/depth_image_t.hpp"
#include "omni/io/grid.h"
#include "omni/io/lcm_log.h"
#include "omni/io/trajectory_io.h"
#include "omni/octomap_builder/depth_io.h"
#include "omni/octomap_builder/map_output.h"
#include "omni/octomap_builder/octomap_builder.h"
#include "omni/octomap_builder/octomap_node.h"
#include "omni/octomap_t.hpp"
#include "omni/pose2d_t.hpp"
#include "omni/trajectory_t.hpp"

namespace fs = std::filesystem;
using omni::octo::DepthImage;
using omni::octo::OctomapBuilderOptions;

namespace {

void Usage(std::FILE* f) {
  std::fprintf(
      f,
      "usage: omni-octomap build INPUT --out DIR [options]\n"
      "  INPUT: an LCM log with DEPTH and POSE_<source> (camera mount, ranges, grid band from\n"
      "         --config), or a folder with depth/N.png|pgm and pose.txt (camera-to-world\n"
      "         \"tx ty tz qx qy qz qw\" per frame) and intrinsics given below or in\n"
      "         INPUT/intrinsics.yaml (fx, fy, cx, cy, depth_scale).\n"
      "  Writes DIR/map.bt, DIR/map.ot, DIR/grid.pgm/.yaml/.png (the --grid-min-z..--grid-max-z\n"
      "  band, map frame z), DIR/view.png (top view) and with --pcd DIR/map.pcd.\n"
      "options:\n"
      "  --config FILE        octomap_builder YAML (default config/octomap_builder.yaml if "
      "present)\n"
      "  --resolution M       leaf size (default from config, 0.05)\n"
      "  --max-range M        ray length limit, < 0 unlimited\n"
      "  --min-depth M --max-depth M --stride N --voxel-filter M\n"
      "  --exact              no discretize: the same key sets as "
      "insertPointCloud(discretize=false)\n"
      "  --discretize         one ray per leaf-sized voxel (insertPointCloud(discretize=true))\n"
      "  --subvoxel N         one ray per (resolution/N) cell to its centroid (config subvoxel;\n"
      "                       0 = every point)\n"
      "  --threads N          threads for the key sets (default 2)\n"
      "  --fx F --fy F --cx F --cy F --depth-scale S   intrinsics for a folder INPUT\n"
      "  --grid-min-z M --grid-max-z M                  height band of the 2D grid\n"
      "  --up x|y|z|-x|-y|-z  the map's up axis for the grid and view (default z; the camera-\n"
      "                       posed rgbd datasets have -y)\n"
      "  --source rbpf|pg     pose channel for a log INPUT (POSE_RBPF / POSE_PG)\n"
      "  --poses TRAJ.txt     for a log INPUT: pose the frames by this trajectory (robot in the\n"
      "                       map; the indexed form omni slam writes, or TUM) instead of the\n"
      "                       log's pose channel, e.g. a mapper's final trajectory.txt: the 3D\n"
      "                       map at the corrected poses, not the ones published live\n"
      "  --repose, --no-repose  for a log INPUT: re-pose keyframes by the source's whole\n"
      "                       trajectories in the log (TRAJECTORY_RBPF / TRAJECTORY_PG), as the\n"
      "                       process does (default: the config's repose.enabled, off with\n"
      "                       --poses); the last trajectory in the log is applied at the end\n"
      "  --pcd                also write the aggregate point cloud\n"
      "  --color              also build a ColorOcTree: DIR/map_color.ot, DIR/view_color.png;\n"
      "                       a folder needs color/N.png (same camera and size as depth/N),\n"
      "                       a log the colour channel (RGB; color_image_t RGB8 or JPEG)\n"
      "\n"
      "usage: omni-octomap extract LOG --out DIR [--channel CH]... [--up AXIS]\n"
      "  The newest readable octomap_t of each tree type in a recorded LCM log (channels OCTOMAP\n"
      "  and OCTOMAP_COLOR unless --channel is given): an OcTree to DIR/map.bt or DIR/map.ot (as\n"
      "  it was sent) and DIR/view.png, a ColorOcTree to DIR/map_color.ot and\n"
      "  DIR/view_color.png. Undecodable messages and trees whose bytes do not read are counted\n"
      "  and skipped (an older readable one is used); no readable tree at all is an error.\n");
}

int Fail(const std::string& msg);

// `omni-octomap extract LOG --out DIR [--channel CH]... [--up AXIS]`.
int Extract(int argc, char** argv) {
  const std::string log = argv[2];
  std::string out;
  std::vector<std::string> channels;
  omni::octo::UpAxis up;
  for (int i = 3; i < argc; ++i) {
    const std::string s = argv[i];
    if ((s == "--out" || s == "--channel" || s == "--up") && i + 1 < argc) {
      const std::string v = argv[++i];
      if (s == "--out") out = v;
      if (s == "--channel") channels.push_back(v);
      if (s == "--up" && !omni::octo::UpAxis::Parse(v, &up))
        return Fail("--up must be one of x y z -x -y -z");
    } else {
      std::fprintf(stderr, "omni-octomap extract: unknown option or missing value '%s'\n",
                   s.c_str());
      Usage(stderr);
      return 2;
    }
  }
  if (out.empty()) return Fail("extract: --out DIR is required");
  if (channels.empty()) channels = {"OCTOMAP", "OCTOMAP_COLOR"};
  auto reader = omni::io::LcmLogReader::Open(log);
  if (!reader.ok()) return Fail(reader.error().message);
  // The newest readable message of each tree type; only its bytes' layout is checked here, the
  // tree is built once at the end.
  struct Newest {
    omni::octomap_t msg;
    std::string channel;
    bool found = false;
  };
  Newest plain, color;
  long long messages = 0, undecodable = 0, unreadable = 0;
  omni::io::LcmLogEvent ev;
  for (;;) {
    auto more = reader->Next(&ev, /*resync=*/true);
    if (!more.ok()) {
      if (!reader->truncated_tail()) return Fail(more.error().message);  // a failed read
      std::fprintf(stderr, "omni-octomap extract: %s (reading stops there)\n",
                   more.error().message.c_str());
      break;
    }
    if (!*more) break;
    if (std::find(channels.begin(), channels.end(), ev.channel) == channels.end()) continue;
    ++messages;
    omni::octomap_t m;
    const int size = static_cast<int>(ev.data.size());
    // DecodeMessage: lcm-gen's decoder throws on some corrupt length fields.
    if (omni::bus::DecodeMessage(&m, ev.data.data(), size) != size) {
      ++undecodable;
      continue;
    }
    // Checked in place (no copy): every message of a long log passes through here.
    const std::string_view bytes(reinterpret_cast<const char*>(m.data.data()), m.data.size());
    if (const std::string bad = omni::octo::CheckTreeBytes(bytes, m.binary, m.tree_type);
        !bad.empty()) {
      ++unreadable;
      std::fprintf(stderr, "omni-octomap extract: %s message at byte %llu: %s\n",
                   ev.channel.c_str(), static_cast<unsigned long long>(ev.offset), bad.c_str());
      continue;
    }
    Newest& n = m.tree_type == "ColorOcTree" ? color : plain;
    n.msg = std::move(m);
    n.channel = ev.channel;
    n.found = true;
  }
  std::printf(
      "omni-octomap extract: %lld messages on %zu channels, %lld undecodable, %lld "
      "unreadable trees, %llu bytes skipped\n",
      messages, channels.size(), undecodable, unreadable,
      static_cast<unsigned long long>(reader->skipped_bytes()));
  if (!plain.found && !color.found)
    return Fail("extract: no readable octomap_t in " + log + " on the channels given");
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) return Fail("cannot create " + out + ": " + ec.message());
  if (plain.found) {
    const std::string bytes(plain.msg.data.begin(), plain.msg.data.end());
    auto tree = omni::octo::ParseTree(bytes, plain.msg.binary, plain.channel);
    if (!tree.ok()) return Fail(tree.error().message);
    const std::string file = out + (plain.msg.binary ? "/map.bt" : "/map.ot");
    if (auto s = omni::octo::WriteFileAtomic(file, bytes); !s.ok()) return Fail(s.message());
    if (auto s = omni::io::WritePng(out + "/view.png", omni::octo::RenderTopView(**tree, up));
        !s.ok())
      return Fail(s.message());
    std::printf("%s: OcTree of %zu nodes at %g m (utime %lld, source %s) -> %s, %s/view.png\n",
                plain.channel.c_str(), (*tree)->size(), (*tree)->getResolution(),
                static_cast<long long>(plain.msg.utime), plain.msg.source.c_str(), file.c_str(),
                out.c_str());
  }
  if (color.found) {
    const std::string bytes(color.msg.data.begin(), color.msg.data.end());
    auto tree = omni::octo::ParseColorTree(bytes, color.channel);
    if (!tree.ok()) return Fail(tree.error().message);
    if (auto s = omni::octo::WriteFileAtomic(out + "/map_color.ot", bytes); !s.ok())
      return Fail(s.message());
    if (auto s =
            omni::io::WritePng(out + "/view_color.png", omni::octo::RenderTopViewColor(**tree, up));
        !s.ok())
      return Fail(s.message());
    std::printf(
        "%s: ColorOcTree of %zu nodes at %g m (utime %lld) -> %s/map_color.ot, "
        "%s/view_color.png\n",
        color.channel.c_str(), (*tree)->size(), (*tree)->getResolution(),
        static_cast<long long>(color.msg.utime), out.c_str(), out.c_str());
  }
  return 0;
}

struct Args {
  std::string input, out, config;
  std::vector<std::pair<std::string, std::string>> opts;  // option -> value, in order
  bool exact = false, discretize = false, pcd = false, color = false;
  int repose = -1;  // --repose 1, --no-repose 0, else the config's repose.enabled
};

std::string Get(const Args& a, const std::string& key, const std::string& def = "") {
  std::string v = def;
  for (const auto& [k, val] : a.opts)
    if (k == key) v = val;
  return v;
}

bool ParseDouble(const std::string& s, double* out) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (s.empty() || *end != '\0' || !std::isfinite(v)) return false;
  *out = v;
  return true;
}

int Fail(const std::string& msg) {
  std::fprintf(stderr, "omni-octomap: %s\n", msg.c_str());
  return 1;
}

omni::Status LoadIntrinsicsYaml(const std::string& path, omni::octo::DepthIntrinsics* k) {
  auto r = omni::ConfigReader::FromFile(path);
  if (!r.ok()) return r.error();
  r->Get("fx", &k->fx, omni::Required());
  r->Get("fy", &k->fy, omni::Required());
  r->Get("cx", &k->cx, omni::Required());
  r->Get("cy", &k->cy, omni::Required());
  r->Get("depth_scale", &k->depth_scale, omni::Required(), omni::Positive<double>());
  return r->Finish();
}

omni::Status WriteOutputs(const omni::octo::OctomapBuilder& b, const OctomapBuilderOptions& o,
                          const std::string& dir, bool pcd) {
  const octomap::OcTree& tree = b.tree();
  if (auto s = omni::octo::SaveTree(tree, dir + "/map"); !s.ok()) return s;
  // A grid that cannot be made (a map wider than a grid carries) is reported at the end; the
  // other outputs are written all the same.
  auto grid = omni::octo::ProjectToGrid(tree, o.grid);
  if (!grid.ok()) {
    std::fprintf(stderr, "omni-octomap: no grid written: %s\n", grid.error().message.c_str());
  } else if (grid->width > 0) {
    if (auto s = omni::io::WriteMapServer(*grid, dir + "/grid"); !s.ok()) return s;
    if (auto s = omni::io::WritePng(dir + "/grid.png", omni::io::RenderGrid(*grid)); !s.ok())
      return s;
  } else {
    std::fprintf(stderr,
                 "omni-octomap: nothing known in the grid band [%g, %g] m: no grid written\n",
                 o.grid.min_z_m, o.grid.max_z_m);
  }
  if (auto s = omni::io::WritePng(dir + "/view.png", omni::octo::RenderTopView(tree, o.grid.up));
      !s.ok())
    return s;
  if (const octomap::ColorOcTree* color = b.color_tree()) {
    if (auto s = omni::octo::SaveColorTree(*color, dir + "/map_color.ot"); !s.ok()) return s;
    if (auto s = omni::io::WritePng(dir + "/view_color.png",
                                    omni::octo::RenderTopViewColor(*color, o.grid.up));
        !s.ok())
      return s;
  }
  if (pcd) {
    if (auto s = omni::octo::WritePcd(dir + "/map.pcd", b.AggregateCloud(), true); !s.ok())
      return s;
  }
  if (!grid.ok())  // the exit status still says a grid is missing
    return omni::MakeError(grid.error().code, "no grid written (" + grid.error().message +
                                                  "); the tree and the other outputs are in " +
                                                  dir);
  return omni::Status::Ok();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
    Usage(stdout);
    return 0;
  }
  if (argc >= 3 && std::string(argv[1]) == "extract") return Extract(argc, argv);
  if (argc < 3 || std::string(argv[1]) != "build") {
    Usage(stderr);
    return 2;
  }
  Args a;
  a.input = argv[2];
  static const std::vector<std::string> kValued = {
      "--out",        "--config", "--resolution",   "--max-range",   "--min-depth",
      "--max-depth",  "--stride", "--voxel-filter", "--threads",     "--fx",
      "--fy",         "--cx",     "--cy",           "--depth-scale", "--grid-min-z",
      "--grid-max-z", "--source", "--up",           "--poses",       "--subvoxel"};
  for (int i = 3; i < argc; ++i) {
    const std::string s = argv[i];
    if (s == "--help" || s == "-h") {
      Usage(stdout);
      return 0;
    } else if (s == "--exact") {
      a.exact = true;
    } else if (s == "--discretize") {
      a.discretize = true;
    } else if (s == "--pcd") {
      a.pcd = true;
    } else if (s == "--color") {
      a.color = true;
    } else if (s == "--repose" || s == "--no-repose") {
      a.repose = s == "--repose" ? 1 : 0;
    } else if (std::find(kValued.begin(), kValued.end(), s) != kValued.end()) {
      if (i + 1 >= argc) return Fail(s + " needs a value");
      a.opts.emplace_back(s, argv[++i]);
    } else {
      std::fprintf(stderr, "omni-octomap: unknown option '%s'\n", s.c_str());
      Usage(stderr);
      return 2;
    }
  }
  a.out = Get(a, "--out");
  if (a.out.empty()) return Fail("--out DIR is required");

  // Options: config file, then command-line overrides.
  OctomapBuilderOptions o;
  std::string config = Get(a, "--config");
  if (config.empty() && fs::exists("config/octomap_builder.yaml"))
    config = "config/octomap_builder.yaml";
  if (!config.empty()) {
    auto loaded = OctomapBuilderOptions::LoadFile(config);
    if (!loaded.ok()) return Fail("bad config:\n" + loaded.error().message);
    o = *loaded;
  }
  struct Num {
    const char* flag;
    double* target;
  };
  double stride = o.depth.pixel_stride, threads = o.threads, subvoxel = o.subvoxel;
  const Num nums[] = {{"--resolution", &o.resolution_m},
                      {"--max-range", &o.max_range_m},
                      {"--min-depth", &o.depth.min_depth_m},
                      {"--max-depth", &o.depth.max_depth_m},
                      {"--stride", &stride},
                      {"--voxel-filter", &o.voxel_filter_m},
                      {"--threads", &threads},
                      {"--grid-min-z", &o.grid.min_z_m},
                      {"--grid-max-z", &o.grid.max_z_m},
                      {"--subvoxel", &subvoxel}};
  for (const auto& n : nums) {
    const std::string v = Get(a, n.flag);
    if (!v.empty() && !ParseDouble(v, n.target))
      return Fail(std::string(n.flag) + " '" + v + "' is not a number");
  }
  // Whole numbers in the config's ranges, checked before the cast (1e10 threads was undefined).
  auto whole = [](double v, double lo, double hi) {
    return v >= lo && v <= hi && v == std::floor(v);
  };
  if (!whole(stride, 1, 64)) return Fail("--stride must be a whole number in [1, 64]");
  if (!whole(threads, 1, 64)) return Fail("--threads must be a whole number in [1, 64]");
  if (!whole(subvoxel, 0, 16)) return Fail("--subvoxel must be in [0, 16]");
  if (!(o.max_range_m != 0 && std::isfinite(o.max_range_m)))
    return Fail("--max-range must be > 0, or < 0 for unlimited");
  if (!(o.voxel_filter_m == 0 || (o.voxel_filter_m >= 0.001 && o.voxel_filter_m <= 10)))
    return Fail("--voxel-filter must be 0 (off) or in [0.001, 10] m");
  o.depth.pixel_stride = static_cast<int>(stride);
  o.threads = static_cast<int>(threads);
  o.subvoxel = static_cast<int>(subvoxel);
  if (a.exact) {
    o.discretize = false;
    o.subvoxel = 0;
  }
  if (a.discretize) {
    o.discretize = true;
    o.subvoxel = 0;
  }
  o.keep_cloud = a.pcd;
  if (a.color) o.color = true;
  if (!(o.resolution_m >= 0.001 && o.resolution_m <= 10))
    return Fail("--resolution must be in [0.001, 10]");
  if (o.depth.pixel_stride < 1 || o.threads < 1) return Fail("--stride and --threads must be >= 1");
  if (o.subvoxel < 0 || o.subvoxel > 16) return Fail("--subvoxel must be in [0, 16]");
  if (!(o.depth.min_depth_m < o.depth.max_depth_m)) return Fail("need --min-depth < --max-depth");
  if (!(o.grid.min_z_m < o.grid.max_z_m)) return Fail("need --grid-min-z < --grid-max-z");
  if (const std::string up = Get(a, "--up");
      !up.empty() && !omni::octo::UpAxis::Parse(up, &o.grid.up))
    return Fail("--up must be one of x y z -x -y -z");
  const std::string source = Get(a, "--source");
  if (!source.empty() && !Get(a, "--poses").empty() && a.repose != 1)
    return Fail(
        "--source and --poses exclude each other (--poses replaces the pose channel; with "
        "--repose, --source picks the trajectory channel)");
  if (!source.empty()) {
    if (source != "rbpf" && source != "pg") return Fail("--source must be rbpf or pg");
    o.pose_source = source;
    o.pose_channel.clear();
    o.repose.trajectory_channel.clear();
  }
  // With --poses (usually a final trajectory) the log's trajectories are not applied unless
  // --repose asks for them (then the file stands in for the live poses).
  if (!Get(a, "--poses").empty()) o.repose.enabled = false;
  if (a.repose >= 0) o.repose.enabled = a.repose == 1;

  std::error_code ec;
  fs::create_directories(a.out, ec);
  if (ec) return Fail("cannot create " + a.out + ": " + ec.message());

  const int64_t t0 = omni::octo::ParallelKeySetInserter::NowMicros();
  if (fs::is_directory(a.input)) {
    // A folder of depth images with camera poses.
    if (!Get(a, "--poses").empty())
      return Fail("--poses is for a log INPUT (a folder has its own pose.txt)");
    omni::octo::DepthIntrinsics k;
    const std::string yaml = a.input + "/intrinsics.yaml";
    if (fs::exists(yaml)) {
      if (auto s = LoadIntrinsicsYaml(yaml, &k); !s.ok()) return Fail(s.message());
    }
    const Num ks[] = {{"--fx", &k.fx},
                      {"--fy", &k.fy},
                      {"--cx", &k.cx},
                      {"--cy", &k.cy},
                      {"--depth-scale", &k.depth_scale}};
    for (const auto& n : ks) {
      const std::string v = Get(a, n.flag);
      if (!v.empty() && !ParseDouble(v, n.target))
        return Fail(std::string(n.flag) + " '" + v + "' is not a number");
    }
    if (const std::string bad = k.Validate(); !bad.empty())
      return Fail("intrinsics: " + bad + " (give --fx --fy --cx --cy --depth-scale or " + yaml +
                  ")");
    auto poses = omni::octo::ReadPoseFile(a.input + "/pose.txt");
    if (!poses.ok()) return Fail(poses.error().message);
    if (poses->empty()) return Fail(a.input + "/pose.txt has no poses");
    omni::octo::OctomapBuilder builder(o);
    size_t points = 0;
    int64_t insert_us = 0;
    for (size_t i = 0; i < poses->size(); ++i) {
      std::string path = a.input + "/depth/" + std::to_string(i + 1) + ".png";
      if (!fs::exists(path)) path = a.input + "/depth/" + std::to_string(i + 1) + ".pgm";
      DepthImage im;
      if (auto s = omni::octo::ReadDepthFile(path, &im); !s.ok()) return Fail(s.message());
      im.intrinsics = k;
      omni::octo::ColorImage color;
      const std::string color_path = a.input + "/color/" + std::to_string(i + 1) + ".png";
      if (o.color) {
        // Registered to the depth image: same camera, same size (no colour intrinsics).
        if (auto s = omni::octo::ReadColorPng(color_path, &color); !s.ok())
          return Fail(s.message());
      }
      const int64_t f0 = omni::octo::ParallelKeySetInserter::NowMicros();
      auto st = o.color ? builder.InsertDepthColor(im, color, (*poses)[i])
                        : builder.InsertDepth(im, (*poses)[i]);
      const int64_t frame_us = omni::octo::ParallelKeySetInserter::NowMicros() - f0;
      insert_us += frame_us;
      if (!st.ok())
        return Fail((o.color ? path + " + " + color_path : path) + ": " + st.error().message);
      points += st->points;
      std::printf("frame %zu: %zu points, %zu rays, %zu free + %zu occupied keys", i + 1,
                  st->points, st->rays, st->insert.free_keys, st->insert.occupied_keys);
      if (o.color)
        std::printf(", %zu coloured keys (colour %.1f ms)", st->colored_keys, st->color_us * 1e-3);
      std::printf(", %.1f ms\n", frame_us * 1e-3);
      if (st->points > 0 && st->insert.free_keys + st->insert.occupied_keys == 0)
        std::fprintf(stderr,
                     "omni-octomap: warning: frame %zu: no point inside the octree's key range "
                     "(+-%.0f m at %.3f m cells): its pose is far out of the map, nothing "
                     "inserted\n",
                     i + 1, 32767 * o.resolution_m, o.resolution_m);
    }
    std::printf("omni-octomap: insertion %.1f ms/frame%s\n",
                insert_us * 1e-3 / static_cast<double>(poses->size()),
                o.color ? " (OcTree + ColorOcTree)" : "");
    if (auto s = WriteOutputs(builder, o, a.out, a.pcd); !s.ok()) return Fail(s.message());
    std::printf(
        "omni-octomap: %zu frames, %zu points, %.2f s -> %s/map.{bt,ot}%s (%zu leaves at %.3f m)\n",
        poses->size(), points, (omni::octo::ParallelKeySetInserter::NowMicros() - t0) * 1e-6,
        a.out.c_str(), o.color ? " + map_color.ot" : "", builder.tree().getNumLeafNodes(),
        o.resolution_m);
    return 0;
  }

  // An LCM log: replayed through the same pipeline as the process.
  auto reader = omni::io::LcmLogReader::Open(a.input);
  if (!reader.ok()) return Fail(reader.error().message);
  omni::octo::OctomapPipeline pipeline(o);
  // --poses: the trajectory file's poses, handed to the pipeline as the frames come (PoseFeed),
  // instead of the log's pose channel.
  const std::string poses_path = Get(a, "--poses");
  std::vector<std::pair<int64_t, omni::Pose2>> file_poses;
  int64_t file_poses_skipped = 0;
  if (!poses_path.empty()) {
    auto traj = omni::io::ReadTrajectory(poses_path);
    if (!traj.ok()) return Fail(traj.error().message);
    for (const auto& e : traj->entries) {
      const int64_t u = omni::SecondsToUtime(e.timestamp_s);
      if (!file_poses.empty() && u <= file_poses.back().first) {
        ++file_poses_skipped;  // not after the previous pose: the poser would refuse it
        continue;
      }
      file_poses.emplace_back(u, e.pose2());
    }
    if (file_poses.size() < 2) return Fail(poses_path + ": fewer than two poses in time order");
    if (file_poses_skipped > 0)
      std::fprintf(stderr,
                   "omni-octomap: warning: %lld of %zu poses in %s are not later than the pose "
                   "before them (a clock that went back?) and are skipped; frames in those "
                   "stretches are posed by the poses around them or dropped\n",
                   static_cast<long long>(file_poses_skipped), traj->entries.size(),
                   poses_path.c_str());
  }
  const bool use_file = !file_poses.empty();
  omni::octo::PoseFeed feed(std::move(file_poses));
  auto add_pose = [&pipeline](int64_t utime, const omni::Pose2& p) { pipeline.AddPose(utime, p); };
  const std::string pose_channel = use_file ? poses_path : o.PoseChannel();
  const std::string trajectory_channel = o.repose.enabled ? o.TrajectoryChannel() : "";
  int64_t decode_errors = 0, color_decode_errors = 0, events = 0, trajectories_rejected = 0;
  omni::io::LcmLogEvent ev;
  for (;;) {
    auto more = reader->Next(&ev, /*resync=*/true);
    if (!more.ok()) {
      // With resync the errors are a final event cut short (a logger killed, power lost): map
      // what came before it, as `extract` and the 2D mappers do; and a failed read: an error.
      if (!reader->truncated_tail()) return Fail(more.error().message);
      std::fprintf(stderr, "omni-octomap build: %s (reading stops there; %lld events read)\n",
                   more.error().message.c_str(), static_cast<long long>(events));
      break;
    }
    if (!*more) break;
    ++events;
    if (!use_file && ev.channel == pose_channel) {
      omni::pose2d_t m;
      if (omni::bus::DecodeMessage(&m, ev.data.data(), static_cast<int>(ev.data.size())) < 0) {
        ++decode_errors;
        continue;
      }
      pipeline.AddPose(m.utime, omni::Pose2(m.x_m, m.y_m, m.yaw_rad));
    } else if (!trajectory_channel.empty() && ev.channel == trajectory_channel) {
      omni::trajectory_t m;
      if (omni::bus::DecodeMessage(&m, ev.data.data(), static_cast<int>(ev.data.size())) < 0) {
        ++decode_errors;
        continue;
      }
      auto poses = omni::octo::FromTrajectoryMessage(m, o.map_frame);
      if (!poses.ok()) {
        ++trajectories_rejected;
        continue;
      }
      pipeline.AddTrajectory(std::move(*poses));
    } else if (ev.channel == o.depth_channel) {
      omni::depth_image_t m;
      if (omni::bus::DecodeMessage(&m, ev.data.data(), static_cast<int>(ev.data.size())) < 0) {
        ++decode_errors;
        continue;
      }
      auto im = omni::octo::FromDepthMessage(m);
      if (!im.ok()) {
        ++decode_errors;
        continue;
      }
      if (use_file) feed.FeedFor(im->utime, add_pose);
      pipeline.AddDepth(std::move(*im));
    } else if (o.color && ev.channel == o.color_channel) {
      omni::color_image_t m;
      if (omni::bus::DecodeMessage(&m, ev.data.data(), static_cast<int>(ev.data.size())) < 0) {
        ++color_decode_errors;
        continue;
      }
      auto im = omni::octo::FromColorMessage(m);
      if (!im.ok()) {
        ++color_decode_errors;
        continue;
      }
      pipeline.AddColor(std::move(*im));
    } else {
      continue;
    }
    pipeline.Process(pipeline.newest_utime());
  }
  // End of log: whatever still waits for a pose can only be posed by what is there.
  if (use_file) feed.FeedRest(add_pose);
  pipeline.FinishInput();
  pipeline.FinishRepose();
  const auto& pc = pipeline.poser_counters();
  const auto& c = pipeline.counters();
  if (c.frames_inserted == 0)
    return Fail("no frame could be posed (" + std::to_string(pc.frames_in) + " depth frames on " +
                o.depth_channel + ", " + std::to_string(pc.poses_in) + " poses on " + pose_channel +
                ", " + std::to_string(decode_errors) + " decode errors)");
  if (auto s = WriteOutputs(pipeline.builder(), o, a.out, a.pcd); !s.ok()) return Fail(s.message());
  if (o.color)
    std::printf(
        "omni-octomap: colour: %lld frames in, %lld depth frames coloured, %lld uncoloured, %lld "
        "colour errors -> %s/map_color.ot\n",
        static_cast<long long>(c.color_frames_in), static_cast<long long>(c.frames_colored),
        static_cast<long long>(c.frames_uncolored),
        static_cast<long long>(color_decode_errors + c.color_invalid), a.out.c_str());
  if (o.repose.enabled)
    std::printf(
        "omni-octomap: repose: %lld trajectories on %s (%lld rejected), %lld keyframes (%lld "
        "points; %lld retired as revisited), %lld rebuilds (the last %.2f s, for a shift of %.3f "
        "m)%s\n",
        static_cast<long long>(c.trajectories_in + trajectories_rejected),
        trajectory_channel.c_str(),
        static_cast<long long>(c.trajectories_invalid + trajectories_rejected),
        static_cast<long long>(c.keyframes), static_cast<long long>(c.keyframe_points),
        static_cast<long long>(c.keyframes_retired), static_cast<long long>(c.rebuilds_done),
        c.last_rebuild_us * 1e-6, c.last_rebuild_shift_mm * 1e-3,
        c.repose_stopped ? "; stopped at repose.max_points" : "");
  if (use_file)
    std::printf("omni-octomap: %zu poses from %s (%lld not after the one before, skipped)\n",
                feed.fed(), poses_path.c_str(), static_cast<long long>(file_poses_skipped));
  std::printf(
      "omni-octomap: %lld events; %lld frames in, %lld inserted, %lld dropped without pose, %lld "
      "out of order, %lld decode errors, %.2f s -> %s/map.{bt,ot} (%zu leaves at %.3f m)\n",
      static_cast<long long>(events), static_cast<long long>(pc.frames_in),
      static_cast<long long>(c.frames_inserted), static_cast<long long>(pc.frames_dropped_no_pose),
      static_cast<long long>(pc.frames_out_of_order + pc.poses_out_of_order),
      static_cast<long long>(decode_errors),
      (omni::octo::ParallelKeySetInserter::NowMicros() - t0) * 1e-6, a.out.c_str(),
      pipeline.builder().tree().getNumLeafNodes(), o.resolution_m);
  return 0;
}
