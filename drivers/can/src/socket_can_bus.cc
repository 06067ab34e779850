#include "omni/can/socket_can_bus.h"

#include <cerrno>
#include <cstring>

#include <libsocketcan.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

namespace omni::can {

Result<std::unique_ptr<SocketCanBus>> SocketCanBus::Open(const std::string& ifname) {
  if (ifname.empty() || ifname.size() >= IFNAMSIZ) {
    return MakeError(ErrorCode::kInvalidArgument, "CAN interface name '" + ifname + "'");
  }
  const int fd = socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) {
    return MakeError(ErrorCode::kUnavailable, "socket(PF_CAN) for " + ifname + ": " +
                                                  std::strerror(errno) +
                                                  " (kernel without SocketCAN?)");
  }
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, ifname.c_str(), IFNAMSIZ - 1);
  if (ioctl(fd, SIOCGIFINDEX, &ifr) < 0) {
    const int e = errno;
    close(fd);
    return MakeError(ErrorCode::kUnavailable, "CAN interface " + ifname + ": " + std::strerror(e));
  }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifr.ifr_ifindex;
  if (bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) < 0) {
    const int e = errno;
    close(fd);
    return MakeError(ErrorCode::kUnavailable, "bind " + ifname + ": " + std::strerror(e));
  }
  // Error frames (bus-off, controller problems) are delivered too.
  can_err_mask_t err_mask = CAN_ERR_MASK;
  setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &err_mask, sizeof(err_mask));
  return std::unique_ptr<SocketCanBus>(new SocketCanBus(ifname, fd));
}

SocketCanBus::~SocketCanBus() { close(fd_); }

Status SocketCanBus::Send(const Frame& f) {
  if (f.dlc > 8) return MakeError(ErrorCode::kInvalidArgument, "CAN dlc > 8");
  can_frame cf{};
  cf.can_id = f.id & (f.extended ? CAN_EFF_MASK : CAN_SFF_MASK);
  if (f.extended) cf.can_id |= CAN_EFF_FLAG;
  if (f.rtr) cf.can_id |= CAN_RTR_FLAG;
  cf.can_dlc = f.dlc;
  std::memcpy(cf.data, f.data, 8);
  const ssize_t n = write(fd_, &cf, sizeof(cf));
  if (n != static_cast<ssize_t>(sizeof(cf))) {
    ++stats_.tx_errors;
    const int e = errno;
    if (e == ENOBUFS || e == EAGAIN)
      return MakeError(ErrorCode::kIo, "CAN tx queue full on " + ifname_);
    return MakeError(ErrorCode::kUnavailable, "CAN write on " + ifname_ + ": " + std::strerror(e));
  }
  ++stats_.tx_frames;
  return Status::Ok();
}

Result<bool> SocketCanBus::Receive(Frame* f, int timeout_ms) {
  for (;;) {
    pollfd p{fd_, POLLIN, 0};
    const int r = poll(&p, 1, timeout_ms);
    if (r < 0 && errno == EINTR) continue;
    if (r < 0)
      return MakeError(ErrorCode::kUnavailable, "poll " + ifname_ + ": " + std::strerror(errno));
    if (r == 0) return false;
    if (p.revents & (POLLERR | POLLHUP | POLLNVAL)) {
      return MakeError(ErrorCode::kUnavailable, "CAN interface " + ifname_ + " went away");
    }
    can_frame cf{};
    const ssize_t n = read(fd_, &cf, sizeof(cf));
    if (n < 0) {
      return MakeError(ErrorCode::kUnavailable,
                       "CAN read on " + ifname_ + ": " + std::strerror(errno));
    }
    if (n != static_cast<ssize_t>(sizeof(cf))) continue;
    if (cf.can_id & CAN_ERR_FLAG) {
      if (cf.can_id & CAN_ERR_BUSOFF) {
        return MakeError(ErrorCode::kUnavailable, "CAN controller " + ifname_ + " is bus-off");
      }
      continue;
    }
    f->extended = (cf.can_id & CAN_EFF_FLAG) != 0;
    f->rtr = (cf.can_id & CAN_RTR_FLAG) != 0;
    f->id = cf.can_id & (f->extended ? CAN_EFF_MASK : CAN_SFF_MASK);
    f->dlc = cf.can_dlc > 8 ? 8 : cf.can_dlc;
    std::memcpy(f->data, cf.data, 8);
    ++stats_.rx_frames;
    return true;
  }
}

bool SocketCanBus::BusOff() const {
  int state = 0;
  if (can_get_state(ifname_.c_str(), &state) != 0) return false;
  return state == CAN_STATE_BUS_OFF;
}

}  // namespace omni::can
