#include "omni/bus/bus.h"

#include "omni/common/log.h"

namespace omni::bus {

Result<std::unique_ptr<Bus>> Bus::Create(const std::string& url) {
  auto lcm = std::make_unique<lcm::LCM>(url);
  if (!lcm->good()) {
    return MakeError(ErrorCode::kUnavailable,
                     "cannot open the LCM bus at '" + (url.empty() ? std::string("default") : url) +
                         "' (UDP multicast needs a route for 224.0.0.0/4; see README, Networking)");
  }
  return std::unique_ptr<Bus>(new Bus(std::move(lcm), url));
}

Bus::Bus(std::unique_ptr<lcm::LCM> lcm, std::string url)
    : lcm_(std::move(lcm)), url_(std::move(url)) {}

Bus::~Bus() = default;

bool Bus::PublishRaw(const std::string& channel, const void* data, int size) {
  if (lcm_->publish(channel, data, static_cast<unsigned>(size)) != 0) {
    ++counters_.publish_errors;
    return false;
  }
  ++counters_.msgs_out;
  return true;
}

int Bus::HandleTimeout(int timeout_ms) {
  const int r = lcm_->handleTimeout(timeout_ms);
  if (r < 0) return -1;
  return r > 0 ? 1 : 0;
}

int Bus::fd() { return lcm_->getFileno(); }

void Bus::NoteDecodeError(const std::string& channel, int size) {
  ++counters_.decode_errors;
  std::lock_guard<std::mutex> lock(mu_);
  if (last_decode_error_ != channel) {
    LOG_WARN << "undecodable message on channel " << channel << " (" << size
             << " bytes): wrong type or truncated; counted in decode_errors";
  }
  last_decode_error_ = channel;
}

std::string Bus::last_decode_error() const {
  std::lock_guard<std::mutex> lock(mu_);
  return last_decode_error_;
}

}  // namespace omni::bus
