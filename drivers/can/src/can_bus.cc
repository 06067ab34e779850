#include "omni/can/can_bus.h"

#include "omni/can/shm_can_bus.h"
#include "omni/can/socket_can_bus.h"

namespace omni::can {

Result<std::unique_ptr<CanBus>> OpenCanBus(const std::string& url) {
  auto starts = [&](const char* p) { return url.rfind(p, 0) == 0; };
  if (starts("shm:")) {
    auto bus = ShmCanBus::Open(url.substr(4));
    if (!bus.ok()) return bus.error();
    return std::unique_ptr<CanBus>(std::move(bus).value());
  }
  if (starts("socketcan:")) {
    auto bus = SocketCanBus::Open(url.substr(10));
    if (!bus.ok()) return bus.error();
    return std::unique_ptr<CanBus>(std::move(bus).value());
  }
  return MakeError(ErrorCode::kInvalidArgument,
                   "CAN bus URL '" + url + "': expected socketcan:<ifname> or shm:<name>");
}

}  // namespace omni::can
