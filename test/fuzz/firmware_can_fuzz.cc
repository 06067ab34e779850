// The base controller's firmware against any CAN traffic and any parameter-store contents:
// the input is a store image (what flash held at boot) and then a script of received frames,
// control periods, bus-off spells and over-current readings, run on the host plant. After every
// control period the motor outputs must be finite and within the limits, the motors off in
// every state but RUNNING and STOPPING, and the watchdog must have stopped a base that hears
// no command. Seeds: well-formed command sequences made by our encoders.
#include <cmath>

#include "fuzz.h"
#include "host_hal.h"
#include "omni/firmware/can_protocol.h"
#include "omni/firmware/firmware.h"
#include "omni/firmware/param_store.h"
#include "plant.h"

namespace {

using namespace omni::firmware;

void CheckOutputs(const Firmware& fw, uint32_t quiet_ms) {
  const Params& p = fw.params();
  uint16_t bad = 0;
  OMNI_FUZZ_CHECK(ValidateParams(p, &bad) == FwStatus::kOk);
  const bool driving = fw.state() == State::kRunning || fw.state() == State::kStopping;
  for (int w = 0; w < kNumWheels; ++w) {
    const WheelState& s = fw.wheel(w);
    OMNI_FUZZ_CHECK(std::isfinite(s.duty) && std::fabs(s.duty) <= p.max_duty + 1e-6f);
    OMNI_FUZZ_CHECK(std::isfinite(s.setpoint_rad_s) && std::isfinite(s.target_rad_s));
    OMNI_FUZZ_CHECK(std::fabs(s.target_rad_s) <= p.max_wheel_speed_rad_s * 1.0001f);
    OMNI_FUZZ_CHECK(std::isfinite(s.speed_rad_s));
    if (!driving) OMNI_FUZZ_CHECK(s.duty == 0.f);
  }
  // No command for longer than the watchdog and a full stop at the slowest allowed deceleration
  // (35 rad/s at the lowest stop_decel is well under 10 s): the base must not be driving.
  if (quiet_ms > p.watchdog_ms + 10000) OMNI_FUZZ_CHECK(fw.state() != State::kRunning);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  omni::fuzz::Reader in(data, size);
  sim::Plant plant(sim::PlantParams{});
  sim::HostHal hal(&plant);
  const size_t store_len = in.U8();
  const std::string store = in.Bytes(store_len);
  hal.param_store.assign(store.begin(), store.end());
  Firmware fw(&hal, Params{});
  if (fw.Init() != FwStatus::kOk) return 0;  // a bad store must not stop the board booting
  uint32_t quiet_ms = 0;
  uint32_t total_ms = 0;
  while (!in.empty() && total_ms < 5000) {
    const uint8_t op = in.U8();
    if (op < 0xC0) {  // a received frame; mostly for this node, so commands get through
      CanFrame f;
      const uint16_t raw = in.U16();
      f.id = (op & 3) != 0 ? can::MakeId(fw.params().node_id, static_cast<uint8_t>(raw))
                           : static_cast<uint16_t>(raw & 0x7FF);
      f.dlc = (op & 4) != 0 ? static_cast<uint8_t>(in.U8() % 16) : uint8_t{8};
      for (uint8_t& b : f.data) b = in.U8();
      const uint8_t cmd = can::CommandOf(f.id);
      if (can::NodeOf(f.id) == fw.params().node_id &&
          (cmd == can::kSetBodyTwist || cmd == can::kSetWheelSpeeds))
        quiet_ms = 0;
      hal.rx.push_back(f);
    } else if (op < 0xF0) {  // run control periods
      const int ms = 1 + (op - 0xC0) * 4;
      for (int i = 0; i < ms; ++i) {
        fw.Step();
        plant.Advance(fw.params().control_period_us * 1e-6);
        ++quiet_ms;
        ++total_ms;
        hal.tx.clear();
        CheckOutputs(fw, quiet_ms);
      }
    } else if (op < 0xF8) {
      hal.bus_off = (op & 1) != 0;
    } else {
      hal.OverrideCurrent((op & 1) != 0 ? 50.f : -1.f);
    }
  }
  // Silence: the watchdog must stop whatever the script left running.
  for (int i = 0; i < 12000; ++i) {
    fw.Step();
    plant.Advance(fw.params().control_period_us * 1e-6);
    hal.tx.clear();
  }
  CheckOutputs(fw, quiet_ms + 12000);
  OMNI_FUZZ_CHECK(fw.state() != State::kRunning);
  return 0;
}

void omni::fuzz::Seeds(SeedList* seeds) {
  using namespace omni::firmware;
  auto frame = [](const CanFrame& f) {
    std::string s;
    s += static_cast<char>(0x01);  // op: addressed to this node, DLC 8
    s += static_cast<char>(can::CommandOf(f.id));
    s += static_cast<char>(0);
    s.append(reinterpret_cast<const char*>(f.data), 8);
    return s;
  };
  const uint8_t node = Params{}.node_id;
  uint8_t store[256];
  const size_t store_len = EncodeParamStore(Params{}, store, sizeof(store));
  for (bool with_store : {false, true}) {
    std::string s;
    if (with_store) {
      s += static_cast<char>(store_len);
      s.append(reinterpret_cast<const char*>(store), store_len);
    } else {
      s += static_cast<char>(0);
    }
    for (int k = 0; k < 10; ++k) {
      s += frame(can::EncodeSetBodyTwist(node, {0.3f, -0.1f, 0.5f, static_cast<uint16_t>(k)}));
      s += static_cast<char>(0xC0 + 5);  // 21 ms
    }
    can::WheelTriple t;
    t.v[0] = 5.f;
    t.v[1] = -5.f;
    t.v[2] = 2.f;
    s += frame(can::EncodeSetWheelSpeeds(node, t));
    s += static_cast<char>(0xEF);
    s += frame(can::EncodeSetParam(node, {2, 0.5f}));
    s += frame(can::EncodeGetParam(node, 2));
    s += frame(can::EncodeEstop(node));
    s += static_cast<char>(0xC8);
    s += frame(can::EncodeClearFaults(node));
    s += frame(can::EncodeSaveParams(node, can::kStoreSave));
    s += static_cast<char>(0xC8);
    seeds->Add(s);
  }
}
