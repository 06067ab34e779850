// Board entry point: clocks, peripherals, then the 1 kHz control loop paced by SysTick.
#include "hal_stm32f4.h"
#include "omni/firmware/firmware.h"

namespace {
using namespace omni::firmware;

stm32::Stm32Hal g_hal;
Firmware g_firmware(&g_hal, Params{});

[[noreturn]] void Halt(uint32_t blink_ms) {
  g_hal.SetMotorEnable(false);
  for (;;) {
    g_hal.SetStatusLed((stm32::Milliseconds() / blink_ms) % 2 == 0);
  }
}
}  // namespace

int main() {
  if (stm32::InitClocks() != FwStatus::kOk) Halt(50);
  stm32::StartSysTick();
  if (g_hal.Init() != FwStatus::kOk) Halt(100);
  if (g_firmware.Init() != FwStatus::kOk) Halt(200);
  stm32::StartIndependentWatchdog();
  uint32_t last = stm32::Milliseconds();
  for (;;) {
    while (stm32::Milliseconds() == last) __asm volatile("wfi");
    last = stm32::Milliseconds();
    g_firmware.Step();
    stm32::KickIndependentWatchdog();
  }
}
