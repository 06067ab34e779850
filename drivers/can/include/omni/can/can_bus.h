// A small CAN bus interface for host processes (the base bridge, the firmware simulator, tools).
//
// Implementations:
//   "socketcan:<ifname>"  Linux SocketCAN raw socket (the robot: can0 on a USB/SPI adapter).
//   "shm:<name>"          a user-space bus in shared memory (/dev/shm/omni-can-<name>): every
//                         process that opens the same name is a node on one bus, and each frame
//                         sent reaches every other node, like a real bus. No root, no kernel
//                         CAN, no network namespace. Used by the simulator and the tests.
//
// Errors: kUnavailable when the interface is down or vanished (callers close and re-open it,
// as the base bridge does), kInvalidArgument for a bad URL or frame.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "omni/common/result.h"

namespace omni::can {

struct Frame {
  uint32_t id = 0;  // 11-bit (or 29-bit when `extended`) identifier
  uint8_t dlc = 0;  // 0..8
  bool extended = false;
  bool rtr = false;
  uint8_t data[8] = {0, 0, 0, 0, 0, 0, 0, 0};
};

struct CanBusStats {
  int64_t tx_frames = 0;
  int64_t rx_frames = 0;
  int64_t rx_overruns = 0;  // frames this node lost because it read too slowly
  int64_t tx_errors = 0;
};

class CanBus {
 public:
  virtual ~CanBus() = default;
  // Sends one frame. kUnavailable when the interface is down.
  virtual Status Send(const Frame& f) = 0;
  // Waits up to timeout_ms (0: poll) for a frame. true = *f filled, false = timeout;
  // an error (kUnavailable) when the interface went down.
  virtual Result<bool> Receive(Frame* f, int timeout_ms) = 0;
  virtual std::string name() const = 0;
  virtual CanBusStats stats() const = 0;
};

// A CAN bus URL taken apart: "socketcan:<ifname>", "shm:<name>", or a bare interface name
// ("can0", as `ip link` prints it), which means socketcan:<ifname>.
struct CanUrl {
  enum class Kind { kSocketCan, kShm } kind = Kind::kSocketCan;
  std::string name;
};
// kInvalidArgument, naming the URL, when it can never be opened (so callers can refuse it at
// start instead of retrying it as if the device were only missing).
Result<CanUrl> ParseCanUrl(const std::string& url);

// Opens a URL of ParseCanUrl's forms.
Result<std::unique_ptr<CanBus>> OpenCanBus(const std::string& url);

}  // namespace omni::can
