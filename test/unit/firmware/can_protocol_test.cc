// CAN protocol: golden vectors (bytes fixed by docs/firmware.md), round trips, and malformed
// frames against the firmware (counted, ignored, never a crash).
#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <vector>

#include "firmware_harness.h"
#include "omni/firmware/can_protocol.h"

namespace omni::firmware::can {
namespace {

std::vector<uint8_t> Bytes(const CanFrame& f) {
  return std::vector<uint8_t>(f.data, f.data + f.dlc);
}

TEST(CanGoldenTest, Ids) {
  EXPECT_EQ(MakeId(1, kHeartbeat), 0x021);
  EXPECT_EQ(MakeId(1, kSetBodyTwist), 0x024);
  EXPECT_EQ(MakeId(3, kHeartbeat), 0x061);
  EXPECT_EQ(MakeId(63, kDiagnostics), 0x7EE);
  EXPECT_EQ(NodeOf(0x7EE), 63);
  EXPECT_EQ(CommandOf(0x7EE), kDiagnostics);
}

TEST(CanGoldenTest, SetBodyTwist) {
  const CanFrame f = EncodeSetBodyTwist(1, BodyTwist{0.5f, -0.25f, 1.0f, 0x1234});
  EXPECT_EQ(f.id, 0x024);
  EXPECT_EQ(f.dlc, 8);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0xF4, 0x01, 0x06, 0xFF, 0xE8, 0x03, 0x34, 0x12}));
  BodyTwist t;
  ASSERT_TRUE(DecodeBodyTwist(f, &t));
  EXPECT_FLOAT_EQ(t.vx_m_s, 0.5f);
  EXPECT_FLOAT_EQ(t.vy_m_s, -0.25f);
  EXPECT_FLOAT_EQ(t.omega_rad_s, 1.0f);
  EXPECT_EQ(t.seq, 0x1234);
}

TEST(CanGoldenTest, SaturatesInsteadOfWrapping) {
  const CanFrame f = EncodeSetBodyTwist(1, BodyTwist{40.f, -40.f, 0.f / 0.f, 0});
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0xFF, 0x7F, 0x00, 0x80, 0x00, 0x00, 0x00, 0x00}));
}

TEST(CanGoldenTest, Heartbeat) {
  Heartbeat hb;
  hb.fault_bits = 0x22;
  hb.state = 5;
  hb.counter = 7;
  hb.bus_voltage_v = 12.0f;
  const CanFrame f = EncodeHeartbeat(3, hb);
  EXPECT_EQ(f.id, 0x061);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x22, 0x00, 0x00, 0x00, 0x05, 0x07, 0xE0, 0x2E}));
  Heartbeat back;
  ASSERT_TRUE(DecodeHeartbeat(f, &back));
  EXPECT_EQ(back.fault_bits, 0x22u);
  EXPECT_EQ(back.state, 5);
  EXPECT_EQ(back.counter, 7);
  EXPECT_FLOAT_EQ(back.bus_voltage_v, 12.0f);
}

TEST(CanGoldenTest, SetParam) {
  const CanFrame f = EncodeSetParam(1, ParamRequest{kParamWatchdogMs, 250.f});
  EXPECT_EQ(f.id, 0x027);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x09, 0x00, 0x00, 0x00, 0x00, 0x00, 0x7A, 0x43}));
}

TEST(CanGoldenTest, EncoderAndSpeedFeedback) {
  EncoderFeedback e;
  e.position_low16[0] = 0x0001;
  e.position_low16[1] = 0xFFFF;
  e.position_low16[2] = 0x8000;
  e.seq = 2;
  CanFrame f = EncodeEncoderFeedback(1, e);
  EXPECT_EQ(f.id, 0x029);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x01, 0x00, 0xFF, 0xFF, 0x00, 0x80, 0x02, 0x00}));
  WheelTriple s;
  s.v[0] = 1.0f;
  s.v[1] = -2.5f;
  s.v[2] = 0.01f;
  s.seq = 0x0102;
  f = EncodeSpeedFeedback(1, s);
  EXPECT_EQ(f.id, 0x02A);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x64, 0x00, 0x06, 0xFF, 0x01, 0x00, 0x02, 0x01}));
}

TEST(CanGoldenTest, EstopAndClear) {
  EXPECT_EQ(EncodeEstop(1).id, 0x022);
  EXPECT_EQ(Bytes(EncodeEstop(1)), std::vector<uint8_t>(8, 0));
  EXPECT_EQ(EncodeClearFaults(2).id, 0x043);
}

TEST(CanGoldenTest, WrongLengthRejectedByDecoders) {
  CanFrame f = EncodeSetBodyTwist(1, BodyTwist{});
  f.dlc = 7;
  BodyTwist t;
  EXPECT_FALSE(DecodeBodyTwist(f, &t));
  Heartbeat hb;
  EXPECT_FALSE(DecodeHeartbeat(f, &hb));
}

TEST(CanGoldenTest, Diagnostics2SaturatesItsCounts) {
  Diagnostics2 d;
  d.watchdog_trips = 3;
  d.commands_limited = SaturateCount(70000);
  d.rx_overruns = 0x0102;
  const CanFrame f = EncodeDiagnostics2(1, d);
  EXPECT_EQ(f.id, 0x031);
  EXPECT_EQ(Bytes(f), (std::vector<uint8_t>{0x03, 0x00, 0xFF, 0xFF, 0x02, 0x01, 0x00, 0x00}));
  Diagnostics2 back;
  ASSERT_TRUE(DecodeDiagnostics2(f, &back));
  EXPECT_EQ(back.watchdog_trips, 3);
  EXPECT_EQ(back.commands_limited, 65535);
  EXPECT_EQ(back.rx_overruns, 0x0102);
  CanFrame short_frame = f;
  short_frame.dlc = 7;
  EXPECT_FALSE(DecodeDiagnostics2(short_frame, &back));
}

// The counts DIAGNOSTICS had no room for leave the board: watchdog trips, commands limited to
// max_wheel_speed, and frames the receive FIFO had to drop.
TEST(CanFirmwareTest, SecondDiagnosticsFrameCarriesWatchdogLimitAndOverruns) {
  testing::Harness h;
  ASSERT_TRUE(h.ok);
  h.SendTwist(0.f, 0.f, 50.f);  // far beyond max_wheel_speed: limited
  h.Run(2);
  for (int i = 0; i < 40; ++i) h.hal.Deliver(EncodeGetParam(1, kParamWatchdogMs));  // a flood
  EXPECT_EQ(h.hal.rx.size(), h.hal.rx_capacity);
  h.Run(1000);  // commands stop: the watchdog trips
  Diagnostics2 last;
  int seen = 0;
  for (const CanFrame& f : h.hal.tx) {
    if (CommandOf(f.id) != kDiagnostics2) continue;
    ASSERT_TRUE(DecodeDiagnostics2(f, &last));
    ++seen;
  }
  EXPECT_GE(seen, 1);
  EXPECT_EQ(last.watchdog_trips, 1);
  EXPECT_EQ(last.commands_limited, 1);
  EXPECT_EQ(last.rx_overruns, 40 - h.hal.rx_capacity);
  EXPECT_EQ(h.fw.counters().rx_overruns, 40 - h.hal.rx_capacity);
}

// The board's controller has three transmit mailboxes, and a frame holds one for ~130 us on
// the wire, while a feedback step writes four frames and every 100 ms six or seven. Without a
// queue the fourth onwards was dropped every time: BODY_TWIST_FEEDBACK every 10 ms, and
// HEARTBEAT, SETPOINT_FEEDBACK and both DIAGNOSTICS frames always, so on the board the bridge
// never heard a heartbeat (review finding 2026-12-06; the simulator's HAL took any number).
TEST(CanFirmwareTest, EveryFrameGetsThroughThreeMailboxes) {
  testing::Harness h;
  int64_t clock_us = 0;
  h.hal.UseClock(&clock_us);
  h.hal.tx_mailboxes = 3;
  int heartbeats = 0, twists = 0, encoders = 0, diagnostics = 0;
  for (int ms = 0; ms < 1000; ++ms) {
    h.fw.Step();
    h.plant.Advance(h.fw.params().control_period_us * 1e-6);
    clock_us += h.fw.params().control_period_us;
    for (const CanFrame& f : h.hal.tx) {
      heartbeats += CommandOf(f.id) == kHeartbeat;
      twists += CommandOf(f.id) == kBodyTwistFeedback;
      encoders += CommandOf(f.id) == kEncoderFeedback;
      diagnostics += CommandOf(f.id) == kDiagnostics || CommandOf(f.id) == kDiagnostics2;
    }
    h.hal.tx.clear();
  }
  EXPECT_GE(heartbeats, 9);
  EXPECT_GE(twists, 99);
  EXPECT_GE(encoders, 99);
  EXPECT_GE(diagnostics, 1);
  EXPECT_EQ(h.fw.counters().tx_dropped, 0u);
  // A bus-off controller: what is queued is dropped and counted, nothing is sent.
  h.hal.bus_off = true;
  for (int ms = 0; ms < 100; ++ms) {
    h.fw.Step();
    clock_us += h.fw.params().control_period_us;
  }
  EXPECT_TRUE(h.hal.tx.empty());
  EXPECT_GT(h.fw.counters().tx_dropped, 40u);
}

TEST(CanFirmwareTest, MalformedFramesCountedAndIgnored) {
  testing::Harness h;
  CanFrame bad_len = EncodeSetBodyTwist(1, BodyTwist{0.3f, 0.f, 0.f, 0});
  bad_len.dlc = 6;
  h.Send(bad_len);
  CanFrame unknown;
  unknown.id = MakeId(1, 0x1F);
  unknown.dlc = 8;
  h.Send(unknown);
  CanFrame own_feedback = EncodeHeartbeat(1, Heartbeat{});  // fw -> host id: not a command
  h.Send(own_feedback);
  CanFrame other_node = EncodeSetBodyTwist(2, BodyTwist{0.3f, 0.f, 0.f, 0});
  h.Send(other_node);
  CanFrame remote;  // an RTR or extended-id frame as the HAL hands it over
  remote.id = kForeignFrameId;
  remote.dlc = 0;
  h.Send(remote);
  h.Run(1);
  EXPECT_EQ(h.fw.counters().rx_bad_length, 1u);
  EXPECT_EQ(h.fw.counters().rx_unknown, 3u) << "a remote/extended frame is counted on node 1 too";
  EXPECT_EQ(h.fw.counters().rx_frames, 4u);  // the other node's frame is not ours
  EXPECT_EQ(h.fw.state(), State::kIdle);
  EXPECT_TRUE(h.MotorsOff());
}

TEST(CanFirmwareTest, RandomFramesNeverCrash) {
  testing::Harness h;
  std::mt19937 rng(42);
  for (int i = 0; i < 20000; ++i) {
    CanFrame f;
    f.id = static_cast<uint16_t>(rng() & 0x7FF);
    f.dlc = static_cast<uint8_t>(rng() % 16);  // also illegal DLCs > 8
    for (auto& b : f.data) b = static_cast<uint8_t>(rng());
    h.Send(f);
    if (i % 8 == 0) h.Run(1);
  }
  h.Run(10);
  // Whatever arrived, outputs stay clamped and finite.
  for (int w = 0; w < 3; ++w) {
    EXPECT_LE(std::fabs(h.fw.wheel(w).duty), h.fw.params().max_duty);
    EXPECT_TRUE(std::isfinite(h.fw.wheel(w).setpoint_rad_s));
  }
  EXPECT_GT(h.fw.counters().rx_unknown + h.fw.counters().rx_bad_length, 0u);
}

TEST(CanFirmwareTest, GetAndSetParameters) {
  testing::Harness h;
  h.Send(EncodeSetParam(1, ParamRequest{kParamWatchdogMs, 120.f}));
  h.Send(EncodeSetParam(1, ParamRequest{kParamKp, -1.f}));                // out of range
  h.Send(EncodeSetParam(1, ParamRequest{kParamKi, 0.f / 0.f}));           // NaN
  h.Send(EncodeSetParam(1, ParamRequest{kParamControlPeriodUs, 500.f}));  // read-only
  h.Send(EncodeGetParam(1, 999));                                         // unknown
  h.Send(EncodeGetParam(1, kParamWheelRadius));
  h.hal.tx.clear();
  h.Run(1);
  std::vector<ParamReply> replies;
  for (const CanFrame& f : h.hal.tx) {
    if (CommandOf(f.id) != kParamValue) continue;
    ParamReply r;
    ASSERT_TRUE(DecodeParamReply(f, &r));
    replies.push_back(r);
  }
  ASSERT_EQ(replies.size(), 6u);
  EXPECT_EQ(replies[0].result, kParamOk);
  EXPECT_FLOAT_EQ(replies[0].value, 120.f);
  EXPECT_EQ(h.fw.params().watchdog_ms, 120u);
  EXPECT_EQ(replies[1].result, kParamOutOfRange);
  EXPECT_FLOAT_EQ(replies[1].value, Params{}.kp);
  EXPECT_EQ(replies[2].result, kParamOutOfRange);
  EXPECT_EQ(replies[3].result, kParamReadOnly);
  EXPECT_EQ(replies[4].result, kParamUnknown);
  EXPECT_EQ(replies[5].result, kParamOk);
  EXPECT_FLOAT_EQ(replies[5].value, 0.05f);
  EXPECT_TRUE(h.fw.fault_bits() & kFaultBadCommand);
  // Each answer says what it answers: the four SETs, then the two GETs.
  for (int i = 0; i < 6; ++i) EXPECT_EQ(replies[i].of_set, i < 4 ? 1 : 0) << i;
}

TEST(CanFirmwareTest, FeedbackIsCyclicWithSequence) {
  testing::Harness h;
  h.hal.tx.clear();
  h.Run(100);
  int enc = 0, hb = 0;
  uint16_t last_seq = 0;
  for (const CanFrame& f : h.hal.tx) {
    if (CommandOf(f.id) == kEncoderFeedback) {
      EncoderFeedback e;
      ASSERT_TRUE(DecodeEncoderFeedback(f, &e));
      if (enc > 0) {
        EXPECT_EQ(static_cast<uint16_t>(last_seq + 1), e.seq);
      }
      last_seq = e.seq;
      ++enc;
    }
    if (CommandOf(f.id) == kHeartbeat) ++hb;
  }
  EXPECT_EQ(enc, 10);  // 10 ms period
  EXPECT_EQ(hb, 1);    // 100 ms period
}

}  // namespace
}  // namespace omni::firmware::can
