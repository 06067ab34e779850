// The user-space CAN bus: a multi-writer, multi-reader ring of frames in one shared-memory
// file, /dev/shm/omni-can-<name>.
//
// Each node appends frames by taking a ticket (atomic fetch_add on the write index) and
// publishing the slot with a per-slot sequence number (odd while being written, even when
// complete: a seqlock, so a reader that was lapped sees it and counts an overrun instead of
// reading a torn frame). Each node reads from its own cursor and skips its own frames, so
// every frame reaches every other node, in one global order, as on a real bus. Readers sleep
// on a futex in the shared file and writers wake them. A "link" flag in the header models the
// interface going down (ip link set can0 down): Send/Receive/Open then fail with kUnavailable.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "omni/can/can_bus.h"

namespace omni::can {

class ShmCanBus final : public CanBus {
 public:
  static constexpr uint32_t kSlots = 4096;

  // Attaches to (creating if needed) the bus `name` ([A-Za-z0-9_.-], at most 64 chars).
  static Result<std::unique_ptr<ShmCanBus>> Open(const std::string& name);
  // 1-64 characters of [A-Za-z0-9_.-] (a file name under /dev/shm, never a path).
  static bool IsValidName(const std::string& name);
  // Brings the bus `name` down or up for every node (tests, `omni-canbus link`).
  static Status SetLinkUp(const std::string& name, bool up);
  // Removes the shared file (nodes still attached keep their mapping).
  static Status Remove(const std::string& name);

  ~ShmCanBus() override;
  Status Send(const Frame& f) override;
  Result<bool> Receive(Frame* f, int timeout_ms) override;
  std::string name() const override { return "shm:" + name_; }
  CanBusStats stats() const override { return stats_; }
  uint16_t node_tag() const { return tag_; }

  struct Shared;

 private:
  ShmCanBus(std::string name, Shared* shared, size_t size, uint16_t tag);
  bool TryRead(Frame* f);

  std::string name_;
  Shared* shared_;
  size_t size_;
  uint16_t tag_;
  uint64_t cursor_ = 0;
  int64_t stuck_since_us_ = 0;
  CanBusStats stats_;
};

}  // namespace omni::can
