#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <limits>
#include <optional>
#include <utility>

namespace omni {

// Keeps one stream's timestamps in order, and recovers when the newest accepted stamp was the
// bad one. A stamp older than the newest accepted one is normally rejected (a reordered or
// late message). But one message stamped far in the future (a clock glitch, a corrupt field)
// would otherwise make every later message "old" for as long as the glitch is ahead, and a
// source whose clock is set back (NTP step, device reboot, a log replayed again) would be shut
// out for good. So when `rebase_after` consecutive rejected stamps are in order among
// themselves, the stream's newest stamp is moved back to them (`kRebase`): the caller drops
// what it holds that is newer than the run's first stamp and takes the run. Equal stamps are
// in order.
class StampOrder {
 public:
  enum class Verdict {
    kInOrder,  // not older than the newest accepted stamp: take it
    kOld,      // older: reject it (it may start or extend a run)
    kRebase,   // older, and completes a run of `rebase_after`: take it, drop what is newer
  };

  explicit StampOrder(int rebase_after = 5) : rebase_after_(rebase_after < 1 ? 1 : rebase_after) {}

  Verdict Check(int64_t utime) {
    if (!have_ || utime >= newest_) {
      Accept(utime);
      return Verdict::kInOrder;
    }
    if (run_ > 0 && utime >= run_last_) {
      ++run_;
    } else {
      run_ = 1;
      run_first_ = utime;
    }
    run_last_ = utime;
    if (run_ < rebase_after_) return Verdict::kOld;
    ++rebases_;
    Accept(utime);
    return Verdict::kRebase;
  }

  bool have() const { return have_; }
  int64_t newest() const { return have_ ? newest_ : std::numeric_limits<int64_t>::min(); }
  // While a run is open (the last Check was kOld): how many stamps it holds and the first.
  int run_length() const { return run_; }
  int64_t run_first() const { return run_first_; }
  int64_t run_last() const { return run_last_; }
  int64_t rebases() const { return rebases_; }
  void Reset() {
    have_ = false;
    run_ = 0;
  }

 private:
  void Accept(int64_t utime) {
    have_ = true;
    newest_ = utime;
    run_ = 0;
  }

  int rebase_after_;
  bool have_ = false;
  int64_t newest_ = 0;
  int run_ = 0;
  int64_t run_first_ = 0, run_last_ = 0;
  int64_t rebases_ = 0;
};

// The state a stream's consumer had after each of its last samples (e.g. an odometry jump
// correction), so a re-base can put it back as it was before the dropped samples: Restore()
// pops the entries stamped at or after `utime` and returns the newest one left, or — when every
// remembered entry was dropped (a source whose clock went back) — the newest dropped one.
template <class State>
class StateHistory {
 public:
  explicit StateHistory(size_t capacity = 256) : capacity_(capacity) {}
  void Push(int64_t utime, const State& s) {
    items_.emplace_back(utime, s);
    while (items_.size() > capacity_) items_.pop_front();
  }
  std::optional<State> Restore(int64_t utime) {
    std::optional<State> newest_dropped;
    while (!items_.empty() && items_.back().first >= utime) {
      if (!newest_dropped) newest_dropped = items_.back().second;
      items_.pop_back();
    }
    if (!items_.empty()) return items_.back().second;
    return newest_dropped;
  }

 private:
  size_t capacity_;
  std::deque<std::pair<int64_t, State>> items_;
};

}  // namespace omni
