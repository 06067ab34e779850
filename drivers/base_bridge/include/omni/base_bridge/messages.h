// The base bridge's outputs as bus messages. One conversion, used by the base_bridge process and
// by the simulator's firmware-in-the-loop base, so both put the same bytes on the bus.
#pragma once

#include "omni/base_bridge/base_bridge.h"
#include "omni/base_status_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/wheel_encoders_t.hpp"

namespace omni::base_bridge {

omni::odometry_t ToMessage(const Odometry& od, const BaseBridgeOptions& o);
omni::wheel_encoders_t ToMessage(const Encoders& en, const BaseBridgeOptions& o);
omni::base_status_t ToMessage(const BaseStatus& s, const Counters& c);

}  // namespace omni::base_bridge
