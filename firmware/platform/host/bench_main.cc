// omni-bench-firmware: host time of one firmware control step (./omni bench-firmware).
//
// Measures Firmware::Step() on the host HAL with all three wheels driven (the worst path:
// encoder read, speed estimate, kinematics, faults, PI loop, PWM write, feedback frames every
// 10th step). The Cortex-M4 estimate in docs/firmware.md is derived from this figure.
#include <benchmark/benchmark.h>

#include "host_hal.h"
#include "omni/firmware/firmware.h"
#include "plant.h"

namespace {

void BM_FirmwareStep(benchmark::State& state) {
  using namespace omni::firmware;
  sim::Plant plant{sim::PlantParams{}};
  sim::HostHal hal(&plant);
  Firmware fw(&hal, Params{});
  if (fw.Init() != FwStatus::kOk) {
    state.SkipWithError("init failed");
    return;
  }
  can::BodyTwist t{0.3f, 0.2f, 0.5f, 0};
  int64_t n = 0;
  for (auto _ : state) {
    if (n % 20 == 0) hal.rx.push_back(can::EncodeSetBodyTwist(1, t));
    fw.Step();
    state.PauseTiming();
    plant.Advance(0.001);
    hal.tx.clear();
    ++n;
    state.ResumeTiming();
  }
  state.counters["max_step_us"] = fw.counters().max_step_us;
}
BENCHMARK(BM_FirmwareStep);

// The step without the plant/timing pause overhead: kinematics + control only.
void BM_ControlOnly(benchmark::State& state) {
  using namespace omni::firmware;
  PidGains g{0.2f, 0.5f, 0.f, 0.026f, 0.95f};
  SpeedPid pid[3];
  SpeedEstimator est[3];
  for (auto& e : est) e.Reset(0);
  const omni::kinematics::OmniGeometry<float> geom{2.0943951f, 0.15f, 0.05f};
  int32_t pos = 0;
  for (auto _ : state) {
    pos += 3;
    omni::kinematics::WheelSpeeds<float> rim;
    for (int w = 0; w < 3; ++w) {
      const float s = est[w].Update(pos) * 4.363f;
      rim.v_m_s[w] = s * 0.05f;
      benchmark::DoNotOptimize(pid[w].Update(g, 10.f, s, 0.001f));
    }
    omni::kinematics::BodyTwist<float> body;
    benchmark::DoNotOptimize(omni::kinematics::WheelsToBody(geom, rim, &body));
    benchmark::DoNotOptimize(body);
  }
}
BENCHMARK(BM_ControlOnly);

}  // namespace

BENCHMARK_MAIN();
