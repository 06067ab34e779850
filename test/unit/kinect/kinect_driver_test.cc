// The Kinect driver without a device: a scripted DepthSource drives the state machine (frames,
// gaps, loss, reconnect) and the node (messages on a memq:// bus, heartbeat counters).
#include <cmath>
#include <deque>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "../common/test_paths.h"
#include "omni/bus/bus.h"
#include "omni/heartbeat_t.hpp"
#include "omni/kinect/depth_message.h"
#include "omni/kinect/kinect_driver.h"
#include "omni/kinect/kinect_node.h"

namespace omni::kinect {
namespace {

// What the fake does on each call: open succeeds or not; each Read returns the next step.
struct Script {
  std::deque<bool> opens;  // results of Open(); empty = succeed
  struct ReadStep {
    enum Kind { kDepth, kColor, kNothing, kError } kind = kDepth;
    int64_t index = -1;
    int64_t ts = 0;
  };
  std::deque<ReadStep> reads;  // empty = nothing ready
  int open_calls = 0;
  int close_calls = 0;
};

class FakeSource final : public DepthSource {
 public:
  explicit FakeSource(Script* s) : s_(s) {}
  Status Open() override {
    ++s_->open_calls;
    bool ok = true;
    if (!s_->opens.empty()) {
      ok = s_->opens.front();
      s_->opens.pop_front();
    }
    if (!ok) return MakeError(ErrorCode::kNotFound, "cannot open fake://cam");
    return Status::Ok();
  }
  Status Read(int, SourceFrames* out) override {
    out->has_depth = out->has_color = false;
    if (s_->reads.empty()) return Status::Ok();
    const Script::ReadStep r = s_->reads.front();
    s_->reads.pop_front();
    if (r.kind == Script::ReadStep::kError) {
      return MakeError(ErrorCode::kUnavailable, "fake://cam unplugged");
    }
    if (r.kind == Script::ReadStep::kDepth) {
      out->has_depth = true;
      DepthFrame& d = out->depth;
      d.width = 4;
      d.height = 3;
      d.depth_mm.resize(12);
      for (size_t i = 0; i < 12; ++i) d.depth_mm[i] = static_cast<uint16_t>(1000 + 7 * i);
      d.intrinsics = {5.0, 6.0, 1.5, 1.0};
      d.frame_index = r.index;
      d.device_timestamp_us = r.ts;
      d.registered_to_color = true;
    } else if (r.kind == Script::ReadStep::kColor) {
      out->has_color = true;
      ColorFrame& c = out->color;
      c.width = 2;
      c.height = 2;
      c.rgb = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12};
      c.intrinsics = {2.0, 2.0, 0.5, 0.5};
    }
    return Status::Ok();
  }
  void Close() override { ++s_->close_calls; }
  std::string Describe() const override { return "fake://cam"; }

 private:
  Script* s_;
};

Script::ReadStep Depth(int64_t index, int64_t ts = 0) {
  return {Script::ReadStep::kDepth, index, ts};
}

TEST(KinectIntrinsics, FromFieldOfView) {
  const double kDeg = M_PI / 180.0;
  const Intrinsics k = IntrinsicsFromFov(640, 480, 58.5 * kDeg, 45.6 * kDeg);
  EXPECT_NEAR(k.fx, 640.0 / (2.0 * std::tan(29.25 * kDeg)), 1e-9);
  EXPECT_NEAR(k.fx, 571.4, 0.5);
  EXPECT_NEAR(k.fy, 480.0 / (2.0 * std::tan(22.8 * kDeg)), 1e-9);
  EXPECT_DOUBLE_EQ(k.cx, 319.5);
  EXPECT_DOUBLE_EQ(k.cy, 239.5);
  // 90 degrees: f = w / 2.
  EXPECT_NEAR(IntrinsicsFromFov(100, 50, M_PI / 2, M_PI / 2).fx, 50.0, 1e-9);
  // Unknown field of view -> 0, not infinity.
  EXPECT_EQ(IntrinsicsFromFov(100, 50, 0, -1).fx, 0.0);
  EXPECT_EQ(IntrinsicsFromFov(100, 50, 0, -1).fy, 0.0);
}

TEST(KinectGapCounter, FrameIndexAndTimestampGaps) {
  GapCounter g(30.0);
  EXPECT_EQ(g.Add(1, 0), 0);
  EXPECT_EQ(g.Add(2, 33333), 0);
  EXPECT_EQ(g.Add(5, 133333), 2);  // 3 and 4 missing
  g.Reset();
  // No frame index: timestamps. One period ok, 1.4 periods ok, 3 periods = 2 missing.
  EXPECT_EQ(g.Add(-1, 0), 0);
  EXPECT_EQ(g.Add(-1, 33333), 0);
  EXPECT_EQ(g.Add(-1, 33333 + 46666), 0);
  EXPECT_EQ(g.Add(-1, 33333 + 46666 + 100000), 2);
}

TEST(KinectDriver, MissingDeviceIsAnErrorNamingIt) {
  Script s;
  s.opens = {false};
  ManualClock clock(1000000);
  KinectDriver d({}, std::make_unique<FakeSource>(&s), &clock);
  const Status st = d.Connect();
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("fake://cam"), std::string::npos) << st.error().message;
  EXPECT_EQ(d.counters().connect_failures, 1);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
}

TEST(KinectDriver, CountsFramesAndDrops) {
  Script s;
  s.reads = {Depth(1), {Script::ReadStep::kColor}, Depth(2), Depth(6), Depth(7)};
  ManualClock clock(1000000);
  KinectDriver d({}, std::make_unique<FakeSource>(&s), &clock);
  ASSERT_TRUE(d.Connect().ok());
  SourceFrames f;
  for (int i = 0; i < 5; ++i) d.Step(10, &f);
  EXPECT_EQ(d.counters().depth_frames, 4);
  EXPECT_EQ(d.counters().color_frames, 1);
  EXPECT_EQ(d.counters().dropped_frames, 3);
  EXPECT_EQ(d.state(), KinectState::kStreaming);
}

TEST(KinectDriver, VanishedDeviceIsRetriedAndComesBack) {
  Script s;
  s.reads = {Depth(1), {Script::ReadStep::kError}};
  s.opens = {true, false, true};  // first connect, one failed retry, then back
  ManualClock clock(1000000);
  KinectDriverOptions o;
  o.reconnect_interval_s = 1.0;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), &clock);
  ASSERT_TRUE(d.Connect().ok());
  SourceFrames f;
  d.Step(10, &f);
  EXPECT_TRUE(f.has_depth);
  d.Step(10, &f);  // the error
  EXPECT_FALSE(f.has_depth);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  EXPECT_EQ(d.counters().device_errors, 1);
  EXPECT_EQ(s.close_calls, 1);
  EXPECT_NE(d.status_text().find("unplugged"), std::string::npos);
  // Before the interval: no attempt.
  clock.Advance(500000);
  d.Step(10, &f);
  EXPECT_EQ(s.open_calls, 1);
  // After it: an attempt that fails, then one that succeeds an interval later.
  clock.Advance(600000);
  d.Step(10, &f);
  EXPECT_EQ(s.open_calls, 2);
  EXPECT_EQ(d.counters().connect_failures, 1);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  clock.Advance(1000000);
  s.reads = {Depth(1)};  // a fresh device restarts its frame counter: not a drop
  d.Step(10, &f);
  EXPECT_EQ(s.open_calls, 3);
  EXPECT_EQ(d.state(), KinectState::kStreaming);
  EXPECT_EQ(d.counters().reconnects, 1);
  EXPECT_TRUE(f.has_depth);
  EXPECT_EQ(d.counters().depth_frames, 2);
  EXPECT_EQ(d.counters().dropped_frames, 0);
}

TEST(KinectDriver, SilentDeviceTimesOut) {
  Script s;
  ManualClock clock(1000000);
  KinectDriverOptions o;
  o.data_timeout_s = 2.0;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), &clock);
  ASSERT_TRUE(d.Connect().ok());
  SourceFrames f;
  clock.Advance(1500000);
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kStreaming);
  clock.Advance(1000000);
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  EXPECT_EQ(d.counters().device_errors, 1);
  EXPECT_NE(d.status_text().find("fake://cam"), std::string::npos);
}

// The wall clock set back a minute (NTP at boot) while the device is silent: the silence is
// counted from the step, so a device that is gone is still found gone, 2 s later — not once the
// clock has caught up with where it was.
TEST(KinectDriver, SilentDeviceTimesOutAfterTheClockIsSetBack) {
  Script s;
  ManualClock clock(100000000);
  KinectDriverOptions o;
  o.data_timeout_s = 2.0;
  o.reconnect_interval_s = 1.0;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), &clock);
  ASSERT_TRUE(d.Connect().ok());
  SourceFrames f;
  clock.Set(40000000);  // 60 s back
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kStreaming);
  clock.Advance(2500000);
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  // Gone, and the clock set back again: the next attempt comes one interval later, not 60 s.
  clock.Set(clock.NowUtime() - 60000000);
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  clock.Advance(1000001);
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kStreaming) << d.status_text();
}

TEST(KinectNode, PublishesDepthColourAndHeartbeat) {
  auto bus = bus::Bus::Create("memq://");
  ASSERT_TRUE(bus.ok()) << bus.error().ToString();
  std::vector<omni::depth_image_t> depth;
  std::vector<omni::color_image_t> color;
  std::vector<omni::heartbeat_t> beats;
  (*bus)->Subscribe<omni::depth_image_t>(
      "DEPTH", [&](const omni::depth_image_t& m, int64_t) { depth.push_back(m); });
  (*bus)->Subscribe<omni::color_image_t>(
      "RGB", [&](const omni::color_image_t& m, int64_t) { color.push_back(m); });
  (*bus)->Subscribe<omni::heartbeat_t>(
      "HEARTBEAT", [&](const omni::heartbeat_t& m, int64_t) { beats.push_back(m); });

  Script s;
  s.reads = {Depth(1), {Script::ReadStep::kColor}, Depth(3), {Script::ReadStep::kError}};
  s.opens = {true, true};
  ManualClock clock(1000000);
  KinectDriverOptions o;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), &clock);
  ASSERT_TRUE(d.Connect().ok());
  KinectNodeOptions n;
  KinectNode node(bus->get(), &d, n, &clock);
  for (int i = 0; i < 4; ++i) {
    clock.Advance(100000);
    node.RunOnce(10);
  }
  clock.Advance(2000000);
  node.RunOnce(10);  // reconnects
  clock.Advance(1100000);
  node.RunOnce(10);  // heartbeat period passed
  while ((*bus)->HandleTimeout(0) > 0) {
  }
  ASSERT_EQ(depth.size(), 2u);
  EXPECT_EQ(depth[0].encoding, omni::depth_image_t::ENCODING_DELTA_ZLIB);
  EXPECT_EQ(depth[0].seq, 0);
  EXPECT_EQ(depth[1].seq, 1);
  EXPECT_EQ(depth[0].frame, "depth_optical");
  EXPECT_DOUBLE_EQ(depth[0].fx, 5.0);
  EXPECT_DOUBLE_EQ(depth[0].fy, 6.0);
  EXPECT_DOUBLE_EQ(depth[0].cx, 1.5);
  EXPECT_DOUBLE_EQ(depth[0].cy, 1.0);
  EXPECT_DOUBLE_EQ(depth[0].depth_scale, 1000.0);
  EXPECT_TRUE(depth[0].registered_to_color);
  std::vector<uint16_t> px;
  ASSERT_TRUE(ReadDepthMessage(depth[0], &px).ok());
  ASSERT_EQ(px.size(), 12u);
  EXPECT_EQ(px[11], 1000 + 77);
  ASSERT_EQ(color.size(), 1u);
  EXPECT_EQ(color[0].encoding, omni::color_image_t::ENCODING_RGB8);
  EXPECT_EQ(color[0].size, 12);
  EXPECT_EQ(color[0].data[11], 12);
  EXPECT_DOUBLE_EQ(color[0].fx, 2.0);
  ASSERT_FALSE(beats.empty());
  const omni::heartbeat_t& hb = beats.back();
  auto counter = [&](const std::string& name) -> int64_t {
    for (int i = 0; i < hb.num_counters; ++i) {
      if (hb.counter_names[static_cast<size_t>(i)] == name) {
        return hb.counter_values[static_cast<size_t>(i)];
      }
    }
    return -1;
  };
  EXPECT_EQ(counter("frames"), 2);
  EXPECT_EQ(counter("dropped_frames"), 1);
  EXPECT_EQ(counter("device_errors"), 1);
  EXPECT_EQ(counter("reconnects"), 1);
  EXPECT_EQ(counter("encode_errors"), 0);
  EXPECT_EQ(counter("depth_messages"), 2);
  EXPECT_EQ(counter("color_messages"), 1);
}

TEST(KinectNode, BadFrameIsAnEncodeErrorNotACrash) {
  DepthFrame f;
  f.width = 4;
  f.height = 3;
  f.depth_mm.resize(5);
  omni::depth_image_t m;
  const Status st = MakeDepthMessage(f, 1, 7, "d", DepthEncoding::kRaw, {}, &m);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("4x3"), std::string::npos);
}

TEST(KinectConfig, ShippedConfigLoadsAndMisspellingsAreErrors) {
  KinectDriverOptions d;
  KinectNodeOptions n;
  const Status st =
      LoadKinectOptions(std::string(OMNI_SOURCE_DIR) + "/config/kinect_driver.yaml", &d, &n);
  ASSERT_TRUE(st.ok()) << st.error().ToString();
  EXPECT_EQ(n.encoding, "DELTA_ZLIB");
  EXPECT_EQ(n.depth_channel, "DEPTH");
  EXPECT_EQ(n.color_channel, "RGB");
  DepthEncoding e;
  EXPECT_TRUE(ParseDepthEncoding(n.encoding, &e));
  EXPECT_EQ(e, DepthEncoding::kDeltaZlib);

  const std::string bad = testing::TempDir() + "/kinect_bad.yaml";
  {
    std::ofstream f(bad);
    f << "uri: Dummy\nreconect_interval_s: 1\n";
  }
  const Status st2 = LoadKinectOptions(bad, &d, &n);
  ASSERT_FALSE(st2.ok());
  EXPECT_NE(st2.error().message.find("reconect_interval_s"), std::string::npos)
      << st2.error().message;
}

}  // namespace
}  // namespace omni::kinect
