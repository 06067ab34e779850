#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <limits>
#include <optional>
#include <utility>
#include <vector>

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

  static constexpr int kDefaultRebaseAfter = 5;
  explicit StampOrder(int rebase_after = kDefaultRebaseAfter)
      : rebase_after_(rebase_after < 1 ? 1 : rebase_after) {}

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

// A StampOrder that also holds the rejected run's samples, so a re-base loses none of them.
// Add() hands the samples to take, in order, to `take(utime, sample)`: the sample itself when
// in order; nothing when it is older (it is held); on a re-base first `on_rebase(run_first)`
// (the caller drops what it holds stamped at or after it), then the held run and the sample.
// A run broken before it re-bases is given up (`abandoned()` counts its samples).
template <class Sample>
class HeldRun {
 public:
  template <class OnRebase, class Take>
  StampOrder::Verdict Add(int64_t utime, Sample sample, OnRebase on_rebase, Take take) {
    const StampOrder::Verdict v = order_.Check(utime);
    switch (v) {
      case StampOrder::Verdict::kOld:
        if (order_.run_length() == 1) {
          abandoned_ += static_cast<int64_t>(run_.size());
          run_.clear();
        }
        run_.emplace_back(utime, std::move(sample));
        return v;
      case StampOrder::Verdict::kRebase: {
        on_rebase(order_.run_first());
        std::vector<std::pair<int64_t, Sample>> run;
        run.swap(run_);
        for (auto& [t, s] : run) take(t, std::move(s));
        break;
      }
      case StampOrder::Verdict::kInOrder:
        break;
    }
    take(utime, std::move(sample));
    return v;
  }
  const StampOrder& order() const { return order_; }
  int64_t abandoned() const { return abandoned_; }
  // Forgets the order and the held run (the caller dropped what it held).
  void Reset() {
    order_.Reset();
    run_.clear();
  }
  // Orders from `utime` on (e.g. the newest sample the caller still holds).
  void Seed(int64_t utime) { (void)order_.Check(utime); }

 private:
  StampOrder order_;
  std::vector<std::pair<int64_t, Sample>> run_;
  int64_t abandoned_ = 0;
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
  // What Restore(utime) would drop, without dropping it: how many remembered entries, the
  // oldest one's stamp, whether every remembered entry (`all`: older
  // ones may have been forgotten), and the stamp of the newest entry it would keep.
  struct Split {
    size_t count = 0;
    std::optional<int64_t> oldest_dropped, newest_kept;
    bool all = false;
  };
  Split SplitAt(int64_t utime) const {
    Split s;
    auto it = items_.rbegin();
    for (; it != items_.rend() && it->first >= utime; ++it) {
      ++s.count;
      s.oldest_dropped = it->first;
    }
    if (it != items_.rend())
      s.newest_kept = it->first;
    else
      s.all = s.count > 0;
    return s;
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
