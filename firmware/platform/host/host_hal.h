// The firmware's HAL on Linux: motors, encoders and sensors come from the Plant; CAN frames
// are queued in memory (the simulator process moves them to and from a CAN bus, the tests
// inject and inspect them directly).
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <deque>
#include <string>
#include <vector>

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
  // A frame reaching the controller: queued, or lost and counted as an overrun when the
  // receive FIFO already holds rx_capacity frames (the board's FIFO is 3 deep; the simulator's
  // is deeper because it delivers a whole control period's frames at once).
  void Deliver(const CanFrame& f) {
    if (rx.size() >= rx_capacity) {
      ++rx_overruns_pending;
      return;
    }
    rx.push_back(f);
  }
  uint32_t TakeCanRxOverruns() override {
    const uint32_t n = rx_overruns_pending;
    rx_overruns_pending = 0;
    return n;
  }
  FwStatus CanWrite(const CanFrame& f) override {
    if (tx.size() >= tx_capacity) return FwStatus::kBusy;
    if (tx_mailboxes > 0) {
      // A frame holds its mailbox until it is on the wire; frames go out one after another.
      const uint32_t now = MicrosNow();
      while (!mailbox_free_at_.empty() && static_cast<int32_t>(now - mailbox_free_at_.front()) >= 0)
        mailbox_free_at_.pop_front();
      if (mailbox_free_at_.size() >= tx_mailboxes) return FwStatus::kBusy;
      const uint32_t start = mailbox_free_at_.empty() ? now : mailbox_free_at_.back();
      mailbox_free_at_.push_back(start + tx_frame_us);
    }
    tx.push_back(f);
    return FwStatus::kOk;
  }
  bool CanBusOff() override { return bus_off; }
  void SetStatusLed(bool on) override { led = on; }

  // Parameter store: `param_store` in memory, or a file when UseParamStoreFile() named one (so
  // omni-firmware-sim keeps its parameters across runs, as the board keeps them in flash).
  bool has_param_store() const override { return param_store_enabled; }
  uint32_t ParamStoreRead(uint8_t* buf, uint32_t cap) override {
    if (!param_store_file_.empty()) {
      param_store.clear();
      if (std::FILE* f = std::fopen(param_store_file_.c_str(), "rb")) {
        uint8_t b[512];
        const size_t n = std::fread(b, 1, sizeof(b), f);
        param_store.assign(b, b + n);
        std::fclose(f);
      }
    }
    const uint32_t n = static_cast<uint32_t>(std::min<size_t>(cap, param_store.size()));
    for (uint32_t i = 0; i < n; ++i) buf[i] = param_store[i];
    return n;
  }
  FwStatus ParamStoreWrite(const uint8_t* buf, uint32_t len) override {
    ++param_store_writes;
    if (fail_param_store_writes) return FwStatus::kHardware;
    param_store.assign(buf, buf + len);
    if (!param_store_file_.empty()) {
      std::FILE* f = std::fopen(param_store_file_.c_str(), "wb");
      if (f == nullptr) return FwStatus::kHardware;
      const bool ok = std::fwrite(buf, 1, len, f) == len;
      if (std::fclose(f) != 0 || !ok) return FwStatus::kHardware;
    }
    return FwStatus::kOk;
  }
  void UseParamStoreFile(std::string path) { param_store_file_ = std::move(path); }

  // Simulated time: when set, MicrosNow() reads *clock_us (a simulator that steps the firmware
  // in simulated time stays deterministic); nullptr: the steady clock.
  void UseClock(const int64_t* clock_us) { clock_us_ = clock_us; }

  // Test hooks.
  void OverrideCurrent(float amps) { current_override_a_ = amps; }  // wheel 0; < 0 = off

  std::deque<CanFrame> rx;  // frames for the firmware
  std::deque<CanFrame> tx;  // frames sent by the firmware
  size_t tx_capacity = 1024;
  // The board's transmit mailboxes (3 on the STM32's bxCAN), each held for tx_frame_us per
  // frame (an 8-byte frame with stuffing at 1 Mbit/s); 0: no limit but tx_capacity.
  size_t tx_mailboxes = 0;
  uint32_t tx_frame_us = 130;
  size_t rx_capacity = 32;
  uint32_t rx_overruns_pending = 0;
  bool bus_off = false;
  bool led = false;
  bool param_store_enabled = true;
  bool fail_param_store_writes = false;  // test hook: the "flash" refuses writes
  int param_store_writes = 0;
  std::vector<uint8_t> param_store;

 private:
  Plant* plant_;
  float current_override_a_ = -1.f;
  const int64_t* clock_us_ = nullptr;
  std::string param_store_file_;
  std::deque<uint32_t> mailbox_free_at_;  // when each busy mailbox frees, in send order
};

}  // namespace omni::firmware::sim
