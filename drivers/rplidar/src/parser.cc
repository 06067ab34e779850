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

void MeasurementParser::ParseStandard(int64_t utime, bool at_end, std::vector<Sample>* out) {
  while (true) {
    const size_t avail = buf_.size() - pos_;
    if (in_sync_) {
      if (avail < kSampleSize) return;
      if (NodeOk(pos_) && (!have_last_ || Near(last_angle_, NodeAngle(pos_)))) {
        Sample s = DecodeStandardSample(&buf_[pos_]);
        s.utime = utime;
        out->push_back(s);
        ++counters_.samples;
        have_last_ = true;
        last_angle_ = s.angle_deg;
        pos_ += kSampleSize;
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
    size_t need = static_cast<size_t>(lookahead_);
    if (avail < need * kSampleSize) {
      if (!at_end || avail < kSampleSize) return;
      need = avail / kSampleSize;
    }
    bool ok = true;
    for (size_t k = 0; k < need && ok; ++k) {
      ok = NodeOk(pos_ + k * kSampleSize) &&
           (k == 0 ||
            Near(NodeAngle(pos_ + (k - 1) * kSampleSize), NodeAngle(pos_ + k * kSampleSize)));
    }
    if (ok) {
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
    ++counters_.capsules;
    if (c.start) have_prev_capsule_ = false;  // first capsule of a new scan: no predecessor
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
  if (s.start) {
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
  current_.push_back(s);
  return completed;
}

}  // namespace omni::rplidar
