#include "hal_stm32f4.h"

#include "omni/firmware/can_protocol.h"
#include "omni/firmware/param_store.h"
#include "regs.h"

namespace omni::firmware::stm32 {
namespace {

volatile uint32_t g_ms = 0;

constexpr uint32_t kSysClockHz = 168000000;
constexpr uint32_t kPwmArr = 8400 - 1;  // TIM1 at 168 MHz: 20 kHz PWM
constexpr uint32_t kEncoderTimers[kNumWheels] = {kTim2, kTim3, kTim4};
constexpr uint32_t kCurrentChannels[kNumWheels] = {10, 11, 12};
constexpr uint32_t kBusVoltageChannel = 13;
constexpr float kAdcVolts = 3.3f / 4095.f;
constexpr float kCurrentZeroV = 1.65f;   // bidirectional hall sensor, 0 A at mid-supply
constexpr float kCurrentVPerA = 0.110f;  // 110 mV/A
constexpr float kBusDivider = 6.f;

bool WaitFor(uint32_t addr, uint32_t mask, uint32_t value, uint32_t spins = 1000000) {
  while (spins-- > 0) {
    if ((Reg(addr) & mask) == value) return true;
  }
  return false;
}

void PinMode(uint32_t port, int pin, uint32_t mode) {  // 0 in, 1 out, 2 alternate, 3 analog
  Reg(port + GPIO_MODER) = (Reg(port + GPIO_MODER) & ~(3u << (2 * pin))) | (mode << (2 * pin));
  Reg(port + GPIO_OSPEEDR) |= (2u << (2 * pin));
}
void PinAf(uint32_t port, int pin, uint32_t af) {
  PinMode(port, pin, 2);
  const uint32_t reg = port + (pin < 8 ? GPIO_AFRL : GPIO_AFRH);
  const int shift = 4 * (pin % 8);
  Reg(reg) = (Reg(reg) & ~(0xFu << shift)) | (af << shift);
}
void PinWrite(uint32_t port, int pin, bool high) {
  Reg(port + GPIO_BSRR) = high ? (1u << pin) : (1u << (pin + 16));
}

float AdcRead(uint32_t channel) {
  Reg(ADC_SQR3) = channel;
  Reg(ADC_CR2) |= (1u << 30);  // SWSTART
  if (!WaitFor(ADC_SR, 1u << 1, 1u << 1, 2000)) return 0.f;
  return static_cast<float>(Reg(ADC_DR) & 0xFFF) * kAdcVolts;
}

}  // namespace

extern "C" void SysTick_Handler() { g_ms = g_ms + 1; }

FwStatus InitClocks() {
  Reg(RCC_CR) |= (1u << 16);  // HSEON
  if (!WaitFor(RCC_CR, 1u << 17, 1u << 17)) return FwStatus::kHardware;
  // PLL: 8 MHz / M=8 * N=336 / P=2 = 168 MHz, / Q=7 = 48 MHz.
  Reg(RCC_PLLCFGR) = 8u | (336u << 6) | (0u << 16) | (1u << 22) | (7u << 24);
  Reg(RCC_CR) |= (1u << 24);  // PLLON
  if (!WaitFor(RCC_CR, 1u << 25, 1u << 25)) return FwStatus::kHardware;
  // 5 wait states at 168 MHz / 3.3 V, prefetch and caches on.
  Reg(FLASH_ACR) = 5u | (1u << 8) | (1u << 9) | (1u << 10);
  // AHB /1, APB1 /4 (42 MHz), APB2 /2 (84 MHz), system clock = PLL.
  Reg(RCC_CFGR) = (Reg(RCC_CFGR) & ~0xFCF3u) | (5u << 10) | (4u << 13) | 2u;
  if (!WaitFor(RCC_CFGR, 0xCu, 0x8u)) return FwStatus::kHardware;
  // Cycle counter for step timing.
  Reg(kDemcr) |= (1u << 24);
  Reg(kDwtCyccnt) = 0;
  Reg(kDwtCtrl) |= 1u;
  return FwStatus::kOk;
}

void StartSysTick() {
  Reg(SYST_RVR) = kSysClockHz / 1000 - 1;
  Reg(SYST_CVR) = 0;
  Reg(SYST_CSR) = 7u;  // processor clock, interrupt, enable
}

uint32_t Milliseconds() { return g_ms; }

void StartIndependentWatchdog() {
  Reg(IWDG_KR) = 0x5555;  // unlock PR/RLR
  Reg(IWDG_PR) = 0;       // LSI 32 kHz / 4 = 8 kHz
  Reg(IWDG_RLR) = 400;    // 50 ms
  Reg(IWDG_KR) = 0xCCCC;  // start
}
void KickIndependentWatchdog() { Reg(IWDG_KR) = 0xAAAA; }

FwStatus Stm32Hal::Init() {
  Reg(RCC_AHB1ENR) |= 0x7u;                                            // GPIOA, B, C
  Reg(RCC_APB1ENR) |= (1u << 0) | (1u << 1) | (1u << 2) | (1u << 25);  // TIM2-4, CAN1
  Reg(RCC_APB2ENR) |= (1u << 0) | (1u << 8);                           // TIM1, ADC1

  // Motor enable off first, then direction pins and LED.
  PinWrite(kGpioB, 15, false);
  PinMode(kGpioB, 15, 1);
  for (int pin = 12; pin <= 14; ++pin) PinMode(kGpioB, pin, 1);
  PinMode(kGpioC, 13, 1);

  // PWM: TIM1 CH1-3 on PA8-10 (AF1), PWM mode 1 with preload, 20 kHz.
  for (int pin = 8; pin <= 10; ++pin) PinAf(kGpioA, pin, 1);
  Reg(kTim1 + TIM_PSC) = 0;
  Reg(kTim1 + TIM_ARR) = kPwmArr;
  Reg(kTim1 + TIM_CCMR1) = (6u << 4) | (1u << 3) | (6u << 12) | (1u << 11);
  Reg(kTim1 + TIM_CCMR2) = (6u << 4) | (1u << 3);
  Reg(kTim1 + TIM_CCER) = (1u << 0) | (1u << 4) | (1u << 8);
  for (int w = 0; w < kNumWheels; ++w) Reg(kTim1 + TIM_CCR1 + 4 * w) = 0;
  Reg(kTim1 + TIM_BDTR) = (1u << 15);  // MOE
  Reg(kTim1 + TIM_EGR) = 1u;
  Reg(kTim1 + TIM_CR1) = (1u << 7) | 1u;

  // Encoders: TIM2 (PA0/PA1, AF1), TIM3 (PA6/PA7, AF2), TIM4 (PB6/PB7, AF2); x4 encoder mode 3,
  // input filter N=8 against motor noise.
  PinAf(kGpioA, 0, 1);
  PinAf(kGpioA, 1, 1);
  PinAf(kGpioA, 6, 2);
  PinAf(kGpioA, 7, 2);
  PinAf(kGpioB, 6, 2);
  PinAf(kGpioB, 7, 2);
  for (uint32_t t : kEncoderTimers) {
    Reg(t + TIM_CCMR1) = 1u | (3u << 4) | (1u << 8) | (3u << 12);
    Reg(t + TIM_SMCR) = 3u;
    Reg(t + TIM_ARR) = 0xFFFFFFFFu;  // TIM2 is 32-bit; TIM3/4 keep the low 16 bits
    Reg(t + TIM_CR1) = 1u;
  }

  // ADC1: PC0-PC3 analog, ADCCLK = 84/4 MHz, 28-cycle sampling on channels 10-13 (the
  // sensors are low-impedance); 4 polled conversions take ~7.6 us of the step.
  for (int pin = 0; pin <= 3; ++pin) PinMode(kGpioC, pin, 3);
  Reg(ADC_CCR) = (1u << 16);
  Reg(ADC_SMPR1) = (2u << 0) | (2u << 3) | (2u << 6) | (2u << 9);  // 28 cycles
  Reg(ADC_SQR1) = 0;                                               // one conversion per start
  Reg(ADC_CR2) = 1u;                                               // ADON

  // CAN1 on PB8/PB9 (AF9), 1 Mbit/s from 42 MHz: BRP 3, BS1 11 tq, BS2 2 tq, SJW 1 (87.5 %).
  PinAf(kGpioB, 8, 9);
  PinAf(kGpioB, 9, 9);
  Reg(CAN_MCR) = (1u << 0) | (1u << 6) | (1u << 2);  // INRQ, ABOM (auto bus-off recovery), TXFP
  if (!WaitFor(CAN_MSR, 1u, 1u)) return FwStatus::kHardware;
  Reg(CAN_BTR) = (0u << 24) | (1u << 20) | (10u << 16) | 2u;
  Reg(CAN_FMR) |= 1u;     // filter init
  Reg(CAN_FM1R) &= ~1u;   // bank 0: mask mode
  Reg(CAN_FS1R) |= 1u;    // 32-bit
  Reg(CAN_FFA1R) &= ~1u;  // -> FIFO 0
  Reg(CAN_F0R1) = 0;      // id
  Reg(CAN_F0R2) = 0;      // mask 0: accept all (the core filters by node id)
  Reg(CAN_FA1R) |= 1u;
  Reg(CAN_FMR) &= ~1u;
  Reg(CAN_MCR) &= ~1u;  // leave init
  if (!WaitFor(CAN_MSR, 1u, 0u)) return FwStatus::kHardware;
  return FwStatus::kOk;
}

uint32_t Stm32Hal::MicrosNow() {
  // Dividing the raw counter would wrap at 2^32 / 168 us = 25.6 s, not at 2^32 us, and a step
  // timed across that wrap would read as 4.27e9 us (max_step_us stuck at 65535). Whole
  // microseconds elapsed are added instead; the remainder cycles carry to the next call.
  constexpr uint32_t kCyclesPerUs = kSysClockHz / 1000000;
  const uint32_t cycles = Reg(kDwtCyccnt);
  const uint32_t us = (cycles - last_cycles_) / kCyclesPerUs;
  last_cycles_ += us * kCyclesPerUs;
  micros_ += us;
  return micros_;
}

uint16_t Stm32Hal::ReadEncoder(int w) {
  return static_cast<uint16_t>(Reg(kEncoderTimers[w] + TIM_CNT) & 0xFFFF);
}

void Stm32Hal::WritePwm(int w, float duty) {
  if (!(duty == duty)) duty = 0.f;
  const bool reverse = duty < 0.f;
  float mag = reverse ? -duty : duty;
  if (mag > 1.f) mag = 1.f;
  PinWrite(kGpioB, 12 + w, reverse);
  Reg(kTim1 + TIM_CCR1 + 4 * w) = static_cast<uint32_t>(mag * static_cast<float>(kPwmArr));
}

void Stm32Hal::SetMotorEnable(bool on) { PinWrite(kGpioB, 15, on); }

float Stm32Hal::ReadCurrentA(int w) {
  return (AdcRead(kCurrentChannels[w]) - kCurrentZeroV) / kCurrentVPerA;
}

float Stm32Hal::ReadBusVoltageV() { return AdcRead(kBusVoltageChannel) * kBusDivider; }

bool Stm32Hal::CanRead(CanFrame* frame) {
  if ((Reg(CAN_RF0R) & 3u) == 0) return false;
  const uint32_t rir = Reg(CAN_RI0R);
  const uint32_t rdtr = Reg(CAN_RI0R + 4);
  const uint32_t lo = Reg(CAN_RI0R + 8);
  const uint32_t hi = Reg(CAN_RI0R + 12);
  // Release the FIFO slot. A plain write, not |=: FULL0 and FOVR0 clear when written as 1, and a
  // read-modify-write would clear an overrun the moment it is read.
  Reg(CAN_RF0R) = 1u << 5;
  // An extended id is not ours; a remote (RTR) frame carries no data, so its "payload" would be
  // whatever the mailbox held (a remote 0x024 read as a twist, 0x023 as CLEAR_FAULTS). Both are
  // reported as the unknown standard id 0x7FF and counted as such.
  if (rir & ((1u << 2) | (1u << 1))) {
    frame->id = can::kForeignFrameId;
    frame->dlc = 0;
    return true;
  }
  frame->id = static_cast<uint16_t>(rir >> 21);
  frame->dlc = static_cast<uint8_t>(rdtr & 0xF);
  for (int i = 0; i < 4; ++i) {
    frame->data[i] = static_cast<uint8_t>(lo >> (8 * i));
    frame->data[4 + i] = static_cast<uint8_t>(hi >> (8 * i));
  }
  return true;
}

uint32_t Stm32Hal::TakeCanRxOverruns() {
  // FOVR0: a frame arrived while FIFO 0 was full and was lost. The flag says "at least one";
  // writing 1 clears it (and only it: RFOM0 written 0 releases nothing).
  if ((Reg(CAN_RF0R) & (1u << 4)) == 0) return 0;
  Reg(CAN_RF0R) = 1u << 4;
  return 1;
}

FwStatus Stm32Hal::CanWrite(const CanFrame& frame) {
  const uint32_t tsr = Reg(CAN_TSR);
  int box = -1;
  for (int i = 0; i < 3; ++i) {
    if (tsr & (1u << (26 + i))) {  // TMEi
      box = i;
      break;
    }
  }
  if (box < 0) return FwStatus::kBusy;
  const uint32_t base = CAN_TI0R + 0x10 * static_cast<uint32_t>(box);
  uint32_t lo = 0, hi = 0;
  for (int i = 0; i < 4; ++i) {
    lo |= static_cast<uint32_t>(frame.data[i]) << (8 * i);
    hi |= static_cast<uint32_t>(frame.data[4 + i]) << (8 * i);
  }
  Reg(base + 4) = frame.dlc & 0xF;
  Reg(base + 8) = lo;
  Reg(base + 12) = hi;
  Reg(base) = (static_cast<uint32_t>(frame.id & 0x7FF) << 21) | 1u;  // TXRQ
  return FwStatus::kOk;
}

bool Stm32Hal::CanBusOff() { return (Reg(CAN_ESR) & (1u << 2)) != 0; }

void Stm32Hal::SetStatusLed(bool on) { PinWrite(kGpioC, 13, !on); }  // LED to 3.3 V: low = on

// --- Parameter store: flash sector 1 ------------------------------------------------------

extern "C" const uint8_t _param_store[];  // linker script: ORIGIN(PARAMS)

namespace {

constexpr uint32_t kFlashBsy = 1u << 16;
constexpr uint32_t kFlashErrors = 0xF2u;  // OPERR, WRPERR, PGAERR, PGPERR, PGSERR
constexpr uint32_t kPsizeX32 = 2u << 8;

// Runs from RAM (.data is copied there at reset; long_call reaches it from flash): erases
// sector 1 and programs n words at dest. While the flash is busy the CPU must not fetch from
// it, so this calls nothing, the caller has turned interrupts off, and the busy loops kick the
// independent watchdog by hand. Returns the flash error flags (0: done).
__attribute__((section(".data.ramfunc"), noinline, long_call)) uint32_t EraseAndProgram(
    const uint32_t* words, uint32_t n, volatile uint32_t* dest) {
  volatile uint32_t* const sr = reinterpret_cast<volatile uint32_t*>(FLASH_SR);
  volatile uint32_t* const cr = reinterpret_cast<volatile uint32_t*>(FLASH_CR);
  volatile uint32_t* const kick = reinterpret_cast<volatile uint32_t*>(IWDG_KR);
  while (*sr & kFlashBsy) *kick = 0xAAAA;
  *sr = kFlashErrors | 1u;                               // clear old flags (write 1)
  *cr = kPsizeX32 | (1u << 3) | (1u << 1);               // SNB = 1, SER
  *cr = kPsizeX32 | (1u << 3) | (1u << 1) | (1u << 16);  // STRT
  while (*sr & kFlashBsy) *kick = 0xAAAA;
  uint32_t err = *sr & kFlashErrors;
  *cr = kPsizeX32;
  for (uint32_t i = 0; i < n && err == 0; ++i) {
    *cr = kPsizeX32 | 1u;  // PG
    dest[i] = words[i];
    while (*sr & kFlashBsy) *kick = 0xAAAA;
    err = *sr & kFlashErrors;
  }
  *cr = kPsizeX32;
  return err;
}

}  // namespace

uint32_t Stm32Hal::ParamStoreRead(uint8_t* buf, uint32_t cap) {
  const uint8_t* p = _param_store;
  if (p[0] == 0xFF && p[1] == 0xFF && p[2] == 0xFF && p[3] == 0xFF) return 0;  // erased
  uint32_t len = 16;  // not a record we know: enough for the decoder to say so
  const uint32_t magic = static_cast<uint32_t>(p[0]) | (static_cast<uint32_t>(p[1]) << 8) |
                         (static_cast<uint32_t>(p[2]) << 16) | (static_cast<uint32_t>(p[3]) << 24);
  if (magic == kParamStoreMagic) len = 8u + 6u * (static_cast<uint32_t>(p[6]) | (p[7] << 8)) + 4u;
  if (len > cap) len = cap;
  for (uint32_t i = 0; i < len; ++i) buf[i] = p[i];
  return len;
}

FwStatus Stm32Hal::ParamStoreWrite(const uint8_t* buf, uint32_t len) {
  if (len > kParamStoreMaxBytes) return FwStatus::kInvalid;
  uint32_t words[kParamStoreMaxBytes / 4];
  const uint32_t n = (len + 3) / 4;
  for (uint32_t i = 0; i < n; ++i) {
    uint32_t w = 0xFFFFFFFFu;
    for (uint32_t b = 0; b < 4; ++b)
      if (4 * i + b < len) {
        w &= ~(0xFFu << (8 * b));
        w |= static_cast<uint32_t>(buf[4 * i + b]) << (8 * b);
      }
    words[i] = w;
  }
  if (Reg(FLASH_CR) & (1u << 31)) {  // LOCK: the unlock sequence
    Reg(FLASH_KEYR) = 0x45670123u;
    Reg(FLASH_KEYR) = 0xCDEF89ABu;
  }
  uint32_t primask = 0;
  __asm volatile("mrs %0, primask\n cpsid i" : "=r"(primask)::"memory");
  const uint32_t err = EraseAndProgram(
      words, n, reinterpret_cast<volatile uint32_t*>(reinterpret_cast<uintptr_t>(_param_store)));
  __asm volatile("msr primask, %0" ::"r"(primask) : "memory");
  Reg(FLASH_CR) |= (1u << 31);  // lock again
  // The data cache may hold the sector's old bytes: reset it (RM0090 3.5.2).
  Reg(FLASH_ACR) &= ~(1u << 10);
  Reg(FLASH_ACR) |= (1u << 12);
  Reg(FLASH_ACR) &= ~(1u << 12);
  Reg(FLASH_ACR) |= (1u << 10);
  return err == 0 ? FwStatus::kOk : FwStatus::kHardware;
}

}  // namespace omni::firmware::stm32
