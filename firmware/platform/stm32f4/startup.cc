// Reset and exception vectors of the STM32F405 (Cortex-M4F): copy .data, zero .bss, enable the
// FPU, run static constructors, call main. Every fault handler turns the motor drivers off.
#include <cstdint>

#include "regs.h"

extern "C" {
extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
extern void (*__init_array_start[])();
extern void (*__init_array_end[])();
int main();
void Reset_Handler();
void SysTick_Handler();
void Fault_Handler();
void Default_Handler();
// Pure virtual calls cannot happen in a correct build; if one does, stop the motors.
void __cxa_pure_virtual() { Fault_Handler(); }
}

namespace {
using omni::firmware::stm32::Reg;
}

extern "C" void Fault_Handler() {
  // Motor enable (PB15) low: the gate drivers go high-impedance.
  Reg(omni::firmware::stm32::kGpioB + omni::firmware::stm32::GPIO_BSRR) = 1u << (15 + 16);
  for (;;) {
  }
}

extern "C" void Default_Handler() { Fault_Handler(); }

extern "C" void Reset_Handler() {
  // FPU on (CP10, CP11 full access) before any float code runs.
  Reg(omni::firmware::stm32::kScbCpacr) |= (0xFu << 20);
  __asm volatile("dsb\n isb");
  uint32_t* src = &_sidata;
  for (uint32_t* dst = &_sdata; dst < &_edata;) *dst++ = *src++;
  for (uint32_t* dst = &_sbss; dst < &_ebss;) *dst++ = 0;
  for (void (**f)() = __init_array_start; f < __init_array_end; ++f) (*f)();
  main();
  Fault_Handler();
}

// Cortex-M core vectors + the STM32F405's 82 IRQ lines (all to the default handler: the
// firmware polls its peripherals from the 1 kHz loop and uses only SysTick).
using Vector = void (*)();
__attribute__((section(".isr_vector"), used)) const Vector kVectors[16 + 82] = {
    reinterpret_cast<Vector>(&_estack),
    Reset_Handler,
    Fault_Handler,  // NMI
    Fault_Handler,  // HardFault
    Fault_Handler,  // MemManage
    Fault_Handler,  // BusFault
    Fault_Handler,  // UsageFault
    nullptr,
    nullptr,
    nullptr,
    nullptr,
    Default_Handler,  // SVCall
    Default_Handler,  // DebugMon
    nullptr,
    Default_Handler,  // PendSV
    SysTick_Handler,
    // IRQ 0..81
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
    Default_Handler,
};
