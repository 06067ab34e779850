// Messages lost in transit, counted from a stream's sequence numbers (+1 per message at the
// sender): the gaps between them, with late (reordered) messages and a restarted sender told
// apart from losses.
#pragma once

#include <algorithm>
#include <cstdint>

namespace omni {

class SeqGaps {
 public:
  // A number more than kLateWindow behind the newest, or kRestartGap or more ahead of it, is
  // not a reordering or a loss: the sender restarted (its count began again) or the number is
  // corrupt. Counting starts again from it.
  static constexpr int64_t kLateWindow = 100;
  static constexpr int64_t kRestartGap = 1000000;

  // `late_window`: how far behind the newest a number may be and still be a late message (a
  // stream whose sender restarts early in its count wants a small one).
  explicit SeqGaps(int64_t late_window = kLateWindow) : late_window_(late_window) {}

  // Takes the next message's number (< 0: the sender does not number them; ignored). A number
  // above the newest counts the ones skipped as lost; one below it, within kLateWindow, is a
  // late message: it fills one of the gaps counted (lost goes down by one) and the newest stays.
  void Add(int64_t seq) {
    if (seq < 0) return;
    if (newest_ < 0) {
      newest_ = seq;
      return;
    }
    if (seq > newest_) {
      const int64_t gap = seq - newest_ - 1;  // both >= 0: no overflow
      if (gap >= kRestartGap) {
        ++restarts_;
      } else {
        lost_ += gap;
      }
      newest_ = seq;
    } else if (seq < newest_) {
      if (newest_ - seq > late_window_) {
        ++restarts_;
        newest_ = seq;
      } else {
        ++late_;
        lost_ = std::max<int64_t>(0, lost_ - 1);
      }
    }
  }
  int64_t newest() const { return newest_; }  // -1 before the first numbered message
  int64_t lost() const { return lost_; }
  int64_t late() const { return late_; }  // arrived after a higher number
  int64_t restarts() const { return restarts_; }

 private:
  int64_t late_window_;
  int64_t newest_ = -1;
  int64_t lost_ = 0;
  int64_t late_ = 0;
  int64_t restarts_ = 0;
};

}  // namespace omni
