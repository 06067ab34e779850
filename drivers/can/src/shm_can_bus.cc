#include "omni/can/shm_can_bus.h"

#include <atomic>
#include <cerrno>
#include <chrono>
#include <climits>
#include <cstring>
#include <ctime>

#include <fcntl.h>
#include <linux/futex.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

namespace omni::can {

namespace {
constexpr uint64_t kMagic = 0x4F4D4E4943414E31ull;  // "OMNICAN1"
constexpr int64_t kStuckSlotUs = 50000;  // a writer that claimed a slot and died: skip after this

int64_t NowUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
std::string ShmPath(const std::string& name) { return "/omni-can-" + name; }
bool ValidName(const std::string& name) {
  if (name.empty() || name.size() > 64) return false;
  for (char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-' || c == '.';
    if (!ok) return false;
  }
  return true;
}
}  // namespace

struct ShmCanBus::Shared {
  struct Slot {
    std::atomic<uint64_t> seq;   // 2t+1 while ticket t is written, 2t+2 when complete
    std::atomic<uint64_t> meta;  // id (32) | dlc (8) | flags (8) | sender tag (16)
    std::atomic<uint64_t> data;  // 8 data bytes, little-endian
  };
  std::atomic<uint64_t> magic;
  std::atomic<uint32_t> link_down;
  std::atomic<uint32_t> next_tag;
  std::atomic<uint64_t> write_index;
  std::atomic<uint32_t> futex_word;
  std::atomic<uint32_t> waiters;
  Slot slots[kSlots];
};
static_assert(std::atomic<uint64_t>::is_always_lock_free,
              "shared-memory atomics must be lock-free");

namespace {
// A zero-filled file is a valid empty bus: no initialisation step that a crash could tear.
Result<std::pair<ShmCanBus::Shared*, size_t>> MapBus(const std::string& name) {
  if (!ValidName(name)) {
    return MakeError(ErrorCode::kInvalidArgument,
                     "CAN bus name '" + name + "': use 1-64 characters of [A-Za-z0-9_.-]");
  }
  const std::string path = ShmPath(name);
  const int fd = shm_open(path.c_str(), O_RDWR | O_CREAT, 0666);
  if (fd < 0) {
    return MakeError(ErrorCode::kIo, "shm_open /dev/shm" + path + ": " + std::strerror(errno));
  }
  const size_t size = sizeof(ShmCanBus::Shared);
  struct stat st {};
  if (fstat(fd, &st) != 0 || (static_cast<size_t>(st.st_size) < size && ftruncate(fd, size) != 0)) {
    const int e = errno;
    close(fd);
    return MakeError(ErrorCode::kIo, "sizing /dev/shm" + path + ": " + std::strerror(e));
  }
  void* p = mmap(nullptr, size, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  const int e = errno;
  close(fd);
  if (p == MAP_FAILED) {
    return MakeError(ErrorCode::kIo, "mmap /dev/shm" + path + ": " + std::strerror(e));
  }
  auto* shared = static_cast<ShmCanBus::Shared*>(p);
  uint64_t expected = 0;
  if (!shared->magic.compare_exchange_strong(expected, kMagic) && expected != kMagic) {
    munmap(p, size);
    return MakeError(ErrorCode::kParse,
                     "/dev/shm" + path + " is not an omni CAN bus of this version (remove it)");
  }
  return std::make_pair(shared, size);
}

long Futex(std::atomic<uint32_t>* addr, int op, uint32_t val, const timespec* ts) {
  return syscall(SYS_futex, reinterpret_cast<uint32_t*>(addr), op, val, ts, nullptr, 0);
}
}  // namespace

bool ShmCanBus::IsValidName(const std::string& name) { return ValidName(name); }

Result<std::unique_ptr<ShmCanBus>> ShmCanBus::Open(const std::string& name) {
  auto mapped = MapBus(name);
  if (!mapped.ok()) return mapped.error();
  auto [shared, size] = mapped.value();
  if (shared->link_down.load() != 0) {
    munmap(shared, size);
    return MakeError(ErrorCode::kUnavailable, "CAN bus shm:" + name + " is down");
  }
  const uint16_t tag = static_cast<uint16_t>(shared->next_tag.fetch_add(1) + 1);
  std::unique_ptr<ShmCanBus> bus(new ShmCanBus(name, shared, size, tag));
  return bus;
}

Status ShmCanBus::SetLinkUp(const std::string& name, bool up) {
  auto mapped = MapBus(name);
  if (!mapped.ok()) return mapped.error();
  auto [shared, size] = mapped.value();
  shared->link_down.store(up ? 0 : 1);
  shared->futex_word.fetch_add(1);
  Futex(&shared->futex_word, FUTEX_WAKE, INT_MAX, nullptr);  // waiters see the change now
  munmap(shared, size);
  return Status::Ok();
}

Status ShmCanBus::Remove(const std::string& name) {
  if (!ValidName(name)) return MakeError(ErrorCode::kInvalidArgument, "bad CAN bus name " + name);
  if (shm_unlink(ShmPath(name).c_str()) != 0 && errno != ENOENT) {
    return MakeError(ErrorCode::kIo, "shm_unlink " + ShmPath(name) + ": " + std::strerror(errno));
  }
  return Status::Ok();
}

ShmCanBus::ShmCanBus(std::string name, Shared* shared, size_t size, uint16_t tag)
    : name_(std::move(name)), shared_(shared), size_(size), tag_(tag) {
  cursor_ = shared_->write_index.load();  // a node hears only what is sent after it attached
}

ShmCanBus::~ShmCanBus() { munmap(shared_, size_); }

Status ShmCanBus::Send(const Frame& f) {
  if (shared_->link_down.load(std::memory_order_relaxed) != 0) {
    ++stats_.tx_errors;
    return MakeError(ErrorCode::kUnavailable, "CAN bus shm:" + name_ + " is down");
  }
  const uint32_t max_id = f.extended ? 0x1FFFFFFFu : 0x7FFu;
  if (f.dlc > 8 || f.id > max_id) {
    ++stats_.tx_errors;
    return MakeError(ErrorCode::kInvalidArgument, "CAN frame id/dlc out of range");
  }
  const uint64_t t = shared_->write_index.fetch_add(1);
  Shared::Slot& s = shared_->slots[t % kSlots];
  s.seq.store(2 * t + 1, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  const uint64_t flags = (f.extended ? 1u : 0u) | (f.rtr ? 2u : 0u);
  s.meta.store(static_cast<uint64_t>(f.id) | (static_cast<uint64_t>(f.dlc) << 32) | (flags << 40) |
                   (static_cast<uint64_t>(tag_) << 48),
               std::memory_order_relaxed);
  uint64_t d = 0;
  for (int i = 0; i < 8; ++i) d |= static_cast<uint64_t>(f.data[i]) << (8 * i);
  s.data.store(d, std::memory_order_relaxed);
  s.seq.store(2 * t + 2, std::memory_order_release);
  shared_->futex_word.fetch_add(1);
  if (shared_->waiters.load() > 0) Futex(&shared_->futex_word, FUTEX_WAKE, INT_MAX, nullptr);
  ++stats_.tx_frames;
  return Status::Ok();
}

bool ShmCanBus::TryRead(Frame* f) {
  for (;;) {
    const uint64_t w = shared_->write_index.load(std::memory_order_acquire);
    if (cursor_ >= w) return false;
    if (w - cursor_ > kSlots) {  // lapped: the oldest frames we had not read are gone
      const uint64_t next = w - kSlots / 2;
      stats_.rx_overruns += static_cast<int64_t>(next - cursor_);
      cursor_ = next;
    }
    Shared::Slot& s = shared_->slots[cursor_ % kSlots];
    const uint64_t want = 2 * cursor_ + 2;
    const uint64_t seq = s.seq.load(std::memory_order_acquire);
    if (seq < want) {
      // Claimed but not yet complete (writer mid-frame). A writer that died here would
      // block the bus: skip the slot after kStuckSlotUs.
      const int64_t now = NowUs();
      if (stuck_since_us_ == 0) stuck_since_us_ = now;
      if (now - stuck_since_us_ < kStuckSlotUs) return false;
      ++stats_.rx_overruns;
      ++cursor_;
      stuck_since_us_ = 0;
      continue;
    }
    stuck_since_us_ = 0;
    if (seq > want) {  // overwritten by a later lap
      ++stats_.rx_overruns;
      ++cursor_;
      continue;
    }
    const uint64_t meta = s.meta.load(std::memory_order_relaxed);
    const uint64_t data = s.data.load(std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_acquire);
    if (s.seq.load(std::memory_order_relaxed) != seq) {  // torn: lapped while reading
      ++stats_.rx_overruns;
      ++cursor_;
      continue;
    }
    ++cursor_;
    if (static_cast<uint16_t>(meta >> 48) == tag_) continue;  // our own frame
    f->id = static_cast<uint32_t>(meta & 0xFFFFFFFFu);
    f->dlc = static_cast<uint8_t>((meta >> 32) & 0xFF);
    const uint64_t flags = (meta >> 40) & 0xFF;
    f->extended = (flags & 1u) != 0;
    f->rtr = (flags & 2u) != 0;
    for (int i = 0; i < 8; ++i) f->data[i] = static_cast<uint8_t>((data >> (8 * i)) & 0xFF);
    ++stats_.rx_frames;
    return true;
  }
}

Result<bool> ShmCanBus::Receive(Frame* f, int timeout_ms) {
  const int64_t deadline = NowUs() + static_cast<int64_t>(timeout_ms) * 1000;
  for (;;) {
    if (shared_->link_down.load(std::memory_order_relaxed) != 0) {
      return MakeError(ErrorCode::kUnavailable, "CAN bus shm:" + name_ + " is down");
    }
    shared_->waiters.fetch_add(1);
    const uint32_t word = shared_->futex_word.load();
    if (TryRead(f)) {
      shared_->waiters.fetch_sub(1);
      return true;
    }
    const int64_t left = deadline - NowUs();
    if (left <= 0) {
      shared_->waiters.fetch_sub(1);
      return false;
    }
    // A slot stuck mid-write is re-checked after a short nap rather than the full timeout.
    const int64_t nap = stuck_since_us_ != 0 ? std::min<int64_t>(left, 5000) : left;
    timespec ts{static_cast<time_t>(nap / 1000000), static_cast<long>((nap % 1000000) * 1000)};
    Futex(&shared_->futex_word, FUTEX_WAIT, word, &ts);
    shared_->waiters.fetch_sub(1);
  }
}

}  // namespace omni::can
