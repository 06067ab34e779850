// Hardware abstraction of the omni base controller board.
//
// The portable core (Firmware) talks to the board only through this interface. Two
// implementations exist: platform/stm32f4 (register-level drivers on an STM32F405) and
// platform/host (a DC-motor-and-wheel plant model, the firmware simulator).
//
// No virtual destructor on purpose: a deleting destructor would drag operator delete (and
// with it the heap) into the firmware image. Platforms own their HAL statically.
#pragma once

#include <cstdint>

#include "omni/firmware/status.h"

namespace omni::firmware {

inline constexpr int kNumWheels = 3;

// A classic CAN 2.0A frame: 11-bit id, up to 8 data bytes.
struct CanFrame {
  uint16_t id = 0;  // 11-bit standard identifier
  uint8_t dlc = 0;  // 0..8
  uint8_t data[8] = {0, 0, 0, 0, 0, 0, 0, 0};
};

class Hal {
 public:
  // Free-running microsecond clock (wraps every ~71 min; compare with unsigned differences).
  virtual uint32_t MicrosNow() = 0;
  // Raw 16-bit hardware quadrature counter of wheel `w` (x4 counting, wraps).
  virtual uint16_t ReadEncoder(int w) = 0;
  // Motor duty of wheel `w` in [-1, 1]; the sign selects the direction.
  virtual void WritePwm(int w, float duty) = 0;
  // Gate-driver enable (GPIO). Off = all bridges high-impedance (motors coast).
  virtual void SetMotorEnable(bool on) = 0;
  // Motor current of wheel `w`, amperes (signed where the board can tell).
  virtual float ReadCurrentA(int w) = 0;
  // Motor supply voltage, volts.
  virtual float ReadBusVoltageV() = 0;
  // Pops one received frame; false when none is pending.
  virtual bool CanRead(CanFrame* frame) = 0;
  // Queues one frame; kBusy when every transmit mailbox is full.
  virtual FwStatus CanWrite(const CanFrame& frame) = 0;
  // Receive-FIFO overruns since the last call (each: at least one frame the controller dropped
  // because the FIFO was full); the call clears them. A board that cannot tell returns 0.
  virtual uint32_t TakeCanRxOverruns() { return 0; }
  // True while the CAN controller is bus-off.
  virtual bool CanBusOff() = 0;
  // Status LED (GPIO): blinks while running, steady on fault.
  virtual void SetStatusLed(bool on) = 0;
  // Non-volatile parameter store (param_store.h), one small area. has_param_store(): false on a
  // board without one (the defaults below). Read copies up to `cap` bytes of the area into buf
  // and returns how many hold a record (0: empty or erased). Write replaces the area with
  // `len` bytes (len 0: erase); it may block the CPU for a long time (a flash sector erase takes
  // up to ~2 s on the STM32F4), so the firmware only calls it with the motors off.
  virtual bool has_param_store() const { return false; }
  virtual uint32_t ParamStoreRead(uint8_t* buf, uint32_t cap) {
    (void)buf;
    (void)cap;
    return 0;
  }
  virtual FwStatus ParamStoreWrite(const uint8_t* buf, uint32_t len) {
    (void)buf;
    (void)len;
    return FwStatus::kHardware;
  }

 protected:
  ~Hal() = default;
};

}  // namespace omni::firmware
