// Linux SocketCAN (raw socket on a CAN interface, e.g. can0). On kernels without CAN support
// Open fails with kUnavailable and the errno text ("Address family not supported by protocol").
#pragma once

#include <memory>
#include <string>

#include "omni/can/can_bus.h"

namespace omni::can {

class SocketCanBus final : public CanBus {
 public:
  static Result<std::unique_ptr<SocketCanBus>> Open(const std::string& ifname);
  ~SocketCanBus() override;
  Status Send(const Frame& f) override;
  Result<bool> Receive(Frame* f, int timeout_ms) override;
  std::string name() const override { return "socketcan:" + ifname_; }
  CanBusStats stats() const override { return stats_; }
  // True when the controller reports bus-off (libsocketcan), false when unknown.
  bool BusOff() const;

 private:
  SocketCanBus(std::string ifname, int fd) : ifname_(std::move(ifname)), fd_(fd) {}
  std::string ifname_;
  int fd_;
  CanBusStats stats_;
};

}  // namespace omni::can
