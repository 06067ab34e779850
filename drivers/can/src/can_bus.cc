#include "omni/can/can_bus.h"

#include <net/if.h>

#include <algorithm>
#include <cctype>
#include <filesystem>

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
    if (!ShmCanBus::IsValidName(u.name))
      return bad("a shared-memory bus name is 1-64 characters of letters, digits, _ . -");
    return u;
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
  if (!bus.ok()) {
    // A simulator bus named without its shm: prefix would otherwise wait for an interface.
    std::error_code ec;
    if (url.rfind("socketcan:", 0) != 0 &&
        std::filesystem::exists("/dev/shm/omni-can-" + u->name, ec))
      return MakeError(bus.error().code, bus.error().message + " (a simulated bus shm:" + u->name +
                                             " exists: did you mean --can shm:" + u->name + "?)");
    return bus.error();
  }
  return std::unique_ptr<CanBus>(std::move(bus).value());
}

}  // namespace omni::can
