// A firmware core wired to the host plant, stepped in lock-step (1 kHz): the test fixture of
// every control-loop test.
#pragma once

#include <cmath>

#include "host_hal.h"
#include "omni/firmware/can_protocol.h"
#include "omni/firmware/firmware.h"
#include "plant.h"

namespace omni::firmware::testing {

struct Harness {
  explicit Harness(const Params& params = Params{}, const sim::PlantParams& plant_params = {})
      : plant(plant_params), hal(&plant), fw(&hal, params) {
    if (fw.Init() != FwStatus::kOk) ok = false;
  }
  // Runs `ms` control periods: firmware step, then the plant integrates one period.
  void Run(int ms) {
    for (int i = 0; i < ms; ++i) {
      fw.Step();
      plant.Advance(fw.params().control_period_us * 1e-6);
    }
  }
  void Send(const CanFrame& f) { hal.rx.push_back(f); }
  void SendWheelSpeeds(float a, float b, float c) {
    can::WheelTriple t;
    t.v[0] = a;
    t.v[1] = b;
    t.v[2] = c;
    Send(can::EncodeSetWheelSpeeds(fw.params().node_id, t));
  }
  void SendTwist(float vx, float vy, float w) {
    can::BodyTwist t{vx, vy, w, 0};
    Send(can::EncodeSetBodyTwist(fw.params().node_id, t));
  }
  bool MotorsOff() const {
    for (int w = 0; w < kNumWheels; ++w)
      if (fw.wheel(w).duty != 0.f) return false;
    return true;
  }

  sim::Plant plant;
  sim::HostHal hal;
  Firmware fw;
  bool ok = true;
};

}  // namespace omni::firmware::testing
