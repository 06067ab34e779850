// The firmware's HAL on Linux: motors, encoders and sensors come from the Plant; CAN frames
// are queued in memory (the simulator process moves them to and from a CAN bus, the tests
// inject and inspect them directly).
#pragma once

#include <chrono>
#include <cmath>
#include <deque>

#include "omni/firmware/hal.h"
#include "plant.h"

namespace omni::firmware::sim {

class HostHal final : public Hal {
 public:
  explicit HostHal(Plant* plant) : plant_(plant) {}

  uint32_t MicrosNow() override {
    if (clock_us_ != nullptr) return static_cast<uint32_t>(*clock_us_);
    return static_cast<uint32_t>(std::chrono::duration_cast<std::chrono::microseconds>(
                                     std::chrono::steady_clock::now().time_since_epoch())
                                     .count());
  }
  uint16_t ReadEncoder(int w) override { return plant_->EncoderRaw(w); }
  void WritePwm(int w, float duty) override { plant_->SetDuty(w, duty); }
  void SetMotorEnable(bool on) override { plant_->SetEnabled(on); }
  float ReadCurrentA(int w) override {
    if (current_override_a_ >= 0.f && w == 0) return current_override_a_;
    // 12-bit ADC over +-20 A.
    const double lsb = 40.0 / 4096.0;
    return static_cast<float>(std::round(plant_->CurrentA(w) / lsb) * lsb);
  }
  float ReadBusVoltageV() override { return static_cast<float>(plant_->SupplyV()); }
  bool CanRead(CanFrame* f) override {
    if (rx.empty()) return false;
    *f = rx.front();
    rx.pop_front();
    return true;
  }
  FwStatus CanWrite(const CanFrame& f) override {
    if (tx.size() >= tx_capacity) return FwStatus::kBusy;
    tx.push_back(f);
    return FwStatus::kOk;
  }
  bool CanBusOff() override { return bus_off; }
  void SetStatusLed(bool on) override { led = on; }

  // Simulated time: when set, MicrosNow() reads *clock_us (a simulator that steps the firmware
  // in simulated time stays deterministic); nullptr: the steady clock.
  void UseClock(const int64_t* clock_us) { clock_us_ = clock_us; }

  // Test hooks.
  void OverrideCurrent(float amps) { current_override_a_ = amps; }  // wheel 0; < 0 = off

  std::deque<CanFrame> rx;  // frames for the firmware
  std::deque<CanFrame> tx;  // frames sent by the firmware
  size_t tx_capacity = 1024;
  bool bus_off = false;
  bool led = false;

 private:
  Plant* plant_;
  float current_override_a_ = -1.f;
  const int64_t* clock_us_ = nullptr;
};

}  // namespace omni::firmware::sim
