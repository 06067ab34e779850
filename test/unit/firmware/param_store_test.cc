// The parameter store: the record's encoding and its checks, and SAVE_PARAMS over CAN with the
// firmware's rules (motors off only, read back before it counts, a bad record never applied).
#include "omni/firmware/param_store.h"

#include <cstring>
#include <vector>

#include <gtest/gtest.h>

#include "firmware_harness.h"

namespace omni::firmware {
namespace {

using testing::Harness;

Params Tuned() {
  Params p;
  p.kp = 0.31f;
  p.ki = 0.7f;
  p.watchdog_ms = 150;
  p.center_to_wheel_m = 0.2f;
  p.heartbeat_period_ms = 50;
  return p;
}

void ExpectSame(const Params& a, const Params& b) {
  for (uint16_t id = kParamKp; id <= kParamFirmwareVersion; ++id) {
    float va = 0, vb = 0;
    ASSERT_EQ(GetParam(a, id, &va), FwStatus::kOk) << id;
    ASSERT_EQ(GetParam(b, id, &vb), FwStatus::kOk) << id;
    EXPECT_EQ(va, vb) << "parameter " << id;
  }
}

TEST(ParamStore, Crc32IsTheIeeeOne) {
  const char* s = "123456789";
  EXPECT_EQ(Crc32(reinterpret_cast<const uint8_t*>(s), 9), 0xCBF43926u);  // zlib's check value
}

TEST(ParamStore, RecordRoundTripsEveryWritableParameter) {
  uint8_t buf[kParamStoreMaxBytes];
  const size_t len = EncodeParamStore(Tuned(), buf, sizeof(buf));
  ASSERT_EQ(len, 8u + 21u * 6u + 4u);
  EXPECT_EQ(EncodeParamStore(Tuned(), buf, len - 1), 0u) << "too small a buffer";
  Params p;
  int applied = 0;
  ASSERT_EQ(DecodeParamStore(buf, len, &p, &applied), FwStatus::kOk);
  EXPECT_EQ(applied, 21);
  ExpectSame(p, Tuned());
}

TEST(ParamStore, ABadRecordChangesNothing) {
  uint8_t good[kParamStoreMaxBytes];
  const size_t len = EncodeParamStore(Tuned(), good, sizeof(good));
  auto rejects = [&](const std::vector<uint8_t>& rec, const char* what) {
    Params p;
    EXPECT_EQ(DecodeParamStore(rec.data(), rec.size(), &p), FwStatus::kInvalid) << what;
    ExpectSame(p, Params{});
  };
  std::vector<uint8_t> r(good, good + len);
  r[20] ^= 0x01;
  rejects(r, "a flipped bit (CRC)");
  rejects(std::vector<uint8_t>(good, good + len - 1), "truncated");
  r.assign(good, good + len);
  r[0] = 'X';
  rejects(r, "wrong magic");
  r.assign(good, good + len);
  r[4] = 2;
  rejects(r, "a newer format");
  // A value out of its range, with a correct CRC: kp = -1.
  r.assign(good, good + len);
  const float bad = -1.f;
  std::memcpy(&r[8 + 2], &bad, 4);
  const uint32_t crc = Crc32(r.data(), len - 4);
  for (int i = 0; i < 4; ++i) r[len - 4 + i] = static_cast<uint8_t>(crc >> (8 * i));
  rejects(r, "kp out of range");
  Params p;
  EXPECT_EQ(DecodeParamStore(good, 0, &p), FwStatus::kUnknown) << "empty";
}

TEST(ParamStore, IdsOfANewerFirmwareAreSkipped) {
  uint8_t buf[kParamStoreMaxBytes];
  size_t len = EncodeParamStore(Tuned(), buf, sizeof(buf));
  // Append a record for id 200 (not known here) and fix count and CRC.
  std::vector<uint8_t> r(buf, buf + len - 4);
  r.insert(r.end(), {200, 0, 0, 0, 0x80, 0x3F});  // id 200 = 1.0f
  r[6] = 22;
  const uint32_t crc = Crc32(r.data(), r.size());
  for (int i = 0; i < 4; ++i) r.push_back(static_cast<uint8_t>(crc >> (8 * i)));
  Params p;
  int applied = 0;
  ASSERT_EQ(DecodeParamStore(r.data(), r.size(), &p, &applied), FwStatus::kOk);
  EXPECT_EQ(applied, 21);
  ExpectSame(p, Tuned());
}

// SAVE_PARAMS and the replies it gets, as the host sees them on CAN.
can::ParamStoreStatus Save(Harness* h, uint8_t action) {
  h->hal.tx.clear();
  h->Send(can::EncodeSaveParams(h->fw.params().node_id, action));
  h->Run(1);
  for (const CanFrame& f : h->hal.tx)
    if (can::CommandOf(f.id) == can::kParamStoreStatus) {
      can::ParamStoreStatus st;
      EXPECT_TRUE(can::DecodeParamStoreStatus(f, &st));
      return st;
    }
  ADD_FAILURE() << "no PARAM_STORE_STATUS";
  return {};
}

TEST(ParamStore, SavedParametersComeBackAtTheNextBoot) {
  Harness h;
  ASSERT_TRUE(h.ok);
  EXPECT_EQ(h.fw.param_store_state(), ParamStoreState::kEmpty);
  can::ParamRequest set;
  set.id = kParamKp;
  set.value = 0.42f;
  h.Send(can::EncodeSetParam(1, set));
  h.Run(1);
  auto st = Save(&h, can::kStoreSave);
  EXPECT_EQ(st.result, can::kStoreOk);
  EXPECT_EQ(st.boot_state, static_cast<uint8_t>(ParamStoreState::kEmpty));
  EXPECT_EQ(st.stored, 21);
  EXPECT_EQ(st.crc, Crc32(h.hal.param_store.data(), h.hal.param_store.size()));
  // Power cycle: the same store, the compiled defaults.
  Firmware again(&h.hal, Params{});
  ASSERT_EQ(again.Init(), FwStatus::kOk);
  EXPECT_EQ(again.param_store_state(), ParamStoreState::kLoaded);
  EXPECT_EQ(again.params_stored(), 21);
  EXPECT_EQ(again.params().kp, 0.42f);
  // Erase: the next boot has the defaults again.
  st = Save(&h, can::kStoreErase);
  EXPECT_EQ(st.result, can::kStoreOk);
  EXPECT_EQ(st.stored, 0);
  EXPECT_TRUE(h.hal.param_store.empty());
  Firmware third(&h.hal, Params{});
  ASSERT_EQ(third.Init(), FwStatus::kOk);
  EXPECT_EQ(third.param_store_state(), ParamStoreState::kEmpty);
  EXPECT_EQ(third.params().kp, Params{}.kp);
}

TEST(ParamStore, NotWhileTheMotorsRunAndNotWhenTheFlashFails) {
  Harness h;
  h.SendTwist(0.2f, 0.f, 0.f);
  h.Run(20);
  ASSERT_EQ(h.fw.state(), State::kRunning);
  auto st = Save(&h, can::kStoreSave);
  EXPECT_EQ(st.result, can::kStoreRefusedMoving);
  EXPECT_EQ(h.hal.param_store_writes, 0);
  EXPECT_NE(h.fw.fault_bits() & kFaultBadCommand, 0u);
  h.Run(1000);  // the watchdog stops it
  ASSERT_EQ(h.fw.state(), State::kIdle);
  h.hal.fail_param_store_writes = true;
  st = Save(&h, can::kStoreSave);
  EXPECT_EQ(st.result, can::kStoreWriteFailed);
  EXPECT_EQ(st.stored, 0);
  st = Save(&h, 7);
  EXPECT_EQ(st.result, can::kStoreBadAction);
  st = Save(&h, can::kStoreQuery);
  EXPECT_EQ(st.result, can::kStoreOk);
  // A board without a store says so.
  h.hal.param_store_enabled = false;
  EXPECT_EQ(Save(&h, can::kStoreSave).result, can::kStoreUnavailable);
}

TEST(ParamStore, ACorruptStoreBootsTheDefaultsAndSaysSo) {
  Harness h;
  uint8_t buf[kParamStoreMaxBytes];
  const size_t len = EncodeParamStore(Tuned(), buf, sizeof(buf));
  h.hal.param_store.assign(buf, buf + len);
  h.hal.param_store[30] ^= 0xFF;
  Firmware fw(&h.hal, Params{});
  ASSERT_EQ(fw.Init(), FwStatus::kOk);
  EXPECT_EQ(fw.param_store_state(), ParamStoreState::kCorrupt);
  ExpectSame(fw.params(), Params{});
  h.hal.param_store_enabled = false;
  Firmware none(&h.hal, Params{});
  ASSERT_EQ(none.Init(), FwStatus::kOk);
  EXPECT_EQ(none.param_store_state(), ParamStoreState::kNoStore);
}

TEST(CanProtocol, SaveParamsAndStoreStatusRoundTrip) {
  uint8_t action = 9;
  ASSERT_TRUE(can::DecodeSaveParams(can::EncodeSaveParams(3, can::kStoreErase), &action));
  EXPECT_EQ(action, can::kStoreErase);
  EXPECT_EQ(can::CommandOf(can::EncodeSaveParams(3, 0).id), can::kSaveParams);
  can::ParamStoreStatus in;
  in.action = can::kStoreSave;
  in.result = can::kStoreWriteFailed;
  in.boot_state = 2;
  in.stored = 21;
  in.crc = 0xDEADBEEF;
  can::ParamStoreStatus out;
  ASSERT_TRUE(can::DecodeParamStoreStatus(can::EncodeParamStoreStatus(3, in), &out));
  EXPECT_EQ(out.action, in.action);
  EXPECT_EQ(out.result, in.result);
  EXPECT_EQ(out.boot_state, in.boot_state);
  EXPECT_EQ(out.stored, in.stored);
  EXPECT_EQ(out.crc, in.crc);
  CanFrame shortf = can::EncodeSaveParams(3, 0);
  shortf.dlc = 2;
  EXPECT_FALSE(can::DecodeSaveParams(shortf, &action));
}

}  // namespace
}  // namespace omni::firmware
