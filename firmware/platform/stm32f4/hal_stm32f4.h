// Register-level HAL of the omni base controller board (STM32F405RG, 8 MHz crystal).
//
// Wiring (docs/firmware.md has the full table):
//   wheel 1: PWM TIM1_CH1 PA8, DIR PB12, encoder TIM2 (PA0/PA1), current ADC1_IN10 (PC0)
//   wheel 2: PWM TIM1_CH2 PA9, DIR PB13, encoder TIM3 (PA6/PA7), current ADC1_IN11 (PC1)
//   wheel 3: PWM TIM1_CH3 PA10, DIR PB14, encoder TIM4 (PB6/PB7), current ADC1_IN12 (PC2)
//   motor enable PB15 (high = drivers on), bus voltage ADC1_IN13 (PC3, 1:6 divider),
//   CAN1 RX PB8 / TX PB9 (1 Mbit/s), status LED PC13.
#pragma once

#include <cstdint>

#include "omni/firmware/hal.h"

namespace omni::firmware::stm32 {

// 168 MHz from the 8 MHz HSE; kHardware if the crystal or the PLL does not start.
[[nodiscard]] FwStatus InitClocks();
// SysTick at 1 kHz; the handler counts milliseconds.
void StartSysTick();
uint32_t Milliseconds();
// Independent watchdog (~50 ms): a hung loop resets the MCU, and the reset state of PB15
// (input, pulled down on the board) keeps the motors off.
void StartIndependentWatchdog();
void KickIndependentWatchdog();

class Stm32Hal final : public Hal {
 public:
  [[nodiscard]] FwStatus Init();
  uint32_t MicrosNow() override;
  uint16_t ReadEncoder(int w) override;
  void WritePwm(int w, float duty) override;
  void SetMotorEnable(bool on) override;
  float ReadCurrentA(int w) override;
  float ReadBusVoltageV() override;
  bool CanRead(CanFrame* frame) override;
  FwStatus CanWrite(const CanFrame& frame) override;
  uint32_t TakeCanRxOverruns() override;
  bool CanBusOff() override;
  void SetStatusLed(bool on) override;
  // Parameter store: flash sector 1 (16 KiB at 0x08004000, kept out of the image by the linker
  // script). The erase (~250-500 ms) and the programming run from RAM with interrupts off,
  // kicking the independent watchdog, so neither the flash stall nor the 50 ms watchdog hits.
  bool has_param_store() const override { return true; }
  uint32_t ParamStoreRead(uint8_t* buf, uint32_t cap) override;
  FwStatus ParamStoreWrite(const uint8_t* buf, uint32_t len) override;

 private:
  // MicrosNow() extends the 32-bit cycle counter (a wrap every 25.6 s at 168 MHz) into a
  // microsecond count that wraps at 2^32 us as Hal promises; it must be called at least once
  // per wrap, which the 1 kHz control step does.
  uint32_t last_cycles_ = 0;
  uint32_t micros_ = 0;
};

}  // namespace omni::firmware::stm32
