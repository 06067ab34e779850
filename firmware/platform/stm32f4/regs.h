// The few STM32F405 / Cortex-M4 registers the firmware touches, by address (RM0090, PM0214).
// Written out here instead of pulling in the vendor CMSIS headers.
#pragma once

#include <cstdint>

namespace omni::firmware::stm32 {

inline volatile uint32_t& Reg(uint32_t addr) { return *reinterpret_cast<volatile uint32_t*>(addr); }

// Bases.
constexpr uint32_t kRcc = 0x40023800;
constexpr uint32_t kFlash = 0x40023C00;
constexpr uint32_t kGpioA = 0x40020000;
constexpr uint32_t kGpioB = 0x40020400;
constexpr uint32_t kGpioC = 0x40020800;
constexpr uint32_t kTim1 = 0x40010000;
constexpr uint32_t kTim2 = 0x40000000;
constexpr uint32_t kTim3 = 0x40000400;
constexpr uint32_t kTim4 = 0x40000800;
constexpr uint32_t kAdc1 = 0x40012000;
constexpr uint32_t kAdcCommon = 0x40012300;
constexpr uint32_t kCan1 = 0x40006400;
constexpr uint32_t kIwdg = 0x40003000;
constexpr uint32_t kSysTick = 0xE000E010;
constexpr uint32_t kScbCpacr = 0xE000ED88;
constexpr uint32_t kDemcr = 0xE000EDFC;
constexpr uint32_t kDwtCtrl = 0xE0001000;
constexpr uint32_t kDwtCyccnt = 0xE0001004;

// RCC.
constexpr uint32_t RCC_CR = kRcc + 0x00;
constexpr uint32_t RCC_PLLCFGR = kRcc + 0x04;
constexpr uint32_t RCC_CFGR = kRcc + 0x08;
constexpr uint32_t RCC_AHB1ENR = kRcc + 0x30;
constexpr uint32_t RCC_APB1ENR = kRcc + 0x40;
constexpr uint32_t RCC_APB2ENR = kRcc + 0x44;
constexpr uint32_t FLASH_ACR = kFlash + 0x00;
constexpr uint32_t FLASH_KEYR = kFlash + 0x04, FLASH_SR = kFlash + 0x0C, FLASH_CR = kFlash + 0x10;

// GPIO (offsets).
constexpr uint32_t GPIO_MODER = 0x00, GPIO_OSPEEDR = 0x08, GPIO_PUPDR = 0x0C, GPIO_BSRR = 0x18,
                   GPIO_AFRL = 0x20, GPIO_AFRH = 0x24;

// Timers (offsets).
constexpr uint32_t TIM_CR1 = 0x00, TIM_SMCR = 0x08, TIM_EGR = 0x14, TIM_CCMR1 = 0x18,
                   TIM_CCMR2 = 0x1C, TIM_CCER = 0x20, TIM_CNT = 0x24, TIM_PSC = 0x28,
                   TIM_ARR = 0x2C, TIM_CCR1 = 0x34, TIM_BDTR = 0x44;

// ADC.
constexpr uint32_t ADC_SR = kAdc1 + 0x00, ADC_CR2 = kAdc1 + 0x08, ADC_SMPR1 = kAdc1 + 0x0C,
                   ADC_SQR1 = kAdc1 + 0x2C, ADC_SQR3 = kAdc1 + 0x34, ADC_DR = kAdc1 + 0x4C,
                   ADC_CCR = kAdcCommon + 0x04;

// bxCAN.
constexpr uint32_t CAN_MCR = kCan1 + 0x000, CAN_MSR = kCan1 + 0x004, CAN_TSR = kCan1 + 0x008,
                   CAN_RF0R = kCan1 + 0x00C, CAN_ESR = kCan1 + 0x018, CAN_BTR = kCan1 + 0x01C,
                   CAN_TI0R = kCan1 + 0x180,  // mailbox i at + 0x10 * i: TIR, TDTR, TDLR, TDHR
    CAN_RI0R = kCan1 + 0x1B0,                 // FIFO 0: RIR, RDTR, RDLR, RDHR
    CAN_FMR = kCan1 + 0x200, CAN_FM1R = kCan1 + 0x204, CAN_FS1R = kCan1 + 0x20C,
                   CAN_FFA1R = kCan1 + 0x214, CAN_FA1R = kCan1 + 0x21C, CAN_F0R1 = kCan1 + 0x240,
                   CAN_F0R2 = kCan1 + 0x244;

// IWDG, SysTick.
constexpr uint32_t IWDG_KR = kIwdg + 0x0, IWDG_PR = kIwdg + 0x4, IWDG_RLR = kIwdg + 0x8;
constexpr uint32_t SYST_CSR = kSysTick + 0x0, SYST_RVR = kSysTick + 0x4, SYST_CVR = kSysTick + 0x8;

}  // namespace omni::firmware::stm32
