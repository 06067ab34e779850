#include "omni/rplidar/parser.h"

#include <algorithm>
#include <cmath>

namespace omni::rplidar {

MeasurementParser::MeasurementParser(StreamMode mode, int resync_lookahead, double max_step_deg)
    : mode_(mode), lookahead_(std::max(1, resync_lookahead)), max_step_deg_(max_step_deg) {
  Reset(mode);
}

void MeasurementParser::Reset(StreamMode mode) {
  mode_ = mode;
  buf_.clear();
  pos_ = 0;
  in_sync_ = mode == StreamMode::kStandard;  // nodes start right after the descriptor
  ever_synced_ = in_sync_;
  have_last_ = false;
  next_checked_ = false;
  have_prev_capsule_ = false;
}

void MeasurementParser::Feed(const uint8_t* data, size_t size, int64_t utime,
                             std::vector<Sample>* out) {
  buf_.insert(buf_.end(), data, data + size);
  if (mode_ == StreamMode::kStandard) {
    ParseStandard(utime, /*at_end=*/false, out);
  } else {
    ParseExpress(utime, out);
  }
  // Drop consumed bytes once in a while (amortised O(1) per byte).
  if (pos_ > 4096 || pos_ == buf_.size()) {
    buf_.erase(buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(pos_));
    pos_ = 0;
  }
}

void MeasurementParser::Finish(int64_t utime, std::vector<Sample>* out) {
  if (mode_ == StreamMode::kStandard) ParseStandard(utime, /*at_end=*/true, out);
  counters_.bytes_skipped += static_cast<int64_t>(buf_.size() - pos_);
  buf_.clear();
  pos_ = 0;
}

bool MeasurementParser::NodeOk(size_t at) const {
  const uint8_t* p = &buf_[at];
  if (!StandardSampleChecksPass(p)) return false;
  const unsigned angle_q6 = (static_cast<unsigned>(p[2]) << 7) | (static_cast<unsigned>(p[1]) >> 1);
  return angle_q6 < 360u * 64u;
}

double MeasurementParser::NodeAngle(size_t at) const {
  const uint8_t* p = &buf_[at];
  return ((static_cast<unsigned>(p[2]) << 7) | (static_cast<unsigned>(p[1]) >> 1)) / 64.0;
}

bool MeasurementParser::Near(double a, double b) const {
  const double d = std::fabs(std::remainder(a - b, 360.0));
  return d <= max_step_deg_;
}

MeasurementParser::LineUp MeasurementParser::NodesLineUpAt(size_t at, bool at_end) const {
  const size_t avail = buf_.size() > at ? buf_.size() - at : 0;
  size_t need = static_cast<size_t>(lookahead_);
  if (avail < need * kSampleSize) {
    if (!at_end) return LineUp::kWait;
    if (avail < kSampleSize) return LineUp::kNo;
    need = avail / kSampleSize;
  }
  for (size_t k = 0; k < need; ++k) {
    if (!NodeOk(at + k * kSampleSize)) return LineUp::kNo;
    if (k > 0 && !Near(NodeAngle(at + (k - 1) * kSampleSize), NodeAngle(at + k * kSampleSize)))
      return LineUp::kNo;
  }
  return LineUp::kYes;
}

void MeasurementParser::ParseStandard(int64_t utime, bool at_end, std::vector<Sample>* out) {
  while (true) {
    const size_t avail = buf_.size() - pos_;
    if (in_sync_) {
      if (avail < kSampleSize) return;
      // The node at pos_ was checked against the last one already when that was emitted.
      const bool checked = next_checked_;
      next_checked_ = false;
      if (checked || (NodeOk(pos_) && (!have_last_ || Near(last_angle_, NodeAngle(pos_))))) {
        // Held back until what follows it is known. A byte lost in a node's distance field
        // leaves a window of that node's first bytes and the next node's quality byte, which
        // passes every check with a range of ~64 mm x that byte; only the bytes after it show
        // it: real nodes then start 4 bytes in, not 5. Garbage inserted after a good node
        // shows no such line-up inside the window, so that node is kept.
        if (avail < 2 * kSampleSize && !at_end) {
          next_checked_ = checked;
          return;
        }
        const bool next_ok = avail >= 2 * kSampleSize && NodeOk(pos_ + kSampleSize) &&
                             Near(NodeAngle(pos_), NodeAngle(pos_ + kSampleSize));
        if (avail >= 2 * kSampleSize && !next_ok) {
          size_t inside = 0;
          for (size_t o = 1; o < kSampleSize && inside == 0; ++o) {
            const LineUp l = NodesLineUpAt(pos_ + o, at_end);
            if (l == LineUp::kWait) {
              next_checked_ = checked;
              return;
            }
            if (l == LineUp::kYes) inside = o;
          }
          if (inside > 0) {
            ++counters_.unconfirmed;
            in_sync_ = false;
            have_last_ = false;
            pos_ += inside;
            counters_.bytes_skipped += static_cast<int64_t>(inside);
            continue;
          }
        }
        Sample s = DecodeStandardSample(&buf_[pos_]);
        s.utime = utime;
        out->push_back(s);
        ++counters_.samples;
        have_last_ = true;
        last_angle_ = s.angle_deg;
        pos_ += kSampleSize;
        next_checked_ = next_ok;
        continue;
      }
      const uint8_t* p = &buf_[pos_];
      if (NodeOk(pos_)) {
        // A plausible node far from the last sample: garbage that passed the checks, or real
        // samples lost in transit. Search again from here; the lookahead decides.
        ++counters_.angle_jumps;
        in_sync_ = false;
        have_last_ = false;
        continue;
      }
      if (StandardSampleChecksPass(p)) {
        ++counters_.bad_angles;
      } else {
        ++counters_.checkbit_errors;
      }
      in_sync_ = false;
      ++pos_;
      ++counters_.bytes_skipped;
      continue;
    }
    // Searching: need `lookahead_` consecutive good nodes (fewer at the end of a capture).
    const LineUp l = NodesLineUpAt(pos_, at_end);
    if (l == LineUp::kWait || (l == LineUp::kNo && avail < kSampleSize)) return;
    if (l == LineUp::kYes) {
      in_sync_ = true;
      have_last_ = false;  // the lookahead vouches for this node
      if (ever_synced_) ++counters_.resyncs;
      ever_synced_ = true;
      continue;
    }
    ++pos_;
    ++counters_.bytes_skipped;
  }
}

void MeasurementParser::ParseExpress(int64_t utime, std::vector<Sample>* out) {
  while (buf_.size() - pos_ >= kCapsuleSize) {
    const uint8_t* p = &buf_[pos_];
    if (!CapsuleSyncMatches(p)) {
      if (in_sync_) {
        in_sync_ = false;
        have_prev_capsule_ = false;
      }
      ++pos_;
      ++counters_.bytes_skipped;
      continue;
    }
    if (!CapsuleChecksumMatches(p)) {
      // While aligned this was a capsule damaged in transit; while searching, a chance match.
      if (in_sync_) ++counters_.checksum_errors;
      in_sync_ = false;
      have_prev_capsule_ = false;
      ++pos_;
      ++counters_.bytes_skipped;
      continue;
    }
    if (!in_sync_) {
      if (ever_synced_) ++counters_.resyncs;
      ever_synced_ = true;
      in_sync_ = true;
    }
    const Capsule c = DecodeCapsule(p);
    pos_ += kCapsuleSize;
    // The checks pass by chance once in 4096 windows (4 sync bits, an 8-bit XOR): a start
    // angle of 360 degrees or more is such a capsule, dropped whole; a start far from where the
    // one before ended would spread that capsule's 32 ranges over a wrong arc, so its samples
    // are dropped (a capsule spans a few degrees: 32 samples at 2-16 kHz and 5-20 Hz).
    if (c.start_angle_q6 >= 360 * 64) {
      ++counters_.bad_angles;
      have_prev_capsule_ = false;
      continue;
    }
    ++counters_.capsules;
    if (c.start) have_prev_capsule_ = false;  // first capsule of a new scan: no predecessor
    if (have_prev_capsule_) {
      const int step = (static_cast<int>(c.start_angle_q6) -
                        static_cast<int>(prev_capsule_.start_angle_q6) + 360 * 64) %
                       (360 * 64);
      if (step > kMaxCapsuleStepDeg * 64) {
        ++counters_.angle_jumps;
        have_prev_capsule_ = false;
      }
    }
    if (have_prev_capsule_) {
      const size_t before = out->size();
      CapsuleToSamples(prev_capsule_, c, utime, out);
      counters_.samples += static_cast<int64_t>(out->size() - before);
    }
    prev_capsule_ = c;
    have_prev_capsule_ = true;
  }
}

bool RevolutionAssembler::Add(const Sample& s, std::vector<Sample>* done) {
  bool completed = false;
  bool start = s.start;
  if (started_ && !current_.empty()) {
    // Signed step, so a sample a little behind the last (jitter) takes sweep off, not 359 on.
    const double step = std::remainder(s.angle_deg - current_.back().angle_deg, 360.0);
    if (!start && sweep_deg_ + step > kMaxSweepDeg) {
      start = true;
      ++implied_starts_;
    }
    sweep_deg_ += step;
  }
  if (start) {
    sweep_deg_ = 0;
    if (started_ && !current_.empty()) {
      done->swap(current_);
      current_.clear();
      ++revolutions_;
      completed = true;
    } else {
      partial_dropped_ += static_cast<int64_t>(current_.size());
      current_.clear();
    }
    started_ = true;
  }
  if (current_.size() >= kMaxSamples) {
    without_turn_ += static_cast<int64_t>(current_.size());
    current_.clear();
    started_ = false;  // the next start flag begins a revolution
    sweep_deg_ = 0;
  }
  current_.push_back(s);
  return completed;
}

}  // namespace omni::rplidar
