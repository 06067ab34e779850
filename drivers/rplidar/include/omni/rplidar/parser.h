// Streaming decoder of RPLidar measurement bytes (after the response descriptor).
//
// It never trusts a length or an alignment. The stream starts aligned (a scan's nodes follow the
// response descriptor; captures start at a node). Standard nodes are accepted one by one while
// each passes its check bits, has an angle below 360 degrees and lies within `max_step_deg` of
// the previous sample (consecutive samples of a real scan are < 10 degrees apart). After a
// failure the parser slides byte by byte until `resync_lookahead` consecutive nodes pass all
// three tests (a random 5-byte string passes the check bits 1 time in 4), so garbage costs only
// the bytes it corrupted. A node is emitted once the bytes after it are known: if real nodes
// start inside its window (a byte lost in transit) it is dropped, not a phantom sample.
// Express capsules are located by their sync
// nibbles and XOR checksum. Every failure is counted.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "omni/rplidar/protocol.h"

namespace omni::rplidar {

enum class StreamMode { kStandard, kExpressLegacy };

struct ParserCounters {
  int64_t samples = 0;          // samples produced
  int64_t checkbit_errors = 0;  // standard nodes that failed S/!S or C while in sync
  int64_t checksum_errors = 0;  // express capsules with good sync nibbles but a bad checksum
  int64_t resyncs = 0;          // times the parser lost and regained alignment
  int64_t bytes_skipped = 0;    // bytes discarded while searching for alignment
  int64_t capsules = 0;         // express capsules accepted
  int64_t bad_angles = 0;       // nodes with an angle >= 360 degrees (rejected)
  int64_t angle_jumps = 0;      // nodes that passed the checks but jumped > max_step_deg
  int64_t unconfirmed = 0;      // windows that passed the checks but had real nodes starting
                                // inside them (a byte lost in transit): dropped, not emitted
};

class MeasurementParser {
 public:
  explicit MeasurementParser(StreamMode mode = StreamMode::kStandard, int resync_lookahead = 4,
                             double max_step_deg = 20.0);

  // Appends the samples completed by `data` to `out`; `utime` is the host time the bytes arrived.
  void Feed(const uint8_t* data, size_t size, int64_t utime, std::vector<Sample>* out);
  // Decodes what is left at the end of a capture with a shorter lookahead.
  void Finish(int64_t utime, std::vector<Sample>* out);
  // Forgets buffered bytes and alignment (after a reconnect or a new scan command).
  void Reset(StreamMode mode);

  StreamMode mode() const { return mode_; }
  const ParserCounters& counters() const { return counters_; }

 private:
  void ParseStandard(int64_t utime, bool at_end, std::vector<Sample>* out);
  enum class LineUp { kYes, kNo, kWait };
  // Whether `lookahead_` nodes (fewer at the end of a capture) start at `at`, each passing the
  // checks and near the one before; kWait when more bytes are needed to tell.
  LineUp NodesLineUpAt(size_t at, bool at_end) const;
  void ParseExpress(int64_t utime, std::vector<Sample>* out);
  bool NodeOk(size_t at) const;
  double NodeAngle(size_t at) const;
  bool Near(double a, double b) const;

  StreamMode mode_;
  int lookahead_;
  double max_step_deg_;
  bool have_last_ = false;
  double last_angle_ = 0;
  std::vector<uint8_t> buf_;
  size_t pos_ = 0;
  bool in_sync_ = false;
  bool next_checked_ = false;  // the node at pos_ passed its checks as the last one's successor
  bool ever_synced_ = false;
  bool have_prev_capsule_ = false;
  Capsule prev_capsule_;
  ParserCounters counters_;
};

// Groups samples into revolutions: a revolution ends where the next sample carries the start
// flag. Samples before the first start flag form no revolution (counted as partial). A start
// flag lost in transit (its node corrupted, or a flipped S bit) would join two turns into one
// scan of 720 degrees with twice the scan time: once a revolution has swept
// kMaxSweepDeg (360 + 10; real start flags come within about a degree of a full turn), the
// next sample starts a new one as if flagged (counted as implied_starts).
// Express capsules: the largest plausible step between two capsules' start angles, degrees.
inline constexpr int kMaxCapsuleStepDeg = 90;

class RevolutionAssembler {
 public:
  // Returns true and fills `done` when `s` completed a revolution.
  bool Add(const Sample& s, std::vector<Sample>* done);
  void Reset() {
    current_.clear();
    started_ = false;
    sweep_deg_ = 0;
  }
  static constexpr double kMaxSweepDeg = 370.0;
  // A revolution holds at most this many samples (the SDK's limit per scan; an A3 sends about
  // 1600 a turn at 10 Hz). More without a turn (a motor that does not turn under a forced
  // scan sends samples at one angle) are dropped and counted, so that memory stays bounded.
  static constexpr size_t kMaxSamples = 8192;
  int64_t samples_without_turn() const { return without_turn_; }
  int64_t implied_starts() const { return implied_starts_; }
  size_t pending() const { return current_.size(); }
  int64_t revolutions() const { return revolutions_; }
  int64_t partial_samples_dropped() const { return partial_dropped_; }

 private:
  std::vector<Sample> current_;
  bool started_ = false;
  int64_t revolutions_ = 0;
  int64_t partial_dropped_ = 0;
  double sweep_deg_ = 0;  // angle swept since the revolution's first sample
  int64_t implied_starts_ = 0;
  int64_t without_turn_ = 0;
};

}  // namespace omni::rplidar
