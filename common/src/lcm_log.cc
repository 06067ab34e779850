#include "omni/io/lcm_log.h"

#include <sys/types.h>
#include <algorithm>

#include <cerrno>
#include <cstring>

namespace omni::io {
namespace {

constexpr uint32_t kSync = 0xEDA1DA01u;
constexpr int32_t kMaxChannel = 255;
constexpr int32_t kMaxData = 256 * 1024 * 1024;

uint64_t Be(const uint8_t* p, int n) {
  uint64_t v = 0;
  for (int i = 0; i < n; ++i) v = (v << 8) | p[i];
  return v;
}
// An event header's lengths, or what is wrong with it ("" when it is good): the one framing rule
// for the reader and for CheckLcmLogFraming.
std::string CheckHeader(const uint8_t* hdr, int32_t* chan_len, int32_t* data_len) {
  const uint32_t sync = static_cast<uint32_t>(Be(hdr, 4));
  *chan_len = static_cast<int32_t>(Be(hdr + 20, 4));
  *data_len = static_cast<int32_t>(Be(hdr + 24, 4));
  if (sync != kSync) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), "bad sync word 0x%08X (expected 0xEDA1DA01)", sync);
    return buf;
  }
  if (*chan_len <= 0 || *chan_len > kMaxChannel)
    return "channel length " + std::to_string(*chan_len) + " out of range";
  if (*data_len < 0 || *data_len > kMaxData)
    return "data length " + std::to_string(*data_len) + " out of range";
  return "";
}

void PutBe(uint8_t* p, uint64_t v, int n) {
  for (int i = n - 1; i >= 0; --i) {
    p[i] = static_cast<uint8_t>(v & 0xff);
    v >>= 8;
  }
}

}  // namespace

Result<LcmLogReader> LcmLogReader::Open(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f)
    return MakeError(ErrorCode::kNotFound,
                     "cannot open LCM log '" + path + "': " + std::strerror(errno));
  return LcmLogReader(f, path);
}

Result<LcmLogReader> LcmLogReader::FromStream(std::FILE* f, std::string name) {
  if (!f) return MakeError(ErrorCode::kInvalidArgument, "no stream to read '" + name + "' from");
  return LcmLogReader(f, std::move(name));
}

LcmLogReader::LcmLogReader(LcmLogReader&& o) noexcept
    : f_(o.f_),
      path_(std::move(o.path_)),
      offset_(o.offset_),
      skipped_bytes_(o.skipped_bytes_),
      truncated_tail_(o.truncated_tail_),
      reseek_(o.reseek_),
      seek_failed_(o.seek_failed_) {
  o.f_ = nullptr;
}
LcmLogReader& LcmLogReader::operator=(LcmLogReader&& o) noexcept {
  if (this != &o) {
    if (f_) std::fclose(f_);
    f_ = o.f_;
    path_ = std::move(o.path_);
    offset_ = o.offset_;
    skipped_bytes_ = o.skipped_bytes_;
    truncated_tail_ = o.truncated_tail_;
    reseek_ = o.reseek_;
    seek_failed_ = o.seek_failed_;
    o.f_ = nullptr;
  }
  return *this;
}
LcmLogReader::~LcmLogReader() {
  if (f_) std::fclose(f_);
}

bool LcmLogReader::Seek(uint64_t offset) {
  if (fseeko(f_, static_cast<off_t>(offset), SEEK_SET) == 0) return true;
  seek_failed_ = true;
  return false;
}

bool LcmLogReader::SyncWordAfter(uint64_t from) {
  if (!Seek(from)) return false;
  uint32_t window = 0;
  int have = 0, c;
  while ((c = std::fgetc(f_)) != EOF) {
    window = (window << 8) | static_cast<uint32_t>(c);
    if (++have >= 4 && window == kSync) return true;
  }
  return false;
}

Result<bool> LcmLogReader::Next(LcmLogEvent* ev, bool resync) {
  auto where = [&](uint64_t off) { return path_ + ": byte offset " + std::to_string(off) + ": "; };
  // A read that fails (a failing disk, a network file system gone) is an I/O error, never taken
  // for the end of the file or for a truncated event; the next call tries again from the event
  // the failure was in.
  int read_errno = 0;
  auto failed = [&]() {
    if (!std::ferror(f_) && !seek_failed_) return false;
    if (read_errno == 0) read_errno = errno != 0 ? errno : EIO;
    return true;
  };
  // The error for a failed read or seek in the event at `start`, where the next call starts
  // again.
  auto read_error = [&](uint64_t start) {
    const off_t pos = ftello(f_);
    const char* what = seek_failed_ ? "seek error" : "read error";
    offset_ = start;
    reseek_ = true;
    seek_failed_ = false;
    return MakeError(ErrorCode::kIo,
                     where(start) + what +
                         (pos >= 0 ? " (near byte offset " + std::to_string(pos) + ")" : "") +
                         ": " + std::strerror(read_errno));
  };
  errno = 0;
  if (reseek_) {  // after an I/O error: from the start of the event it happened in
    std::clearerr(f_);
    if (!Seek(offset_)) return read_error(offset_);
    reseek_ = false;
  }
  // Resync: from `from`, forward to the next sync word; the bytes from `start` on are counted as
  // skipped. False at the end of the file or on a read error (failed() tells which).
  auto scan_from = [&](uint64_t start, uint64_t from) {
    offset_ = from;
    if (!Seek(from)) return false;
    uint32_t window = 0;
    int c;
    int have = 0;
    while ((c = std::fgetc(f_)) != EOF) {
      window = (window << 8) | static_cast<uint32_t>(c);
      ++offset_;
      if (++have >= 4 && window == kSync) break;
    }
    if (c == EOF) {
      if (failed()) return false;  // the bytes not read are not counted as skipped
      skipped_bytes_ += offset_ - start;
      return false;
    }
    offset_ -= 4;
    if (!Seek(offset_)) return false;
    skipped_bytes_ += offset_ - start;
    return true;
  };
  for (;;) {
    const uint64_t start = offset_;
    uint8_t hdr[28];
    const size_t n = std::fread(hdr, 1, sizeof(hdr), f_);
    if (n < sizeof(hdr) && failed()) return read_error(start);  // a folder, a failing disk
    if (n == 0) return false;
    if (n < sizeof(hdr)) {
      truncated_tail_ = true;
      return MakeError(ErrorCode::kParse, where(start) + "truncated event header (" +
                                              std::to_string(n) +
                                              " of 28 bytes): the log ends "
                                              "inside an event");
    }
    int32_t chan_len = 0, data_len = 0;
    const std::string problem = CheckHeader(hdr, &chan_len, &data_len);
    if (!problem.empty()) {
      if (!resync) return MakeError(ErrorCode::kParse, where(start) + problem);
      if (!scan_from(start, start + 1)) {
        if (failed()) return read_error(start);
        return false;
      }
      continue;
    }
    ev->event_number = static_cast<int64_t>(Be(hdr + 4, 8));
    ev->utime = static_cast<int64_t>(Be(hdr + 12, 8));
    ev->offset = start;
    ev->channel.resize(static_cast<size_t>(chan_len));
    // The data in chunks: a header that announces 256 MB at the end of a short file costs what
    // the file holds, not what the header says.
    const auto read_data = [&]() {
      const size_t want = static_cast<size_t>(data_len);
      constexpr size_t kChunk = size_t{1} << 20;
      ev->data.clear();
      while (ev->data.size() < want) {
        const size_t have = ev->data.size();
        ev->data.resize(have + std::min(kChunk, want - have));
        const size_t got = std::fread(ev->data.data() + have, 1, ev->data.size() - have, f_);
        if (have + got < ev->data.size()) {
          ev->data.resize(have + got);
          return false;
        }
      }
      return true;
    };
    const std::string announced = "channel " + std::to_string(chan_len) + " + data " +
                                  std::to_string(data_len) + " bytes announced";
    if (std::fread(ev->channel.data(), 1, ev->channel.size(), f_) != ev->channel.size() ||
        !read_data()) {
      if (failed()) return read_error(start);
      // Past the end of the file: a truncated last event, or a corrupt length with intact
      // events after it, which a resync finds.
      if (resync && scan_from(start, start + 1)) continue;
      const bool events_follow = !resync && SyncWordAfter(start + 1);
      if (failed()) return read_error(start);
      if (!events_follow) {
        truncated_tail_ = true;
        return MakeError(ErrorCode::kParse, where(start) + "event truncated: " + announced +
                                                ": the log ends inside it");
      }
      return MakeError(ErrorCode::kParse, where(start) + "event truncated: " + announced +
                                              "; events follow (its length is corrupt)");
    }
    offset_ =
        start + sizeof(hdr) + static_cast<uint64_t>(chan_len) + static_cast<uint64_t>(data_len);
    // An event is intact only if the next event or the end of the file follows it. A length
    // corrupted to a value still inside the file would otherwise swallow the events after it
    // as its data.
    uint8_t next[4];
    const size_t got = std::fread(next, 1, sizeof(next), f_);
    if (got < sizeof(next) && failed()) return read_error(start);
    if (got > 0 && !Seek(offset_)) return read_error(start);
    if (got < sizeof(next) || Be(next, 4) == kSync) return true;
    // Not followed by an event. When the data holds a sync word, the length is the likely
    // culprit (it swallowed the events after it): an error naming this event, or with resync a
    // search restarting inside it. Otherwise the event stands and the bytes after it are the
    // damage, which the next call reports (or skips).
    static constexpr uint8_t kSyncBytes[4] = {0xED, 0xA1, 0xDA, 0x01};
    // A length 1-3 bytes too large takes the start of the next event's sync word into this
    // one's data: the word then straddles the data's end and the 4 bytes after it. Treated as
    // a sync word inside the data, or the next event would be lost with this one's damage.
    uint8_t edge[7];
    const size_t tail = std::min<size_t>(3, ev->data.size());
    std::copy(ev->data.end() - static_cast<std::ptrdiff_t>(tail), ev->data.end(), edge);
    std::copy(next, next + sizeof(next), edge + tail);
    const bool straddles = std::search(edge, edge + tail + sizeof(next), kSyncBytes,
                                       kSyncBytes + 4) != edge + tail + sizeof(next);
    if (!straddles &&
        std::search(ev->data.begin(), ev->data.end(), kSyncBytes, kSyncBytes + 4) == ev->data.end())
      return true;
    if (!resync) {
      return MakeError(ErrorCode::kParse,
                       where(start) + "event on '" + ev->channel + "' (" + announced +
                           ") holds event headers and is not followed by another event: its "
                           "length is corrupt");
    }
    if (!scan_from(start, start + 1)) {
      if (failed()) return read_error(start);
      return false;
    }
  }
}

Result<LcmLogWriter> LcmLogWriter::Open(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f)
    return MakeError(ErrorCode::kIo,
                     "cannot create LCM log '" + path + "': " + std::strerror(errno));
  return LcmLogWriter(f, path);
}
LcmLogWriter::LcmLogWriter(LcmLogWriter&& o) noexcept
    : f_(o.f_), path_(std::move(o.path_)), next_event_(o.next_event_) {
  o.f_ = nullptr;
}
LcmLogWriter& LcmLogWriter::operator=(LcmLogWriter&& o) noexcept {
  if (this != &o) {
    if (f_) std::fclose(f_);
    f_ = o.f_;
    path_ = std::move(o.path_);
    next_event_ = o.next_event_;
    o.f_ = nullptr;
  }
  return *this;
}
LcmLogWriter::~LcmLogWriter() {
  if (f_) std::fclose(f_);
}

Status LcmLogWriter::Write(int64_t utime, const std::string& channel, const void* data,
                           size_t size) {
  if (!f_) return MakeError(ErrorCode::kIo, "LCM log '" + path_ + "' is closed");
  if (channel.empty() || channel.size() > static_cast<size_t>(kMaxChannel))
    return MakeError(ErrorCode::kInvalidArgument, "channel name must be 1..255 bytes");
  // The reader refuses more (and the 4-byte length field would wrap at 4 GiB, losing the
  // framing of every event after it): refused here, before anything is written.
  if (size > static_cast<size_t>(kMaxData))
    return MakeError(ErrorCode::kInvalidArgument,
                     "an event of " + std::to_string(size) + " bytes on " + channel +
                         " is more than an LCM log event holds here (" + std::to_string(kMaxData) +
                         " bytes); not written");
  uint8_t hdr[28];
  PutBe(hdr, kSync, 4);
  PutBe(hdr + 4, static_cast<uint64_t>(next_event_), 8);
  PutBe(hdr + 12, static_cast<uint64_t>(utime), 8);
  PutBe(hdr + 20, channel.size(), 4);
  PutBe(hdr + 24, size, 4);
  if (std::fwrite(hdr, 1, sizeof(hdr), f_) != sizeof(hdr) ||
      std::fwrite(channel.data(), 1, channel.size(), f_) != channel.size() ||
      (size > 0 && std::fwrite(data, 1, size, f_) != size)) {
    return MakeError(ErrorCode::kIo,
                     "write to LCM log '" + path_ + "' failed: " + std::strerror(errno));
  }
  ++next_event_;
  return Status::Ok();
}

Status LcmLogWriter::Close() {
  if (!f_) return Status::Ok();
  const int r = std::fclose(f_);
  f_ = nullptr;
  if (r != 0) return MakeError(ErrorCode::kIo, "closing LCM log '" + path_ + "' failed");
  return Status::Ok();
}

Status CheckLcmLogFraming(const std::string& path) {
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f)
    return MakeError(ErrorCode::kIo, "cannot open LCM log '" + path + "': " + std::strerror(errno));
  if (fseeko(f.get(), 0, SEEK_END) != 0)
    return MakeError(ErrorCode::kIo, "cannot seek in '" + path + "'");
  const uint64_t size = static_cast<uint64_t>(ftello(f.get()));
  uint64_t off = 0;
  auto bad = [&](const std::string& what) {
    return MakeError(ErrorCode::kParse,
                     path + ": byte offset " + std::to_string(off) + ": " + what);
  };
  uint64_t prev = 0;
  bool have_prev = false;
  while (off < size) {
    uint8_t hdr[28];
    if (size - off < sizeof(hdr)) return bad("truncated event header");
    if (fseeko(f.get(), static_cast<off_t>(off), SEEK_SET) != 0 ||
        std::fread(hdr, 1, sizeof(hdr), f.get()) != sizeof(hdr))
      return MakeError(ErrorCode::kIo, "cannot read '" + path + "'");
    int32_t chan_len = 0, data_len = 0;
    if (const std::string problem = CheckHeader(hdr, &chan_len, &data_len); !problem.empty()) {
      if (!have_prev) return bad(problem);
      // The event before ended here by its lengths, and no event starts here: those lengths
      // are the likely damage (or these bytes are).
      return MakeError(ErrorCode::kParse,
                       path + ": byte offset " + std::to_string(prev) +
                           ": the event there is not followed by another event (at byte offset " +
                           std::to_string(off) + ": " + problem +
                           "): its length is corrupt, or the bytes after it are");
    }
    const uint64_t next =
        off + sizeof(hdr) + static_cast<uint64_t>(chan_len) + static_cast<uint64_t>(data_len);
    if (next > size)
      return bad("event runs past the end of the file (" + std::to_string(chan_len) + " + " +
                 std::to_string(data_len) +
                 " bytes announced): the file is truncated, or the length is corrupt");
    prev = off;
    have_prev = true;
    off = next;
  }
  return Status::Ok();
}

}  // namespace omni::io
