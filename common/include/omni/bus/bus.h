// Typed publish/subscribe over LCM, with the counters every process reports in its heartbeat.
//
// A Bus owns one lcm::LCM. Subscriptions decode into the generated message type; a message
// that fails to decode (wrong fingerprint: another type on the channel; truncated bytes) is
// counted in decode_errors and never reaches the handler. URLs: "" uses LCM_DEFAULT_URL or
// LCM's default multicast; "memq://" for one process; "file:///path?speed=0" to read a log.
#pragma once

#include <atomic>
#include <cstdint>
#include <exception>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <lcm/lcm-cpp.hpp>

#include "omni/common/result.h"

namespace omni::bus {

struct BusCounters {
  std::atomic<int64_t> msgs_in{0};         // decoded and handed to a handler
  std::atomic<int64_t> msgs_out{0};        // published successfully
  std::atomic<int64_t> decode_errors{0};   // received but undecodable
  std::atomic<int64_t> publish_errors{0};  // lcm publish returned an error
  std::atomic<int64_t> drops{0};           // discarded by the process (invalid, late, queue full)
  // file:// only: 1 when the log's framing is broken (LCM's reader stops or skips there, so
  // events are lost); in the heartbeat as log_framing_errors.
  std::atomic<int64_t> log_framing_errors{0};
};

class Bus {
 public:
  // Opens LCM on `url`. Fails with a message naming the URL when LCM cannot start
  // (e.g. no multicast route: see README "Networking").
  static Result<std::unique_ptr<Bus>> Create(const std::string& url);
  ~Bus();
  Bus(const Bus&) = delete;
  Bus& operator=(const Bus&) = delete;

  template <class Msg>
  void Subscribe(const std::string& channel,
                 std::function<void(const Msg& msg, int64_t recv_utime)> handler);

  template <class Msg>
  bool Publish(const std::string& channel, const Msg& msg) {
    const int size = msg.getEncodedSize();
    std::vector<uint8_t> buf(static_cast<size_t>(size));
    if (msg.encode(buf.data(), 0, size) != size) {
      ++counters_.publish_errors;
      return false;
    }
    return PublishRaw(channel, buf.data(), size);
  }
  bool PublishRaw(const std::string& channel, const void* data, int size);

  // Dispatches at most one message. Returns 1 if a message was handled, 0 on timeout,
  // -1 when LCM failed (or the log being read ended).
  int HandleTimeout(int timeout_ms);
  int fd();
  const std::string& url() const { return url_; }
  // Messages LCM keeps per subscription while the process is busy (LCM's default is 30).
  static constexpr int kSubscriptionQueueCapacity = 500;
  BusCounters& counters() { return counters_; }
  // The channel of the most recent decode failure ("" if none), for status texts.
  std::string last_decode_error() const;

 private:
  struct SubscriptionBase {
    virtual ~SubscriptionBase() = default;
    virtual void Handle(const lcm::ReceiveBuffer* rbuf, const std::string& channel) = 0;
  };
  template <class Msg>
  struct TypedSubscription;

  Bus(std::unique_ptr<lcm::LCM> lcm, std::string url);
  void NoteDecodeError(const std::string& channel, int size);

  std::unique_ptr<lcm::LCM> lcm_;
  std::string url_;
  BusCounters counters_;
  std::vector<std::unique_ptr<SubscriptionBase>> subs_;
  mutable std::mutex mu_;
  std::string last_decode_error_;
  std::map<std::string, int64_t> decode_errors_by_channel_;  // for the log's rate limit
};

// Decodes an LCM message; -1 when it does not decode. lcm-gen's decoders size arrays from the
// counts in the bytes before checking them against the data; the build patches them
// (common/lcmtypes/harden_decoders.cmake) to refuse a count beyond the bytes and a string
// length of 0 first, and anything they still throw (length_error, bad_alloc) is an undecodable
// message too, never a crash.
template <class Msg>
int DecodeMessage(Msg* msg, const void* data, int size) noexcept {
  try {
    return msg->decode(data, 0, size);
  } catch (const std::exception&) {
    return -1;
  }
}

template <class Msg>
struct Bus::TypedSubscription final : Bus::SubscriptionBase {
  Bus* bus;
  std::function<void(const Msg&, int64_t)> handler;
  void Handle(const lcm::ReceiveBuffer* rbuf, const std::string& channel) override {
    Msg msg;
    const int n = DecodeMessage(&msg, rbuf->data, static_cast<int>(rbuf->data_size));
    if (n < 0) {
      bus->NoteDecodeError(channel, static_cast<int>(rbuf->data_size));
      return;
    }
    ++bus->counters_.msgs_in;
    handler(msg, rbuf->recv_utime);
  }
};

template <class Msg>
void Bus::Subscribe(const std::string& channel,
                    std::function<void(const Msg& msg, int64_t recv_utime)> handler) {
  auto sub = std::make_unique<TypedSubscription<Msg>>();
  sub->bus = this;
  sub->handler = std::move(handler);
  lcm::Subscription* s = lcm_->subscribe(channel, &SubscriptionBase::Handle,
                                         static_cast<SubscriptionBase*>(sub.get()));
  // LCM's receive thread queues at most 30 messages per subscription by default and silently
  // drops the rest while the handler thread is busy (e.g. one slow filter update); a deeper
  // queue rides out such stalls. Gaps that remain show up in the receivers' seq counters.
  if (s != nullptr) s->setQueueCapacity(kSubscriptionQueueCapacity);
  subs_.push_back(std::move(sub));
}

}  // namespace omni::bus
