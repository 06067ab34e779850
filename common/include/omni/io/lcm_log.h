// LCM log files (the format of lcm-logger), read and written without the LCM library so
// corrupt files get precise errors. Each event: sync word 0xEDA1DA01, event number (int64),
// timestamp (int64, microseconds), channel length (int32), data length (int32), channel, data;
// all integers big-endian.
#pragma once

#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "omni/common/result.h"

namespace omni::io {

struct LcmLogEvent {
  int64_t event_number = 0;
  int64_t utime = 0;  // log timestamp, microseconds
  std::string channel;
  std::vector<uint8_t> data;
  uint64_t offset = 0;  // byte offset of the event in the file
};

class LcmLogReader {
 public:
  static Result<LcmLogReader> Open(const std::string& path);
  // A reader of an open, seekable stdio stream (a file, or a stream of fopencookie's), which it
  // closes; `name` stands for the path in errors.
  static Result<LcmLogReader> FromStream(std::FILE* f, std::string name);
  LcmLogReader(LcmLogReader&&) noexcept;
  LcmLogReader& operator=(LcmLogReader&&) noexcept;
  ~LcmLogReader();
  // Reads the next event. Returns true with an event, false at a clean end of file, or an
  // error naming the file and byte offset for a corrupt or truncated event. With
  // `resync` set, a corrupt region is skipped to the next sync word instead (counted in
  // skipped_bytes()) and only a truncated final event is an error. A failed read is an I/O
  // error (ErrorCode::kIo) either way, never an end of file or a truncation; the next call
  // reads again from the start of the event it happened in.
  Result<bool> Next(LcmLogEvent* event, bool resync = false);
  uint64_t skipped_bytes() const { return skipped_bytes_; }
  // After an error from Next: the file ends inside the event (a recording cut short, the
  // usual end of a log whose writer lost power); every complete event before it was read.
  bool truncated_tail() const { return truncated_tail_; }
  const std::string& path() const { return path_; }

 private:
  LcmLogReader(std::FILE* f, std::string path) : f_(f), path_(std::move(path)) {}
  std::FILE* f_ = nullptr;
  std::string path_;
  uint64_t offset_ = 0;
  uint64_t skipped_bytes_ = 0;
  bool truncated_tail_ = false;
  bool reseek_ = false;               // an I/O error happened: seek to offset_ before reading on
  bool seek_failed_ = false;          // a seek failed in this call of Next (an I/O error)
  bool Seek(uint64_t offset);         // sets seek_failed_ when it fails
  bool SyncWordAfter(uint64_t from);  // moves the file position
};

// Walks the event headers of a log, seeking over channels and data, and names the first event
// whose framing is broken (bad sync word, lengths out of range, or truncated at the end): the
// check LcmLogReader::Next makes, without reading the payloads, so a multi-GB log takes well
// under a second. An unreadable file is an error too.
Status CheckLcmLogFraming(const std::string& path);

class LcmLogWriter {
 public:
  static Result<LcmLogWriter> Open(const std::string& path);
  LcmLogWriter(LcmLogWriter&&) noexcept;
  LcmLogWriter& operator=(LcmLogWriter&&) noexcept;
  ~LcmLogWriter();
  Status Write(int64_t utime, const std::string& channel, const void* data, size_t size);
  Status Close();
  int64_t events_written() const { return next_event_; }

 private:
  LcmLogWriter(std::FILE* f, std::string path) : f_(f), path_(std::move(path)) {}
  std::FILE* f_ = nullptr;
  std::string path_;
  int64_t next_event_ = 0;
};

}  // namespace omni::io
