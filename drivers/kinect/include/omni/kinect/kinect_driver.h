// The Kinect driver state machine (no bus): opens a DepthSource, waits for its first depth
// frame before calling it streaming, reads its frames, counts frames lost on the way (gaps in
// the device's frame index or timestamps) and frames it could not use, and when the device
// vanishes (read error, or no depth for `data_timeout_s`) or opens without ever sending depth
// closes it and reopens it every `reconnect_interval_s` until it streams again; the process
// never has to restart.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "omni/common/result.h"
#include "omni/common/time.h"
#include "omni/kinect/depth_codec.h"
#include "omni/kinect/depth_source.h"

namespace omni {
class ConfigReader;
}  // namespace omni

namespace omni::kinect {

struct KinectDriverOptions {
  std::string uri;  // "" = first device found; "Dummy" = OpenNI2's built-in test device
  bool color = true;
  bool register_depth_to_color = true;
  double fps = 30.0;  // nominal rate; a timestamp gap over 1.5 periods counts missed frames
  double data_timeout_s = 2.0;
  double reconnect_interval_s = 1.0;
  double fallback_hfov_deg = 58.5;  // when the device reports no field of view
  double fallback_vfov_deg = 45.6;
};

struct KinectNodeOptions {
  std::string depth_channel = "DEPTH";
  std::string color_channel = "RGB";
  std::string depth_frame = "depth_optical";
  std::string color_frame = "rgb_optical";
  std::string encoding = "DELTA_ZLIB";  // RAW | ZLIB | DELTA_ZLIB
  int zlib_level = 1;
  std::string bus_url;
};

Status LoadKinectOptions(const std::string& path, KinectDriverOptions* driver,
                         KinectNodeOptions* node);
// The same from a reader already open (a string in the config fuzz target); Finish()es it.
Status LoadKinectOptions(ConfigReader& reader, KinectDriverOptions* driver,
                         KinectNodeOptions* node);
// "RAW" / "ZLIB" / "DELTA_ZLIB" -> the codec's encoding; false for other names.
bool ParseDepthEncoding(const std::string& name, DepthEncoding* out);

struct KinectCounters {
  int64_t depth_frames = 0;
  int64_t color_frames = 0;
  int64_t dropped_frames = 0;    // depth frames missing from the index/timestamp sequence
  int64_t bad_frames = 0;        // frames the source could not use (kParse): skipped
  int64_t reconnects = 0;        // first depth frames after a loss (the device streams again)
  int64_t connect_failures = 0;  // open attempts that failed, or gave no depth frame in time
  int64_t device_errors = 0;     // read errors and data timeouts that lost a streaming device
  int64_t color_stalls = 0;      // colour stopped for data_timeout_s while depth went on
};

// kOpening: the source opened but has not sent a depth frame yet. Some devices open and then
// never send (reported for the Kinect v1 on some USB 3 ports), so only the first depth frame
// means streaming.
enum class KinectState { kDisconnected, kOpening, kStreaming };

// Microseconds on a clock that never steps (std::chrono::steady_clock by default). The data
// timeout and the retry delay are measured on it: a wall clock stepped forward by NTP would
// look like a silent device, one stepped back would postpone the timeout.
using MonotonicNow = std::function<int64_t()>;

// Counts frames missing between consecutive depth frames: by frame index when the device
// numbers its frames, else by timestamp gaps longer than 1.5 nominal periods.
class GapCounter {
 public:
  explicit GapCounter(double fps) : period_us_(fps > 0 ? 1e6 / fps : 0) {}
  int64_t Add(int64_t frame_index, int64_t timestamp_us);
  void Reset() { have_ = false; }

 private:
  double period_us_;
  bool have_ = false;
  int64_t last_index_ = -1;
  int64_t last_ts_ = 0;
};

class KinectDriver {
 public:
  // `now_us` times the data timeouts and reconnect delays (tests pass a ManualClock's time).
  // The driver reads no wall clock: the node stamps the messages.
  KinectDriver(KinectDriverOptions options, std::unique_ptr<DepthSource> source,
               MonotonicNow now_us = MonotonicMicros);
  ~KinectDriver();
  // Opens the source (state kOpening until its first depth frame); the error names the
  // device (URI) when it is absent.
  Status Connect();
  // Reads for at most `timeout_ms`; on loss closes the source and retries later.
  void Step(int timeout_ms, SourceFrames* out);
  void Shutdown();

  KinectState state() const { return state_; }
  const std::string& status_text() const { return status_; }
  // The source's Warning() from the last open (colour off, ...); empty when none.
  const std::string& warning() const { return warning_; }
  // Whether any depth frame has arrived since the process started.
  bool ever_streamed() const { return ever_streamed_; }
  // While streaming with colour on (and opened): why colour is missing ("" while it comes). A
  // colour endpoint can stall while depth goes on (a Kinect v1 on some USB controllers); the
  // 3D map is then built without colour, which the heartbeat must say.
  std::string ColorProblem() const;
  const KinectCounters& counters() const { return counters_; }
  const KinectDriverOptions& options() const { return options_; }

 private:
  void Lose(const std::string& why);
  void FailOpening(const std::string& why);
  void Retry(const std::string& why);

  KinectDriverOptions options_;
  std::unique_ptr<DepthSource> source_;
  MonotonicNow now_us_;
  KinectState state_ = KinectState::kDisconnected;
  std::string status_ = "starting";
  std::string warning_;
  std::string last_bad_frame_;  // why the last unusable frame was skipped, "" after good depth
  KinectCounters counters_;
  GapCounter gaps_;
  bool ever_streamed_ = false;
  int64_t opened_us_ = 0;       // monotonic
  int64_t last_data_us_ = 0;    // monotonic
  int64_t color_since_us_ = 0;  // monotonic: the last colour frame, or when streaming began
  bool color_stalled_ = false;
  int64_t next_attempt_us_ = 0;  // monotonic
};

}  // namespace omni::kinect
