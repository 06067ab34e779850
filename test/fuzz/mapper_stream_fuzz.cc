// A stream of scans, odometry, IMU samples and undecodable messages, as the RBPF or the pose-graph
// mapper node receives it on the bus (memq://), with ticks and deferred processing in between (or
// odom_mapper's library, as its process receives it).
// The input is a script: its first byte picks the mapper and its mode, then each record is one
// event whose numbers come from the input, with NaN, infinities, absurd magnitudes and clock
// jumps among them. What must hold whatever comes: every pose, trajectory and grid the node
// publishes is finite and well formed, heartbeat counters are counts, and the final trajectory
// and map are finite. Seeds: scripted drives around a rectangular room, one per mapper and mode.
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "fuzz.h"
#include "omni/bus/bus.h"
#include "omni/bus/convert.h"
#include "omni/common/time.h"
#include "omni/heartbeat_t.hpp"
#include "omni/imu_t.hpp"
#include "omni/laser_scan_t.hpp"
#include "omni/occupancy_grid_t.hpp"
#include "omni/odom_mapper/odom_mapper.h"
#include "omni/odom_mapper/scan_message.h"
#include "omni/odometry_t.hpp"
#include "omni/pose2d_t.hpp"
#include "omni/pose_graph_mapper/pose_graph_node.h"
#include "omni/rbpf_mapper/rbpf_node.h"
#include "omni/trajectory_t.hpp"
#include "quiet_logs.h"

namespace {

using omni::fuzz::AppendU16;
using omni::fuzz::ScriptTimeStep;
using omni::fuzz::ScriptValue;

// Script layout (docs/fuzzing.md):
//   byte 0: bit 0 the mapper (0 RBPF, 1 pose graph), bit 1 deferred mode, bit 2 IMU fusion,
//           bit 3 odom_mapper's library instead (wired as its process wires it)
//   records, each an op byte then its fields:
//     kOdom:  dt, dx, dy, dyaw (a delta from the last odometry pose, or a special value)
//     kScan:  dt, seq step, beams, room size, angle choice, range limits, sensor pose, sweep,
//             then a count of beams overwritten with special values and each (index, value)
//     kImu:   dt, yaw rate
//     kJunk:  channel, length, bytes: published raw, so the bus must refuse or decode them
//     kTick:  clock advance, then Tick() and ProcessReady()
enum Op : uint8_t { kOdom, kScan, kImu, kJunk, kTick, kOps };

constexpr int kMaxRecords = 160;
constexpr int kMaxScans = 40;
constexpr int kMaxBeams = 360;

float Special(uint8_t code, float normal) {
  switch (code % 8) {
    case 0:
      return std::numeric_limits<float>::quiet_NaN();
    case 1:
      return std::numeric_limits<float>::infinity();
    case 2:
      return -std::numeric_limits<float>::infinity();
    case 3:
      return -1.0f;
    case 4:
      return 0.0f;
    case 5:
      return 3e38f;
    case 6:
      return std::numeric_limits<float>::denorm_min();
    default:
      return normal;
  }
}

bool Finite(double x, double y, double yaw) {
  return std::isfinite(x) && std::isfinite(y) && std::isfinite(yaw);
}

// Whatever the node publishes, checked as it goes out.
struct Observer {
  explicit Observer(omni::bus::Bus* b, const std::string& prefix) {
    b->Subscribe<omni::pose2d_t>("POSE_" + prefix, [this](const omni::pose2d_t& p, int64_t) {
      OMNI_FUZZ_CHECK(Finite(p.x_m, p.y_m, p.yaw_rad));
      ++poses;
    });
    b->Subscribe<omni::trajectory_t>(
        "TRAJECTORY_" + prefix, [](const omni::trajectory_t& t, int64_t) {
          OMNI_FUZZ_CHECK(t.num_poses >= 0);
          const auto n = static_cast<size_t>(t.num_poses);
          OMNI_FUZZ_CHECK(t.pose_utime.size() == n && t.x_m.size() == n && t.y_m.size() == n &&
                          t.yaw_rad.size() == n);
          for (size_t i = 0; i < n; ++i) OMNI_FUZZ_CHECK(Finite(t.x_m[i], t.y_m[i], t.yaw_rad[i]));
        });
    b->Subscribe<omni::occupancy_grid_t>("GRID_" + prefix,
                                         [](const omni::occupancy_grid_t& g, int64_t) {
                                           auto grid = omni::bus::FromGridMessage(g);
                                           OMNI_FUZZ_CHECK(grid.ok());
                                         });
    b->Subscribe<omni::heartbeat_t>("HEARTBEAT", [](const omni::heartbeat_t& h, int64_t) {
      OMNI_FUZZ_CHECK(h.num_counters == static_cast<int32_t>(h.counter_values.size()));
      for (size_t i = 0; i < h.counter_values.size(); ++i) {
        const std::string& name = h.counter_names[i];
        const int64_t v = h.counter_values[i];
        // Estimates (calibration in ppm, gyro bias in µrad/s) are signed, and finite estimates
        // give modest numbers; everything else counts events.
        const bool estimate =
            name.find("_ppm") != std::string::npos || name.find("urad") != std::string::npos;
        if (estimate) {
          OMNI_FUZZ_CHECK(v > -(int64_t{1} << 53) && v < (int64_t{1} << 53));
        } else {
          OMNI_FUZZ_CHECK(v >= 0);
        }
      }
    });
  }
  int poses = 0;
};

void CheckMap(const omni::io::GridMap& m) {
  OMNI_FUZZ_CHECK(m.width >= 0 && m.height >= 0);
  OMNI_FUZZ_CHECK(m.cells.size() == static_cast<size_t>(m.width) * m.height);
  OMNI_FUZZ_CHECK(std::isfinite(m.origin_x_m) && std::isfinite(m.origin_y_m));
  for (int8_t c : m.cells) OMNI_FUZZ_CHECK(c == -1 || (c >= 0 && c <= 100));
}

class Script {
 public:
  Script(const uint8_t* data, size_t size) : r_(data, size) {}

  void Run() {
    const uint8_t mode = r_.U8();
    const bool odom_only = mode & 8;
    const bool pose_graph = !odom_only && (mode & 1);
    const bool deferred = mode & 2;
    const bool imu = mode & 4;
    auto bus_or = omni::bus::Bus::Create("memq://");
    OMNI_FUZZ_CHECK(bus_or.ok());
    bus_ = std::move(*bus_or);
    Observer observer(bus_.get(), pose_graph ? "PG" : "RBPF");
    if (odom_only) {
      // odom_mapper's process wires its library to the bus this way (host/odom_mapper/main.cc).
      odom_ =
          std::make_unique<omni::odom_mapper::OdomMapper>(omni::odom_mapper::OdomMapperOptions{});
      bus_->Subscribe<omni::odometry_t>("WHEEL_ODOM", [this](const omni::odometry_t& m, int64_t) {
        (void)odom_->AddOdometry(m.utime, omni::Pose2(m.x_m, m.y_m, m.yaw_rad));
      });
      bus_->Subscribe<omni::laser_scan_t>(
          "LIDAR_SCAN", [this](const omni::laser_scan_t& m, int64_t) {
            (void)odom_->AddScan(omni::odom_mapper::ScanFromMessage(m));
          });
    } else if (pose_graph) {
      omni::pgm::PoseGraphSlamOptions slam;
      slam.num_threads = 1;
      slam.loop.num_threads = 1;
      slam.window_size = 10;
      slam.use_gyro = imu;
      pg_ = std::make_unique<omni::pgm::PoseGraphNode>(
          bus_.get(), omni::pgm::PoseGraphNodeOptions{}, slam, omni::pgm::BatchOptions{}, &clock_);
      pg_->set_deferred(deferred);
    } else {
      omni::rbpf::RbpfOptions opt;
      opt.particles = 4;
      opt.threads = 1;
      opt.use_imu = imu;
      opt.grid_publish_interval_s = 0.5;
      opt.trajectory_publish_interval_s = 0.5;
      opt.odometry_calibration.min_pairs = 3;
      rbpf_ = std::make_unique<omni::rbpf::RbpfNode>(bus_.get(), opt, &clock_);
      rbpf_->set_deferred(deferred);
    }
    for (int records = 0; records < kMaxRecords && !r_.empty(); ++records) {
      switch (r_.U8() % kOps) {
        case kOdom:
          Odometry();
          break;
        case kScan:
          if (scans_ < kMaxScans) Scan();
          break;
        case kImu:
          Imu();
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
    if (odom_) {
      const auto& c = odom_->counters();
      OMNI_FUZZ_CHECK(c.scans_mapped <= c.scans_in && c.odom_invalid <= c.odom_in);
      CheckMap(odom_->Map());
    } else if (pg_) {
      pg_->Flush();
      Pump();
      for (const auto& p : pg_->slam().Trajectory())
        OMNI_FUZZ_CHECK(Finite(p.pose.x, p.pose.y, p.pose.theta));
      CheckMap(pg_->slam().RenderMap(omni::io::LogOddsOptions{}));
    } else {
      rbpf_->Flush();
      Pump();
      const auto& c = rbpf_->slam().counters();
      OMNI_FUZZ_CHECK(c.scans_processed <= c.scans_in);
      for (const auto& p : rbpf_->slam().BestTrajectory())
        OMNI_FUZZ_CHECK(Finite(p.pose.x, p.pose.y, p.pose.theta));
      CheckMap(rbpf_->slam().BestMap());
    }
  }

 private:
  void Pump() {
    while (bus_->HandleTimeout(0) > 0) {
    }
  }

  void Advance() {
    const int64_t step = ScriptTimeStep(r_, utime_);
    utime_ += step;
  }

  void Odometry() {
    Advance();
    omni::odometry_t m{};
    m.utime = utime_;
    m.seq = odom_seq_++;
    m.frame = "odom";
    m.child_frame = "base";
    // Mostly a step from the last pose (up to 0.3 m, 0.3 rad); a special value is taken as is
    // and the next step starts from it.
    x_ += ScriptValue(r_, 0.3);
    y_ += ScriptValue(r_, 0.3);
    yaw_ += ScriptValue(r_, 0.3);
    m.x_m = x_;
    m.y_m = y_;
    m.yaw_rad = yaw_;
    bus_->Publish("WHEEL_ODOM", m);
    if (!std::isfinite(x_) || !std::isfinite(y_) || !std::isfinite(yaw_)) x_ = y_ = yaw_ = 0;
  }

  void Scan() {
    ++scans_;
    Advance();
    omni::laser_scan_t m{};
    m.utime = utime_;
    const uint8_t seq_step = r_.U8();
    seq_ += seq_step % 4 == 3 ? -static_cast<int64_t>(seq_step) : seq_step % 4;
    m.seq = seq_;
    m.frame = "laser";
    const int beams = r_.U8() * kMaxBeams / 255;
    // The room: a rectangle of half-sizes a x b around the sensor, seen from the centre, so the
    // mappers have walls to match.
    const double a = 1.0 + r_.U8() / 32.0, b = 1.0 + r_.U8() / 32.0;
    const uint8_t angles = r_.U8();
    const float full = static_cast<float>(2 * M_PI);
    m.angle_min_rad =
        angles % 4 == 0 ? Special(r_.U8(), -static_cast<float>(M_PI)) : -static_cast<float>(M_PI);
    m.angle_increment_rad = beams > 0 ? full / static_cast<float>(beams) : 0.0f;
    if (angles % 4 == 1) m.angle_increment_rad = Special(r_.U8(), m.angle_increment_rad);
    if (angles % 4 == 2) m.angle_increment_rad = -m.angle_increment_rad;
    const uint8_t limits = r_.U8();
    m.range_min_m = limits % 3 == 0 ? Special(r_.U8(), 0.1f) : 0.1f;
    m.range_max_m = limits % 3 == 1 ? Special(r_.U8(), 12.0f) : 12.0f;
    const uint8_t sensor = r_.U8();
    if (sensor % 2 == 1) {
      m.sensor_x_m = ScriptValue(r_, 0.5);
      m.sensor_y_m = ScriptValue(r_, 0.5);
      m.sensor_yaw_rad = ScriptValue(r_, 4.0);
    }
    m.scan_time_s = sensor % 4 >= 2 ? Special(r_.U8(), 0.1f) : 0.0f;
    m.ranges_m.resize(static_cast<size_t>(beams));
    for (int i = 0; i < beams; ++i) {
      const double t = m.angle_min_rad + i * static_cast<double>(m.angle_increment_rad);
      const double c = std::abs(std::cos(t)), s = std::abs(std::sin(t));
      const double range = std::min(c > 1e-9 ? a / c : 1e9, s > 1e-9 ? b / s : 1e9);
      m.ranges_m[static_cast<size_t>(i)] = static_cast<float>(range);
    }
    const int specials = r_.U8() % 16;
    for (int k = 0; k < specials && beams > 0; ++k) {
      const size_t i = r_.U16() % static_cast<size_t>(beams);
      m.ranges_m[i] = Special(r_.U8(), m.ranges_m[i]);
    }
    m.num_ranges = beams;
    bus_->Publish("LIDAR_SCAN", m);
  }

  void Imu() {
    Advance();
    omni::imu_t m{};
    m.utime = utime_;
    m.seq = imu_seq_++;
    m.frame = "imu";
    m.orientation_wxyz[0] = 1;
    m.angular_velocity_rad_s[2] = ScriptValue(r_, 2.0);
    m.magnetic_field_t[0] = m.magnetic_field_t[1] = m.magnetic_field_t[2] = NAN;
    m.temperature_c = NAN;
    bus_->Publish("IMU", m);
  }

  void Junk() {
    static const char* const kChannels[] = {"LIDAR_SCAN", "WHEEL_ODOM", "IMU"};
    const char* channel = kChannels[r_.U8() % 3];
    const std::string bytes = r_.Bytes(r_.U8());
    bus_->PublishRaw(channel, bytes.data(), static_cast<int>(bytes.size()));
  }

  void Tick() {
    clock_.Advance(static_cast<int64_t>(r_.U8()) * 20000);
    const int ready = 1 + r_.U8() % 8;
    if (pg_) {
      pg_->Tick();
      (void)pg_->ProcessReady(ready);
    } else if (rbpf_) {
      rbpf_->Tick();
      (void)rbpf_->ProcessReady(ready);
    }
  }

  omni::fuzz::Reader r_;
  omni::ManualClock clock_{1000000};
  std::unique_ptr<omni::bus::Bus> bus_;
  std::unique_ptr<omni::pgm::PoseGraphNode> pg_;
  std::unique_ptr<omni::rbpf::RbpfNode> rbpf_;
  std::unique_ptr<omni::odom_mapper::OdomMapper> odom_;
  int64_t utime_ = 1000000;
  int64_t seq_ = 0, odom_seq_ = 0, imu_seq_ = 0;
  int scans_ = 0;
  double x_ = 0, y_ = 0, yaw_ = 0;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  omni::fuzz::QuietLogs();
  Script(data, size).Run();
  return 0;
}

namespace {

// A drive through the room: odometry every 40 ms (4 cm and 0.02 rad a step, so both mappers'
// update gates open every few steps), a 180-beam scan after every second odometry sample, an
// IMU sample and a tick every step.
std::string Drive(uint8_t mode, int steps) {
  std::string s(1, static_cast<char>(mode));
  for (int k = 0; k < steps; ++k) {
    s += static_cast<char>(kOdom);
    s += static_cast<char>(40);  // dt 40 ms
    s += static_cast<char>(0);   // dx = 0.3 * v / 32768: a normal value
    AppendU16(&s, 4369);         // 0.04 m
    s += static_cast<char>(0);
    AppendU16(&s, 0);
    s += static_cast<char>(0);
    AppendU16(&s, 2185);  // 0.02 rad
    if (k % 2 == 1) {
      s += static_cast<char>(kScan);
      s += static_cast<char>(0);    // same stamp as the odometry
      s += static_cast<char>(1);    // seq + 1
      s += static_cast<char>(128);  // 180 beams
      s += static_cast<char>(64);   // 3 m x 2 m half-sizes
      s += static_cast<char>(32);
      s += static_cast<char>(3);                   // the normal angles
      s += static_cast<char>(2);                   // the normal limits
      s += static_cast<char>(0);                   // sensor at the base, no sweep
      s += static_cast<char>(k % 8 == 1 ? 3 : 0);  // a few NaN/inf/-1 beams now and then
      for (int j = 0; j < (k % 8 == 1 ? 3 : 0); ++j) {
        AppendU16(&s, static_cast<int16_t>(17 * j + k));
        s += static_cast<char>(j);
      }
    }
    if (mode & 4) {
      s += static_cast<char>(kImu);
      s += static_cast<char>(0);
      s += static_cast<char>(0);
      AppendU16(&s, 1638);  // 0.1 rad/s
    }
    s += static_cast<char>(kTick);
    s += static_cast<char>(2);  // 40 ms
    s += static_cast<char>(7);
  }
  return s;
}

}  // namespace

void omni::fuzz::Seeds(SeedList* seeds) {
  for (uint8_t mode = 0; mode < 8; ++mode) seeds->Add(Drive(mode, 24));
  seeds->Add(Drive(8, 24));  // odom_mapper
  // A garbled message on each channel between two scans.
  std::string junk = Drive(0, 6);
  for (uint8_t channel = 0; channel < 3; ++channel) {
    junk += static_cast<char>(kJunk);
    junk += static_cast<char>(channel);
    junk += static_cast<char>(12);
    junk += std::string(12, '\x7f');
  }
  seeds->Add(junk + Drive(0, 6).substr(1));
}
