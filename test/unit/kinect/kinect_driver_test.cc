// The Kinect driver without a device: a scripted DepthSource drives the state machine (frames,
// gaps, unusable frames, loss, reconnect, a device that opens but never sends) and the node
// (messages on a memq:// bus, heartbeat state and counters). Two ManualClocks stand for the
// wall clock (the node's stamps) and the monotonic clock (the driver's timeouts).
#include <cmath>
#include <deque>
#include <fstream>
#include <memory>
#include <string>
#include <utility>
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
    // kBadFrame: a frame the source cannot use (ErrorCode::kParse), the device stays open.
    enum Kind { kDepth, kColor, kNothing, kError, kBadFrame } kind = kDepth;
    int64_t index = -1;
    int64_t ts = 0;
  };
  std::deque<ReadStep> reads;  // empty = nothing ready
  std::string warning;         // Warning() after each open
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
  std::string Warning() const override { return s_->warning; }
  Status Read(int, SourceFrames* out) override {
    out->has_depth = out->has_color = false;
    if (s_->reads.empty()) return Status::Ok();
    const Script::ReadStep r = s_->reads.front();
    s_->reads.pop_front();
    if (r.kind == Script::ReadStep::kError) {
      return MakeError(ErrorCode::kUnavailable, "fake://cam unplugged");
    }
    if (r.kind == Script::ReadStep::kBadFrame) {
      return MakeError(ErrorCode::kParse, "fake://cam: depth frame of 5 bytes for 4x3");
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
const Script::ReadStep kColorStep{Script::ReadStep::kColor};
const Script::ReadStep kErrorStep{Script::ReadStep::kError};
const Script::ReadStep kBadStep{Script::ReadStep::kBadFrame};

// The driver's monotonic time read from a ManualClock.
MonotonicNow Mono(const ManualClock& c) {
  return [&c] { return c.NowUtime(); };
}

// A memq:// bus recording what the node publishes.
struct Recorder {
  Recorder() {
    auto b = bus::Bus::Create("memq://");
    EXPECT_TRUE(b.ok()) << b.error().ToString();
    bus = std::move(*b);
    bus->Subscribe<omni::depth_image_t>(
        "DEPTH", [this](const omni::depth_image_t& m, int64_t) { depth.push_back(m); });
    bus->Subscribe<omni::color_image_t>(
        "RGB", [this](const omni::color_image_t& m, int64_t) { color.push_back(m); });
    bus->Subscribe<omni::heartbeat_t>(
        "HEARTBEAT", [this](const omni::heartbeat_t& m, int64_t) { beats.push_back(m); });
  }
  void Drain() {
    while (bus->HandleTimeout(0) > 0) {
    }
  }
  std::unique_ptr<bus::Bus> bus;
  std::vector<omni::depth_image_t> depth;
  std::vector<omni::color_image_t> color;
  std::vector<omni::heartbeat_t> beats;
};

int64_t Counter(const omni::heartbeat_t& hb, const std::string& name) {
  for (int i = 0; i < hb.num_counters; ++i) {
    if (hb.counter_names[static_cast<size_t>(i)] == name) {
      return hb.counter_values[static_cast<size_t>(i)];
    }
  }
  return -1;
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
  KinectDriver d({}, std::make_unique<FakeSource>(&s), Mono(clock));
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
  KinectDriver d({}, std::make_unique<FakeSource>(&s), Mono(clock));
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
  KinectDriver d(o, std::make_unique<FakeSource>(&s), Mono(clock));
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

// A reopened device counts as a reconnect when it sends depth again, not when it opens.
TEST(KinectDriver, ReconnectIsCountedAtTheFirstDepthFrame) {
  Script s;
  s.reads = {Depth(1), kErrorStep};
  ManualClock clock(1000000);
  KinectDriver d({}, std::make_unique<FakeSource>(&s), Mono(clock));
  ASSERT_TRUE(d.Connect().ok());
  EXPECT_EQ(d.state(), KinectState::kOpening);
  SourceFrames f;
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kStreaming);
  EXPECT_EQ(d.counters().reconnects, 0);  // the first stream is no reconnect
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  clock.Advance(1100000);
  d.Step(10, &f);  // reopened, nothing read yet
  EXPECT_EQ(s.open_calls, 2);
  EXPECT_EQ(d.state(), KinectState::kOpening);
  EXPECT_EQ(d.counters().reconnects, 0);
  s.reads = {Depth(1)};
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kStreaming);
  EXPECT_EQ(d.counters().reconnects, 1);
}

TEST(KinectDriver, SilentDeviceTimesOut) {
  Script s;
  s.reads = {Depth(1)};
  ManualClock clock(1000000);
  KinectDriverOptions o;
  o.data_timeout_s = 2.0;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), Mono(clock));
  ASSERT_TRUE(d.Connect().ok());
  SourceFrames f;
  d.Step(10, &f);
  ASSERT_EQ(d.state(), KinectState::kStreaming);
  clock.Advance(1500000);
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kStreaming);
  clock.Advance(1000000);
  d.Step(10, &f);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  EXPECT_EQ(d.counters().device_errors, 1);
  EXPECT_NE(d.status_text().find("fake://cam"), std::string::npos);
}

// A device that opens and then never sends a frame (reported for the Kinect v1 on USB 3) is never
// reported as streaming: STARTING, then ERROR, with every opening that times out counted as a
// connect failure (not as a reconnect, nor as a device error).
TEST(KinectNode, DeviceThatOpensButNeverSendsIsNeverOk) {
  Recorder r;
  Script s;  // every open succeeds, every read returns nothing
  ManualClock wall(1000000000), mono(1000000);
  KinectDriverOptions o;
  o.data_timeout_s = 2.0;
  o.reconnect_interval_s = 1.0;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), Mono(mono));
  ASSERT_TRUE(d.Connect().ok());
  KinectNode node(r.bus.get(), &d, {}, &wall);
  for (int i = 0; i < 200; ++i) {  // 20 s
    node.RunOnce(10);
    EXPECT_NE(d.state(), KinectState::kStreaming) << "step " << i;
    wall.Advance(100000);
    mono.Advance(100000);
  }
  r.Drain();
  // STARTING while the first opening waits (2 s), ERROR from its timeout on, never OK.
  ASSERT_GE(r.beats.size(), 15u);
  EXPECT_EQ(r.beats.front().state, omni::heartbeat_t::STATE_STARTING);
  EXPECT_NE(r.beats.front().status_text.find("no depth frame yet"), std::string::npos)
      << r.beats.front().status_text;
  bool failed = false;
  for (size_t i = 0; i < r.beats.size(); ++i) {
    const omni::heartbeat_t& hb = r.beats[i];
    failed = failed || hb.state == omni::heartbeat_t::STATE_ERROR;
    EXPECT_EQ(hb.state, failed ? omni::heartbeat_t::STATE_ERROR : omni::heartbeat_t::STATE_STARTING)
        << "heartbeat " << i << ": " << hb.status_text;
  }
  EXPECT_EQ(r.beats.back().state, omni::heartbeat_t::STATE_ERROR);
  EXPECT_GE(s.open_calls, 6);  // an opening of 2 s and a wait of 1 s, over 20 s
  EXPECT_EQ(d.counters().connect_failures, s.open_calls - 1);
  EXPECT_EQ(d.counters().reconnects, 0);
  EXPECT_EQ(d.counters().device_errors, 0);
  EXPECT_EQ(d.counters().depth_frames, 0);
  EXPECT_TRUE(r.depth.empty());

  // When depth finally arrives: streaming, OK, and still no reconnect (it never streamed).
  s.reads = {Depth(1)};
  for (int i = 0; i < 30 && d.state() != KinectState::kStreaming; ++i) {
    wall.Advance(100000);
    mono.Advance(100000);
    node.RunOnce(10);
  }
  ASSERT_EQ(d.state(), KinectState::kStreaming) << d.status_text();
  wall.Advance(1100000);
  mono.Advance(100000);
  node.RunOnce(10);
  r.Drain();
  EXPECT_EQ(r.beats.back().state, omni::heartbeat_t::STATE_OK) << r.beats.back().status_text;
  EXPECT_EQ(Counter(r.beats.back(), "reconnects"), 0);
  EXPECT_EQ(r.depth.size(), 1u);
}

// An NTP step of the wall clock forward by more than data_timeout_s is no silence: the driver
// times on the monotonic clock, the messages keep the wall clock's stamps.
TEST(KinectNode, WallClockSteppedForwardIsNoSilentDevice) {
  Recorder r;
  Script s;
  s.reads = {Depth(1), kColorStep};
  ManualClock wall(1700000000000000), mono(5000000);
  KinectDriverOptions o;
  o.data_timeout_s = 2.0;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), Mono(mono));
  ASSERT_TRUE(d.Connect().ok());
  KinectNode node(r.bus.get(), &d, {}, &wall);
  node.RunOnce(10);
  ASSERT_EQ(d.state(), KinectState::kStreaming);
  wall.Advance(2100000);  // stepped forward
  mono.Advance(33000);    // one frame period went by
  node.RunOnce(10);       // a colour frame, no depth
  EXPECT_EQ(d.state(), KinectState::kStreaming) << d.status_text();
  mono.Advance(33000);
  node.RunOnce(10);  // nothing
  EXPECT_EQ(d.state(), KinectState::kStreaming) << d.status_text();
  EXPECT_EQ(d.counters().device_errors, 0);
  EXPECT_EQ(s.close_calls, 0);
  r.Drain();
  ASSERT_EQ(r.depth.size(), 1u);
  ASSERT_EQ(r.color.size(), 1u);
  EXPECT_EQ(r.depth[0].utime, 1700000000000000);
  EXPECT_EQ(r.color[0].utime, 1700000000000000 + 2100000);
  ASSERT_FALSE(r.beats.empty());
  EXPECT_EQ(r.beats.back().state, omni::heartbeat_t::STATE_OK);
}

// The wall clock set back a minute (NTP at boot) while the device is silent: the silence is
// timed on the monotonic clock, so a device that is gone is still found gone 2 s later (not
// once the wall clock has caught up with where it was), and after a second step back the next
// attempt still comes one interval later, not 60 s.
TEST(KinectNode, SilentDeviceTimesOutAfterTheClockIsSetBack) {
  Recorder r;
  Script s;
  s.reads = {Depth(1)};
  ManualClock wall(100000000), mono(1000000);
  KinectDriverOptions o;
  o.data_timeout_s = 2.0;
  o.reconnect_interval_s = 1.0;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), Mono(mono));
  ASSERT_TRUE(d.Connect().ok());
  KinectNode node(r.bus.get(), &d, {}, &wall);
  node.RunOnce(10);
  ASSERT_EQ(d.state(), KinectState::kStreaming);
  wall.Set(40000000);  // 60 s back
  mono.Advance(100000);
  node.RunOnce(10);
  EXPECT_EQ(d.state(), KinectState::kStreaming);
  wall.Advance(2500000);
  mono.Advance(2500000);
  node.RunOnce(10);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  EXPECT_EQ(d.counters().device_errors, 1);
  // Gone, and the wall clock set back again: the next attempt comes one interval later.
  wall.Set(wall.NowUtime() - 60000000);
  mono.Advance(100000);
  node.RunOnce(10);
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  EXPECT_EQ(s.open_calls, 1);
  wall.Advance(1000001);
  mono.Advance(1000001);
  s.reads = {Depth(1)};
  node.RunOnce(10);
  EXPECT_EQ(s.open_calls, 2);
  EXPECT_EQ(d.state(), KinectState::kStreaming) << d.status_text();
}

// A short frame or one in the wrong pixel format is skipped and counted; the device stays open.
TEST(KinectNode, UnusableFrameIsSkippedNotALoss) {
  Recorder r;
  Script s;
  s.reads = {Depth(1), kBadStep, Depth(2)};
  ManualClock wall(1000000000), mono(1000000);
  KinectDriver d({}, std::make_unique<FakeSource>(&s), Mono(mono));
  ASSERT_TRUE(d.Connect().ok());
  KinectNode node(r.bus.get(), &d, {}, &wall);
  for (int i = 0; i < 3; ++i) {
    node.RunOnce(10);
    EXPECT_EQ(d.state(), KinectState::kStreaming) << "step " << i;
    wall.Advance(33000);
    mono.Advance(33000);
  }
  wall.Advance(1100000);
  node.RunOnce(10);
  r.Drain();
  EXPECT_EQ(s.open_calls, 1);
  EXPECT_EQ(s.close_calls, 0);
  EXPECT_EQ(d.counters().bad_frames, 1);
  EXPECT_EQ(d.counters().dropped_frames, 0);
  EXPECT_EQ(r.depth.size(), 2u);
  ASSERT_FALSE(r.beats.empty());
  const omni::heartbeat_t& hb = r.beats.back();
  EXPECT_EQ(hb.state, omni::heartbeat_t::STATE_OK);
  EXPECT_EQ(Counter(hb, "bad_frames"), 1);
  EXPECT_EQ(Counter(hb, "reconnects"), 0);
  EXPECT_EQ(Counter(hb, "device_errors"), 0);
}

// Nothing but unusable frames is no depth: the data timeout still finds the device lost, and
// says why.
TEST(KinectDriver, OnlyUnusableFramesTimeOut) {
  Script s;
  s.reads = {Depth(1)};
  for (int i = 0; i < 30; ++i) s.reads.push_back(kBadStep);
  ManualClock clock(1000000);
  KinectDriverOptions o;
  o.data_timeout_s = 2.0;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), Mono(clock));
  ASSERT_TRUE(d.Connect().ok());
  SourceFrames f;
  d.Step(10, &f);
  for (int i = 0; i < 30 && d.state() == KinectState::kStreaming; ++i) {
    clock.Advance(100000);
    d.Step(10, &f);
  }
  EXPECT_EQ(d.state(), KinectState::kDisconnected);
  EXPECT_EQ(d.counters().device_errors, 1);
  EXPECT_EQ(d.counters().bad_frames, 21);  // up to 2.1 s after the last depth frame
  EXPECT_NE(d.status_text().find("last frame skipped: fake://cam: depth frame of 5 bytes"),
            std::string::npos)
      << d.status_text();
}

// The source opened without colour although colour was asked for (a device refusing RGB888):
// depth streams, the heartbeat says DEGRADED and why.
TEST(KinectNode, ColourOffIsDegradedNotOk) {
  Recorder r;
  Script s;
  s.reads = {Depth(1)};
  s.warning = "colour off: the device gives pixel format 205 and refuses RGB888";
  ManualClock wall(1000000000), mono(1000000);
  KinectDriver d({}, std::make_unique<FakeSource>(&s), Mono(mono));
  ASSERT_TRUE(d.Connect().ok());
  KinectNode node(r.bus.get(), &d, {}, &wall);
  node.RunOnce(10);
  ASSERT_EQ(d.state(), KinectState::kStreaming);
  r.Drain();
  ASSERT_EQ(r.beats.size(), 1u);
  EXPECT_EQ(r.beats[0].state, omni::heartbeat_t::STATE_DEGRADED);
  EXPECT_NE(r.beats[0].status_text.find("refuses RGB888"), std::string::npos)
      << r.beats[0].status_text;
  EXPECT_EQ(r.depth.size(), 1u);
}

// Colour that stops while depth goes on (a stalled colour endpoint): the heartbeat goes
// DEGRADED saying so, once past the data timeout, and OK again when colour comes back. Before,
// it said OK while the 3D map was built without colour.
TEST(KinectNode, ColourThatStopsWhileDepthGoesOnIsDegraded) {
  Recorder r;
  Script s;
  ManualClock wall(1000000000), mono(1000000);
  KinectDriver d({}, std::make_unique<FakeSource>(&s), Mono(mono));
  ASSERT_TRUE(d.Connect().ok());
  KinectNode node(r.bus.get(), &d, {}, &wall);
  int64_t index = 0;
  auto run = [&](bool colour, int frames) {
    for (int k = 0; k < frames; ++k) {
      s.reads.push_back(Depth(++index));
      if (colour) s.reads.push_back(kColorStep);
      while (!s.reads.empty()) node.RunOnce(0);
      mono.Advance(33333);
      wall.Advance(33333);
    }
    r.Drain();
    ASSERT_FALSE(r.beats.empty());
  };
  run(true, 45);
  EXPECT_EQ(r.beats.back().state, omni::heartbeat_t::STATE_OK) << r.beats.back().status_text;
  run(false, 90);  // 3 s, past the 2 s data timeout
  EXPECT_EQ(r.beats.back().state, omni::heartbeat_t::STATE_DEGRADED);
  EXPECT_NE(r.beats.back().status_text.find("no colour frame"), std::string::npos)
      << r.beats.back().status_text;
  EXPECT_EQ(Counter(r.beats.back(), "color_stalls"), 1);
  EXPECT_EQ(d.state(), KinectState::kStreaming) << "depth goes on: no reconnect";
  run(true, 45);
  EXPECT_EQ(r.beats.back().state, omni::heartbeat_t::STATE_OK) << r.beats.back().status_text;
  EXPECT_EQ(Counter(r.beats.back(), "color_stalls"), 1);
}

TEST(KinectNode, PublishesDepthColourAndHeartbeat) {
  Recorder r;
  Script s;
  // The device vanishes after three frames and sends depth again once reopened.
  s.reads = {Depth(1), kColorStep, Depth(3), kErrorStep, Depth(1)};
  s.opens = {true, true};
  ManualClock wall(1000000000), mono(1000000);
  KinectDriverOptions o;
  KinectDriver d(o, std::make_unique<FakeSource>(&s), Mono(mono));
  ASSERT_TRUE(d.Connect().ok());
  KinectNodeOptions n;
  KinectNode node(r.bus.get(), &d, n, &wall);
  for (int i = 0; i < 4; ++i) {
    wall.Advance(100000);
    mono.Advance(100000);
    node.RunOnce(10);
  }
  wall.Advance(2000000);
  mono.Advance(2000000);
  node.RunOnce(10);  // reconnects
  wall.Advance(1100000);
  mono.Advance(1100000);
  node.RunOnce(10);  // heartbeat period passed
  r.Drain();
  const auto& depth = r.depth;
  const auto& color = r.color;
  ASSERT_EQ(depth.size(), 3u);
  EXPECT_EQ(depth[0].encoding, omni::depth_image_t::ENCODING_DELTA_ZLIB);
  EXPECT_EQ(depth[0].seq, 0);
  EXPECT_EQ(depth[1].seq, 1);
  EXPECT_EQ(depth[2].seq, 2);
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
  ASSERT_FALSE(r.beats.empty());
  const omni::heartbeat_t& hb = r.beats.back();
  EXPECT_EQ(hb.state, omni::heartbeat_t::STATE_OK) << hb.status_text;
  EXPECT_EQ(Counter(hb, "frames"), 3);
  EXPECT_EQ(Counter(hb, "dropped_frames"), 1);  // frame 2; the reopened device restarts at 1
  EXPECT_EQ(Counter(hb, "bad_frames"), 0);
  EXPECT_EQ(Counter(hb, "device_errors"), 1);
  EXPECT_EQ(Counter(hb, "reconnects"), 1);
  EXPECT_EQ(Counter(hb, "connect_failures"), 0);
  EXPECT_EQ(Counter(hb, "encode_errors"), 0);
  EXPECT_EQ(Counter(hb, "depth_messages"), 3);
  EXPECT_EQ(Counter(hb, "color_messages"), 1);
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
