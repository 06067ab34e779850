#include "omni/bus/bus.h"

#include <cstdint>
#include <cstdlib>
#include <filesystem>

#include "omni/common/log.h"
#include "omni/io/lcm_log.h"

namespace omni::bus {

namespace {

// The path of a file:// URL ("file:///abs/log?speed=0" -> "/abs/log"), or "" for other URLs.
std::string LogPathOf(const std::string& url) {
  if (url.rfind("file://", 0) != 0) return "";
  return url.substr(7, url.find('?') == std::string::npos ? std::string::npos : url.find('?') - 7);
}

bool WritesLog(const std::string& url) {
  const size_t q = url.find('?');
  // LCM's file provider writes with mode=w and appends with mode=a.
  return q != std::string::npos &&
         (url.find("mode=w", q) != std::string::npos || url.find("mode=a", q) != std::string::npos);
}

// Why LCM could not open `url`, as far as we can tell from outside it.
std::string OpenFailureHint(const std::string& url) {
  const std::string path = LogPathOf(url);
  if (!path.empty()) {
    std::error_code ec;
    if (WritesLog(url)) return "cannot write the log file '" + path + "'";
    if (!std::filesystem::exists(path, ec)) return "log file '" + path + "' does not exist";
    if (std::filesystem::is_regular_file(path, ec) && std::filesystem::file_size(path, ec) == 0)
      return "log file '" + path + "' is empty";
    return "log file '" + path + "' is not a readable LCM log";
  }
  if (url.empty() || url.rfind("udpm://", 0) == 0)
    return "UDP multicast needs a route for 224.0.0.0/4; see README, Networking";
  if (url.rfind("memq://", 0) == 0 || url.rfind("tcpq://", 0) == 0)
    return "see LCM's documentation of this provider";
  return "unknown provider; use udpm://, file://, memq:// or tcpq://";
}

}  // namespace

Result<std::unique_ptr<Bus>> Bus::Create(const std::string& url) {
  const char* env = std::getenv("LCM_DEFAULT_URL");
  const std::string effective = url.empty() && env != nullptr ? std::string(env) : url;
  auto lcm = std::make_unique<lcm::LCM>(url);
  if (!lcm->good()) {
    return MakeError(ErrorCode::kUnavailable, "cannot open the LCM bus at '" +
                                                  (effective.empty() ? "default" : effective) +
                                                  "' (" + OpenFailureHint(effective) + ")");
  }
  // LCM's file reader ends or skips silently at a corrupt event: check the log first so that a
  // replay that will lose events says so before it starts.
  if (const std::string path = LogPathOf(effective); !path.empty() && !WritesLog(effective)) {
    if (Status s = io::CheckLcmLogFraming(path); !s.ok()) {
      LOG_WARN << s.message()
               << ": LCM's file reader stops or skips there, so events of this log are lost "
                  "(counted as log_framing_errors; `omni replay --resync` reads past it)";
      auto bus = std::unique_ptr<Bus>(new Bus(std::move(lcm), url));
      bus->counters_.log_framing_errors = 1;
      return bus;
    }
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
  // Logged per channel at the 1st, 10th, 100th ... failure: a stale publisher on two channels
  // used to log a line at every switch between them (hundreds a second).
  int64_t& n = decode_errors_by_channel_[channel];
  ++n;
  int64_t p = 1;
  while (p < n && p <= INT64_MAX / 10) p *= 10;
  if (p == n) {
    LOG_WARN << "undecodable message on channel " << channel << " (" << size
             << " bytes): wrong type or truncated; " << n
             << (n == 1 ? " so far" : " on this channel so far") << ", counted in decode_errors";
  }
  last_decode_error_ = channel;
}

std::string Bus::last_decode_error() const {
  std::lock_guard<std::mutex> lock(mu_);
  return last_decode_error_;
}

}  // namespace omni::bus
