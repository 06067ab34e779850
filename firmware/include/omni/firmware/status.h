// Status codes of the firmware core. No exceptions, no heap: every fallible call returns one
// of these and the compiler warns when a caller ignores it.
#pragma once

#include <cstdint>

namespace omni::firmware {

enum class [[nodiscard]] FwStatus : uint8_t{
    kOk = 0,
    kBusy,      // try again later (CAN mailbox full)
    kInvalid,   // argument outside its allowed range (parameter value, wheel index)
    kUnknown,   // unknown parameter id / command
    kReadOnly,  // parameter cannot be written
    kHardware,  // the peripheral refused (clock did not lock, CAN did not leave init)
};

inline constexpr bool Ok(FwStatus s) { return s == FwStatus::kOk; }

}  // namespace omni::firmware
