#include "omni/can/can_bus.h"

#include <net/if.h>

#include <algorithm>
#include <cctype>

#include "omni/can/shm_can_bus.h"
#include "omni/can/socket_can_bus.h"

namespace omni::can {

Result<CanUrl> ParseCanUrl(const std::string& url) {
  auto bad = [&](const std::string& why) {
    return MakeError(ErrorCode::kInvalidArgument,
                     "CAN bus URL '" + url + "': " + why +
                         " (expected an interface name such as can0, socketcan:<ifname> or "
                         "shm:<name>)");
  };
  auto starts = [&](const char* p) { return url.rfind(p, 0) == 0; };
  CanUrl u;
  if (starts("shm:")) {
    u.kind = CanUrl::Kind::kShm;
    u.name = url.substr(4);
    if (u.name.empty()) return bad("empty bus name");
    return u;  // the shared-memory bus checks its own name rules when it opens
  }
  u.kind = CanUrl::Kind::kSocketCan;
  u.name = starts("socketcan:") ? url.substr(10) : url;
  if (u.name.empty()) return bad("empty interface name");
  if (u.name.size() >= IFNAMSIZ) return bad("interface name longer than 15 characters");
  const bool ok_chars = std::all_of(u.name.begin(), u.name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_' || c == '-' || c == '.';
  });
  if (!ok_chars) return bad("not an interface name");
  return u;
}

Result<std::unique_ptr<CanBus>> OpenCanBus(const std::string& url) {
  auto u = ParseCanUrl(url);
  if (!u.ok()) return u.error();
  if (u->kind == CanUrl::Kind::kShm) {
    auto bus = ShmCanBus::Open(u->name);
    if (!bus.ok()) return bus.error();
    return std::unique_ptr<CanBus>(std::move(bus).value());
  }
  auto bus = SocketCanBus::Open(u->name);
  if (!bus.ok()) return bus.error();
  return std::unique_ptr<CanBus>(std::move(bus).value());
}

}  // namespace omni::can
