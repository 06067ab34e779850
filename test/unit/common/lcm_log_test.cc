#include "omni/io/lcm_log.h"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "failing_log.h"
#include "test_paths.h"

namespace omni::io {
namespace {

using ::omni::testing::FailingLog;

TEST(LcmLog, ReadsLogWrittenByLcmTools) {
  OMNI_REQUIRE_DATASET(path, "lcm/example.lcmlog");
  auto r = LcmLogReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.error().message;
  LcmLogEvent ev;
  int n = 0;
  int64_t last = 0;
  for (;;) {
    auto more = r->Next(&ev);
    ASSERT_TRUE(more.ok()) << more.error().message;
    if (!*more) break;
    EXPECT_EQ(ev.channel, "JOINT_TEST");
    EXPECT_GE(ev.utime, last);
    last = ev.utime;
    ++n;
  }
  EXPECT_EQ(n, 10);
}

std::string WriteSample(const std::string& dir) {
  auto w = LcmLogWriter::Open(dir + "/s.lcmlog");
  EXPECT_TRUE(w.ok());
  const std::string a = "hello", b = "world!";
  EXPECT_TRUE(w->Write(100, "A", a.data(), a.size()).ok());
  EXPECT_TRUE(w->Write(200, "BB", b.data(), b.size()).ok());
  EXPECT_TRUE(w->Write(300, "A", a.data(), a.size()).ok());
  EXPECT_TRUE(w->Close().ok());
  return dir + "/s.lcmlog";
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), {});
}

TEST(LcmLog, RoundTrip) {
  const std::string path = WriteSample(omni::testing::TempDir());
  auto r = LcmLogReader::Open(path);
  ASSERT_TRUE(r.ok());
  LcmLogEvent ev;
  ASSERT_TRUE(*r->Next(&ev));
  EXPECT_EQ(ev.channel, "A");
  EXPECT_EQ(ev.utime, 100);
  ASSERT_TRUE(*r->Next(&ev));
  EXPECT_EQ(ev.channel, "BB");
  EXPECT_EQ(std::string(ev.data.begin(), ev.data.end()), "world!");
  EXPECT_EQ(ev.event_number, 1);
  ASSERT_TRUE(*r->Next(&ev));
  EXPECT_FALSE(*r->Next(&ev));
}

// An event larger than the reader takes (256 MiB) is refused before a byte is written: its
// length used to be cut to 32 bits in the header, so the file could not be read past it.
TEST(LcmLog, AnEventTooLargeToReadBackIsRefusedAndTheLogStaysReadable) {
  const std::string path = omni::testing::TempDir() + "/big.lcmlog";
  auto w = LcmLogWriter::Open(path);
  ASSERT_TRUE(w.ok());
  const std::string a = "hello";
  for (uint64_t size : {uint64_t{256} * 1024 * 1024 + 1, uint64_t{4} * 1024 * 1024 * 1024 + 5}) {
    // Refused before `data` is read: a small buffer stands for the large one.
    const Status st = w->Write(100, "GRID", a.data(), static_cast<size_t>(size));
    EXPECT_FALSE(st.ok());
    EXPECT_NE(st.message().find("GRID"), std::string::npos) << st.message();
  }
  ASSERT_TRUE(w->Write(200, "A", a.data(), a.size()).ok());
  ASSERT_TRUE(w->Close().ok());
  auto r = LcmLogReader::Open(path);
  ASSERT_TRUE(r.ok());
  LcmLogEvent ev;
  ASSERT_TRUE(*r->Next(&ev));
  EXPECT_EQ(ev.channel, "A");
  EXPECT_EQ(ev.event_number, 0);
  EXPECT_FALSE(*r->Next(&ev));
}

TEST(LcmLog, CorruptionNamesOffsetAndResyncSkipsIt) {
  const std::string path = WriteSample(omni::testing::TempDir());
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(34);  // first event is 28 + 1 + 5 = 34 bytes: corrupt the second sync word
    f.put('\x00');
  }
  auto r = LcmLogReader::Open(path);
  LcmLogEvent ev;
  ASSERT_TRUE(*r->Next(&ev));
  auto bad = r->Next(&ev);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("byte offset 34"), std::string::npos) << bad.error().message;
  EXPECT_NE(bad.error().message.find("sync"), std::string::npos);

  auto r2 = LcmLogReader::Open(path);
  ASSERT_TRUE(*r2->Next(&ev, true));
  ASSERT_TRUE(*r2->Next(&ev, true));
  EXPECT_EQ(ev.utime, 300) << "resync lands on the third event";
  EXPECT_EQ(r2->skipped_bytes(), 28u + 2 + 6);
}

TEST(LcmLog, FramingCheckNamesTheFirstBrokenEvent) {
  const std::string path = WriteSample(omni::testing::TempDir());
  EXPECT_TRUE(CheckLcmLogFraming(path).ok());
  const std::string all = ReadAll(path);
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(all.data(), static_cast<std::streamsize>(all.size() - 3));
  }
  Status s = CheckLcmLogFraming(path);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("truncated"), std::string::npos) << s.message();
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(all.data(), static_cast<std::streamsize>(all.size()));
  }
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(34);  // the second event's sync word
    f.put('\x00');
  }
  s = CheckLcmLogFraming(path);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("byte offset 34: bad sync"), std::string::npos) << s.message();
  EXPECT_FALSE(CheckLcmLogFraming(path + ".none").ok());
}

// A length corrupted to a value still inside the file (one bit flipped): the event swallows the
// ones after it. The reader names that event, and a resync loses only it; a length corrupted
// past the end of the file with intact events after it is read past too. (Before, --resync
// silently dropped every swallowed event and counted a few skipped bytes.)
TEST(LcmLog, ACorruptLengthLosesOnlyItsEvent) {
  const std::string dir = omni::testing::TempDir() + "/lcm_len";
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/len.lcmlog";
  std::vector<uint64_t> offsets;
  {
    auto w = LcmLogWriter::Open(path);
    ASSERT_TRUE(w.ok());
    const std::string payload(100, 'x');
    uint64_t off = 0;
    for (int i = 0; i < 50; ++i) {
      offsets.push_back(off);
      ASSERT_TRUE(w->Write(1000 + i, "CH", payload.data(), payload.size()).ok());
      off += 28 + 2 + 100;
    }
    ASSERT_TRUE(w->Close().ok());
  }
  const std::string good = ReadAll(path);
  auto corrupt = [&](uint32_t data_len) {
    std::string bytes = good;
    const uint64_t at = offsets[10] + 24;  // event 10's data length
    for (int k = 0; k < 4; ++k)
      bytes[at + k] = static_cast<char>((data_len >> (24 - 8 * k)) & 0xFF);
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  };
  auto read_all = [&](bool resync, std::vector<int64_t>* stamps) -> Status {
    auto r = LcmLogReader::Open(path);
    if (!r.ok()) return r.error();
    LcmLogEvent ev;
    for (;;) {
      auto more = r->Next(&ev, resync);
      if (!more.ok()) return more.error();
      if (!*more) return Status::Ok();
      stamps->push_back(ev.utime);
    }
  };
  // Inside the file, past its end, and 1-3 bytes too large (the next event's sync word then
  // straddles the data's end: it was taken for damage after the event, and the next event was
  // lost with it).
  for (const uint32_t len : {100u + 130u * 20u + 50u, 100u + (1u << 20), 101u, 102u, 103u}) {
    corrupt(len);
    std::vector<int64_t> stamps;
    Status s = read_all(false, &stamps);
    ASSERT_FALSE(s.ok()) << len;
    EXPECT_NE(s.message().find("byte offset " + std::to_string(offsets[10])), std::string::npos)
        << s.message();
    EXPECT_EQ(stamps.size(), 10u) << "the events before it are read";
    stamps.clear();
    s = read_all(true, &stamps);
    ASSERT_TRUE(s.ok()) << len << ": " << s.message();
    ASSERT_EQ(stamps.size(), 49u) << len;
    EXPECT_EQ(stamps[9], 1009);
    EXPECT_EQ(stamps[10], 1011);
    Status framing = CheckLcmLogFraming(path);
    ASSERT_FALSE(framing.ok());
    EXPECT_NE(framing.message().find("byte offset " + std::to_string(offsets[10])),
              std::string::npos)
        << framing.message();
  }
}

TEST(LcmLog, TruncationIsAnError) {
  const std::string path = WriteSample(omni::testing::TempDir());
  std::string all = ReadAll(path);
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(all.data(), static_cast<std::streamsize>(all.size() - 3));
  }
  auto r = LcmLogReader::Open(path);
  LcmLogEvent ev;
  ASSERT_TRUE(*r->Next(&ev));
  ASSERT_TRUE(*r->Next(&ev));
  auto bad = r->Next(&ev);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("truncated"), std::string::npos) << bad.error().message;
  EXPECT_TRUE(r->truncated_tail()) << "a log cut inside its last event";
  // Cut inside the last event's header: a tail too.
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(all.data(), static_cast<std::streamsize>(all.size() - 34 + 10));
  }
  for (const bool resync : {false, true}) {
    auto h = LcmLogReader::Open(path);
    ASSERT_TRUE(*h->Next(&ev, resync));
    ASSERT_TRUE(*h->Next(&ev, resync));
    EXPECT_FALSE(h->Next(&ev, resync).ok());
    EXPECT_TRUE(h->truncated_tail()) << resync;
  }
}

// A length running past the end of the file with an intact event after it is corruption, not
// a log cut short: without resync an error that says events follow (no tail), with resync the
// next event is read.
TEST(LcmLog, ALengthPastTheEndWithEventsAfterIsNotATail) {
  const std::string path = WriteSample(omni::testing::TempDir());
  std::string all = ReadAll(path);
  ASSERT_EQ(all.size(), 104u);
  all[34 + 27] = 100;  // second event's data length 6 -> 100, past the end
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(all.data(), static_cast<std::streamsize>(all.size()));
  }
  auto r = LcmLogReader::Open(path);
  LcmLogEvent ev;
  ASSERT_TRUE(*r->Next(&ev));
  auto bad = r->Next(&ev);
  ASSERT_FALSE(bad.ok());
  EXPECT_FALSE(r->truncated_tail());
  EXPECT_NE(bad.error().message.find("events follow"), std::string::npos) << bad.error().message;
  auto s = LcmLogReader::Open(path);
  ASSERT_TRUE(*s->Next(&ev, true));
  ASSERT_TRUE(*s->Next(&ev, true));
  EXPECT_EQ(ev.utime, 300);
  EXPECT_FALSE(*s->Next(&ev, true));
  EXPECT_FALSE(s->truncated_tail());
}

// Events of the sample: [0, 34) "A" 100, [34, 70) "BB" 200, [70, 104) "A" 300.
TEST(LcmLog, AFailedReadIsAnIoErrorAndTheEventIsReadWhenTheDeviceComesBack) {
  for (const bool resync : {false, true}) {
    FailingLog log;
    log.bytes = ReadAll(WriteSample(omni::testing::TempDir()));
    ASSERT_EQ(log.bytes.size(), 104u);
    log.fail_from = 64;  // inside the second event's data
    log.fail_to = 66;
    LcmLogReader r = log.Reader();
    LcmLogEvent ev;
    ASSERT_TRUE(*r.Next(&ev, resync));
    EXPECT_EQ(ev.utime, 100);
    auto bad = r.Next(&ev, resync);
    ASSERT_FALSE(bad.ok()) << "resync " << resync << ": taken for an end or a truncation";
    EXPECT_EQ(bad.error().code, ErrorCode::kIo) << bad.error().message;
    EXPECT_NE(bad.error().message.find("byte offset 34: read error"), std::string::npos)
        << bad.error().message;
    EXPECT_NE(bad.error().message.find(std::strerror(EIO)), std::string::npos);
    EXPECT_FALSE(r.truncated_tail());
    EXPECT_GT(log.failed_reads, 0);
    // Still failing: the same error again, nothing skipped.
    EXPECT_FALSE(r.Next(&ev, resync).ok());
    log.failing = false;  // the device is back: the event the failure was in, then the rest
    auto again = r.Next(&ev, resync);
    ASSERT_TRUE(again.ok()) << again.error().message;
    ASSERT_TRUE(*again);
    EXPECT_EQ(ev.utime, 200);
    EXPECT_EQ(std::string(ev.data.begin(), ev.data.end()), "world!");
    ASSERT_TRUE(*r.Next(&ev, resync));
    EXPECT_EQ(ev.utime, 300);
    EXPECT_FALSE(*r.Next(&ev, resync));
    EXPECT_EQ(r.skipped_bytes(), 0u);
  }
}

TEST(LcmLog, AFailedReadWhileResynchronisingIsNotTheEndOfTheLog) {
  FailingLog log;
  log.bytes = ReadAll(WriteSample(omni::testing::TempDir()));
  log.bytes[34] = 0;  // no sync word at the second event, nor at the third:
  log.bytes[70] = 0;  // the resync scans to the end of the file
  log.fail_from = 80;
  log.fail_to = 90;
  LcmLogReader r = log.Reader();
  LcmLogEvent ev;
  ASSERT_TRUE(*r.Next(&ev, true));
  auto bad = r.Next(&ev, true);
  ASSERT_FALSE(bad.ok()) << "a read error inside the resync's scan was taken for the end";
  EXPECT_EQ(bad.error().code, ErrorCode::kIo);
  EXPECT_NE(bad.error().message.find("byte offset 34: read error"), std::string::npos)
      << bad.error().message;
  EXPECT_EQ(r.skipped_bytes(), 0u) << "bytes not read are not counted as skipped";
  log.failing = false;
  auto end = r.Next(&ev, true);
  ASSERT_TRUE(end.ok()) << end.error().message;
  EXPECT_FALSE(*end);
  EXPECT_EQ(r.skipped_bytes(), 104u - 34);
}

// The other places a read can fail: the four bytes after an event (read to check that an event
// follows it), and the middle of an event header.
TEST(LcmLog, AFailedReadAfterAnEventOrInAHeaderIsAnIoErrorToo) {
  struct Case {
    long fail_from;
    uint64_t event_at;  // the event the error names (and the next call reads again)
    int64_t utime;      // that event's
  };
  for (const Case c : {Case{34, 0, 100}, Case{40, 34, 200}}) {
    for (const bool resync : {false, true}) {
      FailingLog log;
      log.bytes = ReadAll(WriteSample(omni::testing::TempDir()));
      log.fail_from = c.fail_from;
      log.fail_to = c.fail_from + 2;
      LcmLogReader r = log.Reader();
      LcmLogEvent ev;
      if (c.event_at > 0) {
        ASSERT_TRUE(*r.Next(&ev, resync));
      }
      auto bad = r.Next(&ev, resync);
      ASSERT_FALSE(bad.ok()) << "fail at " << c.fail_from << " resync " << resync;
      EXPECT_EQ(bad.error().code, ErrorCode::kIo);
      EXPECT_NE(bad.error().message.find("byte offset " + std::to_string(c.event_at) + ": read"),
                std::string::npos)
          << bad.error().message;
      log.failing = false;
      ASSERT_TRUE(*r.Next(&ev, resync));
      EXPECT_EQ(ev.utime, c.utime) << "the event is read again, not lost";
      int rest = 0;
      while (*r.Next(&ev, resync)) ++rest;
      EXPECT_EQ(rest, c.event_at > 0 ? 1 : 2);
      EXPECT_EQ(r.skipped_bytes(), 0u);
    }
  }
}

TEST(LcmLog, AFailedSeekIsAnIoError) {
  FailingLog log;
  log.bytes = ReadAll(WriteSample(omni::testing::TempDir()));
  log.failing = false;
  log.seeks_fail = true;  // the reader seeks back after looking past each event
  LcmLogReader r = log.Reader();
  LcmLogEvent ev;
  auto bad = r.Next(&ev);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code, ErrorCode::kIo);
  EXPECT_NE(bad.error().message.find("byte offset 0: seek error"), std::string::npos)
      << bad.error().message;
  EXPECT_FALSE(r.Next(&ev).ok()) << "still failing";
  log.seeks_fail = false;
  int n = 0;
  for (;;) {
    auto more = r.Next(&ev);
    ASSERT_TRUE(more.ok()) << more.error().message;
    if (!*more) break;
    EXPECT_EQ(ev.utime, 100 * (n + 1));
    ++n;
  }
  EXPECT_EQ(n, 3);
}

TEST(LcmLog, NoStreamIsAnError) {
  EXPECT_FALSE(LcmLogReader::FromStream(nullptr, "x.lcmlog").ok());
}

}  // namespace
}  // namespace omni::io
