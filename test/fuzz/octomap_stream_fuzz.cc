// A stream of robot poses, depth frames, colour frames, trajectories and undecodable messages, as
// the octomap_builder node receives them on the bus (memq://), with ticks in between.
// The input is a script: its first byte picks the node's options (colour, re-posing, the kept
// cloud, the voxel filter), then each record is one event whose numbers come from the input,
// with NaN, infinities, absurd magnitudes, bad intrinsics, wrong sizes and clock jumps among them.
// What must hold whatever comes: every OCTOMAP message parses back into a tree, every GRID_OCTO
// is a well-formed grid, heartbeat counters are counts, and the final tree has only finite
// leaves inside its key range. The sanitizer builds also catch any coordinate that reaches
// OctoMap's int cast out of range. Seeds: a camera on a robot driving along a wall, one per mode.

#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "fuzz.h"
#include "omni/bus/bus.h"
#include "omni/bus/convert.h"
#include "omni/color_image_t.hpp"
#include "omni/common/time.h"
#include "omni/depth_image_t.hpp"
#include "omni/heartbeat_t.hpp"
#include "omni/occupancy_grid_t.hpp"
#include "omni/octomap_builder/map_output.h"
#include "omni/octomap_builder/octomap_node.h"
#include "omni/octomap_t.hpp"
#include "omni/pose2d_t.hpp"
#include "omni/trajectory_t.hpp"
#include "quiet_logs.h"

namespace {

using omni::fuzz::AppendU16;
using omni::fuzz::ScriptTimeStep;
using omni::fuzz::ScriptValue;

// Script layout (docs/fuzzing.md):
//   byte 0: bit 0 colour, bit 1 re-posing from trajectories, bit 2 the kept cloud, bit 3 the
//           voxel filter and one ray per voxel
//   records, each an op byte then its fields:
//     kPose:  dt, dx, dy, dyaw (a step from the last pose, or a special value)
//     kDepth: dt, seq step, size, intrinsics choice, wall distance, encoding/size damage, then a
//             count of pixels overwritten and each (index, value)
//     kColor: dt, size choice, intrinsics choice, byte-count damage, colour
//     kTraj:  pose count, a shift of every pose, the frame, and one special pose or stamp
//     kJunk:  channel, length, bytes: published raw, so the bus must refuse or decode them
//     kTick:  clock advance, then the node's Tick
enum Op : uint8_t { kPose, kDepth, kColor, kTraj, kJunk, kTick, kOps };

constexpr int kMaxRecords = 120;
constexpr int kMaxFrames = 24;
constexpr int kMaxSide = 32;

// Intrinsics for a w x h image: mostly a 60° camera; a few codes give what a broken driver or a
// foreign publisher could send.
void Intrinsics(omni::fuzz::Reader& r, int w, int h, double* fx, double* fy, double* cx,
                double* cy) {
  *fx = *fy = 0.87 * w;
  *cx = (w - 1) / 2.0;
  *cy = (h - 1) / 2.0;
  switch (r.U8() % 8) {
    case 0:
      *fx = ScriptValue(r, 100.0);
      break;
    case 1:
      *fy = ScriptValue(r, 100.0);
      break;
    case 2:
      *cx = ScriptValue(r, 1e4);
      break;
    case 3:
      *cy = ScriptValue(r, 1e4);
      break;
    case 4:
      *fx = -*fx;  // a flipped axis
      break;
    default:
      break;
  }
}

bool Finite(double x, double y, double yaw) {
  return std::isfinite(x) && std::isfinite(y) && std::isfinite(yaw);
}

// Whatever the node publishes, checked as it goes out.
struct Observer {
  explicit Observer(omni::bus::Bus* b) {
    b->Subscribe<omni::octomap_t>("OCTOMAP", [this](const omni::octomap_t& m, int64_t) {
      OMNI_FUZZ_CHECK(m.size == static_cast<int32_t>(m.data.size()));
      OMNI_FUZZ_CHECK(m.resolution_m > 0 && std::isfinite(m.resolution_m));
      const std::string bytes(m.data.begin(), m.data.end());
      OMNI_FUZZ_CHECK(omni::octo::ParseTree(bytes, m.binary, "OCTOMAP").ok());
      ++octomaps;
    });
    b->Subscribe<omni::octomap_t>("OCTOMAP_COLOR", [](const omni::octomap_t& m, int64_t) {
      const std::string bytes(m.data.begin(), m.data.end());
      OMNI_FUZZ_CHECK(omni::octo::ParseColorTree(bytes, "OCTOMAP_COLOR").ok());
    });
    b->Subscribe<omni::occupancy_grid_t>("GRID_OCTO", [](const omni::occupancy_grid_t& g, int64_t) {
      auto grid = omni::bus::FromGridMessage(g);
      OMNI_FUZZ_CHECK(grid.ok());
      OMNI_FUZZ_CHECK(std::isfinite(grid->origin_x_m) && std::isfinite(grid->origin_y_m));
      for (int8_t c : grid->cells) OMNI_FUZZ_CHECK(c == -1 || (c >= 0 && c <= 100));
    });
    b->Subscribe<omni::heartbeat_t>("HEARTBEAT", [](const omni::heartbeat_t& h, int64_t) {
      OMNI_FUZZ_CHECK(h.num_counters == static_cast<int32_t>(h.counter_values.size()));
      for (const int64_t v : h.counter_values) OMNI_FUZZ_CHECK(v >= 0);
    });
  }
  int octomaps = 0;
};

class Script {
 public:
  Script(const uint8_t* data, size_t size) : r_(data, size) {}

  void Run() {
    const uint8_t mode = r_.U8();
    omni::octo::OctomapBuilderOptions o;
    o.color = mode & 1;
    o.repose.enabled = mode & 2;
    o.repose.min_interval_s = 0.5;
    o.repose.rebuild_budget_ms = 1000;  // a rebuild finishes within a tick: runs repeat
    o.keep_cloud = mode & 4;
    if (mode & 8) {
      o.voxel_filter_m = 0.1;
      o.discretize = true;
    }
    o.resolution_m = 0.1;
    o.max_range_m = 4.0;
    o.threads = 1;
    o.out_dir = "";  // never saved: the save period below is never reached
    o.save_interval_s = 1e9;
    o.octomap_interval_s = 0.2;  // published often, so the checks see many trees
    o.grid_interval_s = 0.2;
    o.heartbeat_period_s = 0.2;
    auto bus_or = omni::bus::Bus::Create("memq://");
    OMNI_FUZZ_CHECK(bus_or.ok());
    bus_ = std::move(*bus_or);
    Observer observer(bus_.get());
    node_ = std::make_unique<omni::octo::OctomapNode>(bus_.get(), o, &clock_);
    for (int records = 0; records < kMaxRecords && !r_.empty(); ++records) {
      switch (r_.U8() % kOps) {
        case kPose:
          Pose();
          break;
        case kDepth:
          if (frames_ < kMaxFrames) Depth();
          break;
        case kColor:
          if (frames_ < kMaxFrames) Color();
          break;
        case kTraj:
          Trajectory();
          break;
        case kJunk:
          Junk();
          break;
        default:
          Tick();
          break;
      }
      Pump();
    }
    // As the process ends (host/octomap_builder/node/main.cc), then one more publication.
    auto& p = node_->pipeline();
    p.FlushAwaitingColor();
    p.FinishRepose();
    (void)node_->PublishOctomap();
    (void)node_->PublishGrid();
    Pump();
    const auto& pc = p.poser_counters();
    const auto& c = p.counters();
    OMNI_FUZZ_CHECK(pc.frames_posed <= pc.frames_in);
    OMNI_FUZZ_CHECK(c.frames_inserted <= pc.frames_posed);
    OMNI_FUZZ_CHECK(pc.poses_invalid + pc.poses_out_of_order <= pc.poses_in);
    const octomap::OcTree& tree = p.builder().tree();
    const double half = tree.getResolution() * (1 << (tree.getTreeDepth() - 1));
    for (auto it = tree.begin_leafs(); it != tree.end_leafs(); ++it) {
      const double x = it.getX(), y = it.getY(), z = it.getZ();
      OMNI_FUZZ_CHECK(std::isfinite(x) && std::isfinite(y) && std::isfinite(z));
      OMNI_FUZZ_CHECK(std::abs(x) <= half && std::abs(y) <= half && std::abs(z) <= half);
    }
    for (const auto& pt : p.builder().AggregateCloud()) OMNI_FUZZ_CHECK(pt.allFinite());
  }

 private:
  void Pump() {
    while (bus_->HandleTimeout(0) > 0) {
    }
  }

  void Advance() { utime_ += ScriptTimeStep(r_, utime_); }

  void Pose() {
    Advance();
    x_ += ScriptValue(r_, 0.3);
    y_ += ScriptValue(r_, 0.3);
    yaw_ += ScriptValue(r_, 0.3);
    omni::pose2d_t m{};
    m.utime = utime_;
    m.frame = "map";
    m.x_m = x_;
    m.y_m = y_;
    m.yaw_rad = yaw_;
    bus_->Publish("POSE_RBPF", m);
    path_.push_back({utime_, x_, y_, yaw_});
    if (path_.size() > 64) path_.erase(path_.begin());
    if (!Finite(x_, y_, yaw_)) x_ = y_ = yaw_ = 0;
  }

  void Depth() {
    ++frames_;
    Advance();
    omni::depth_image_t m{};
    m.utime = utime_;
    const uint8_t seq_step = r_.U8();
    depth_seq_ += seq_step % 4 == 3 ? -static_cast<int64_t>(seq_step) : seq_step % 4;
    m.seq = depth_seq_;
    m.frame = "depth_optical";
    const uint8_t size = r_.U8();
    m.width = 1 + size % kMaxSide;
    m.height = 1 + (size / kMaxSide) * 3 % kMaxSide;
    Intrinsics(r_, m.width, m.height, &m.fx, &m.fy, &m.cx, &m.cy);
    const uint8_t scale = r_.U8();
    m.depth_scale = scale < 250 ? 1000.0 : ScriptValue(r_, 5000.0);
    // A wall facing the camera, 0.2-6.6 m away (so some frames lie beyond the range limits).
    const uint16_t wall = static_cast<uint16_t>(200 + r_.U8() * 25);
    std::vector<uint16_t> pixels(static_cast<size_t>(m.width) * m.height, wall);
    const int specials = r_.U8() % 16;
    for (int k = 0; k < specials; ++k) {
      const size_t i = r_.U16() % pixels.size();
      pixels[i] = r_.U16();  // 0 (no reading), 65535, anything
    }
    m.encoding = omni::depth_image_t::ENCODING_RAW_U16_LE;
    m.uncompressed_size = static_cast<int32_t>(pixels.size() * 2);
    m.data.resize(pixels.size() * 2);
    for (size_t i = 0; i < pixels.size(); ++i) {
      m.data[2 * i] = static_cast<uint8_t>(pixels[i] & 0xff);
      m.data[2 * i + 1] = static_cast<uint8_t>(pixels[i] >> 8);
    }
    const uint8_t damage = r_.U8() % 8;
    if (damage == 0 && !m.data.empty()) m.data.pop_back();  // bytes short of the size
    if (damage == 1) m.width += 1;                          // size disagrees with the bytes
    if (damage == 2) m.encoding = 7;                        // unknown encoding
    if (damage == 3) m.encoding = omni::depth_image_t::ENCODING_ZLIB_U16_LE;  // not zlib
    m.size = static_cast<int32_t>(m.data.size());
    bus_->Publish("DEPTH", m);
  }

  void Color() {
    ++frames_;
    Advance();
    omni::color_image_t m{};
    m.utime = utime_;
    m.seq = color_seq_++;
    m.frame = "rgb_optical";
    const uint8_t size = r_.U8();
    m.width = 1 + size % kMaxSide;
    m.height = 1 + (size / kMaxSide) * 3 % kMaxSide;
    Intrinsics(r_, m.width, m.height, &m.fx, &m.fy, &m.cx, &m.cy);
    if (r_.U8() % 4 == 0) m.fx = m.fy = m.cx = m.cy = 0;  // registered: no own intrinsics
    m.encoding = omni::color_image_t::ENCODING_RGB8;
    m.data.assign(static_cast<size_t>(m.width) * m.height * 3, r_.U8());
    const uint8_t damage = r_.U8() % 8;
    if (damage == 0 && !m.data.empty()) m.data.pop_back();
    if (damage == 1) m.encoding = omni::color_image_t::ENCODING_JPEG;  // not a JPEG
    m.size = static_cast<int32_t>(m.data.size());
    bus_->Publish("RGB", m);
  }

  void Trajectory() {
    // The mapper's whole corrected path: the poses sent so far (the newest `n`), shifted, with
    // one of them replaced by a special value now and then.
    const size_t n = std::min<size_t>(path_.size(), r_.U8() % 65);
    const double dx = ScriptValue(r_, 1.0), dy = ScriptValue(r_, 1.0), dyaw = ScriptValue(r_, 0.5);
    omni::trajectory_t t{};
    t.utime = utime_;
    t.frame = r_.U8() % 16 == 0 ? "odom" : "map";
    t.num_poses = static_cast<int32_t>(n);
    for (size_t i = path_.size() - n; i < path_.size(); ++i) {
      t.pose_utime.push_back(path_[i].utime);
      t.x_m.push_back(path_[i].x + dx);
      t.y_m.push_back(path_[i].y + dy);
      t.yaw_rad.push_back(path_[i].yaw + dyaw);
    }
    const uint8_t special = r_.U8();
    if (n > 0 && special % 4 == 0) t.x_m[special % n] = ScriptValue(r_, 1e3);
    if (n > 0 && special % 4 == 1) t.pose_utime[special % n] = -static_cast<int64_t>(special);
    bus_->Publish("TRAJECTORY_RBPF", t);
  }

  void Junk() {
    static const char* const kChannels[] = {"DEPTH", "RGB", "POSE_RBPF", "TRAJECTORY_RBPF"};
    const char* channel = kChannels[r_.U8() % 4];
    const std::string bytes = r_.Bytes(r_.U8());
    bus_->PublishRaw(channel, bytes.data(), static_cast<int>(bytes.size()));
  }

  void Tick() {
    mono_ += static_cast<int64_t>(r_.U8()) * 20000;
    clock_.Set(1000000 + mono_);
    node_->Tick(mono_);
  }

  struct Step {
    int64_t utime;
    double x, y, yaw;
  };

  omni::fuzz::Reader r_;
  omni::ManualClock clock_{1000000};
  std::unique_ptr<omni::bus::Bus> bus_;
  std::unique_ptr<omni::octo::OctomapNode> node_;
  std::vector<Step> path_;
  int64_t utime_ = 1000000000000;  // 1970 + 11 days: stamps after 1970 (trajectories need it)
  int64_t mono_ = 0;
  int64_t depth_seq_ = 0, color_seq_ = 0;
  int frames_ = 0;
  double x_ = 0, y_ = 0, yaw_ = 0;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  omni::fuzz::QuietLogs();
  Script(data, size).Run();
  return 0;
}

namespace {

// A drive along a wall: a pose every 50 ms (5 cm and 0.01 rad a step), a 24 x 18 depth frame
// 20 ms after every second pose (so it is posed once the next pose comes), a colour frame at the
// same time, the path as a trajectory every eighth step, and a tick every step.
std::string Drive(uint8_t mode, int steps) {
  std::string s(1, static_cast<char>(mode));
  for (int k = 0; k < steps; ++k) {
    s += static_cast<char>(kPose);
    s += static_cast<char>(k % 2 == 0 ? 50 : 30);  // the frames sit 20 ms after a pose
    s += static_cast<char>(0);
    AppendU16(&s, 5461);  // 0.05 m
    s += static_cast<char>(0);
    AppendU16(&s, 0);
    s += static_cast<char>(0);
    AppendU16(&s, 1092);  // 0.01 rad
    if (k % 2 == 1) {
      s += static_cast<char>(kDepth);
      s += static_cast<char>(20);
      s += static_cast<char>(1);                   // seq + 1
      s += static_cast<char>(23 + kMaxSide * 5);   // 24 wide, 16 high
      s += static_cast<char>(7);                   // the normal intrinsics
      s += static_cast<char>(0);                   // millimetres
      s += static_cast<char>(80);                  // the wall 2.2 m ahead
      s += static_cast<char>(k % 6 == 1 ? 2 : 0);  // a few odd pixels now and then
      for (int j = 0; j < (k % 6 == 1 ? 2 : 0); ++j) {
        AppendU16(&s, static_cast<int16_t>(31 * j + k));
        AppendU16(&s, static_cast<int16_t>(j == 0 ? 0 : 9000));
      }
      s += static_cast<char>(7);  // undamaged
      if (mode & 1) {
        s += static_cast<char>(kColor);
        s += static_cast<char>(0);  // the depth frame's stamp
        s += static_cast<char>(23 + kMaxSide * 5);
        s += static_cast<char>(7);
        s += static_cast<char>(1);    // own intrinsics
        s += static_cast<char>(200);  // colour
        s += static_cast<char>(7);    // undamaged
      }
    }
    if ((mode & 2) && k % 8 == 7) {
      s += static_cast<char>(kTraj);
      s += static_cast<char>(64);
      s += static_cast<char>(0);  // dx
      AppendU16(&s, 9830);        // 0.3 m: past the shift that asks for a rebuild
      s += static_cast<char>(255);
      s += static_cast<char>(255);
      s += static_cast<char>(1);  // the map frame
      s += static_cast<char>(2);  // no special pose
    }
    s += static_cast<char>(kTick);
    s += static_cast<char>(3);  // 60 ms
  }
  return s;
}

}  // namespace

void omni::fuzz::Seeds(SeedList* seeds) {
  for (uint8_t mode = 0; mode < 16; ++mode) seeds->Add(Drive(mode, 24));
  // A garbled message on each channel between two stretches of driving.
  std::string junk = Drive(3, 8);
  for (uint8_t channel = 0; channel < 4; ++channel) {
    junk += static_cast<char>(kJunk);
    junk += static_cast<char>(channel);
    junk += static_cast<char>(12);
    junk += std::string(12, '\x7f');
  }
  seeds->Add(junk + Drive(3, 8).substr(1));
}
