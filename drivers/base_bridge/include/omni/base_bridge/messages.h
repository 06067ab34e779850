// The base bridge's bus messages. One conversion each way, used by the base_bridge process and
// by the simulator's firmware-in-the-loop base, so both read and put the same bytes on the bus.
#pragma once

#include "omni/base_bridge/base_bridge.h"
#include "omni/base_cmd_t.hpp"
#include "omni/base_status_t.hpp"
#include "omni/odometry_t.hpp"
#include "omni/wheel_encoders_t.hpp"

namespace omni::base_bridge {

omni::odometry_t ToMessage(const Odometry& od, const BaseBridgeOptions& o);
omni::wheel_encoders_t ToMessage(const Encoders& en, const BaseBridgeOptions& o);
omni::base_status_t ToMessage(const BaseStatus& s, const Counters& c);

// A BASE_CMD message as the bridge's command. An unknown mode becomes an invalid one, which
// BaseBridge::OnCommand rejects and counts (as it does non-finite velocities).
Command FromMessage(const omni::base_cmd_t& m);

}  // namespace omni::base_bridge
