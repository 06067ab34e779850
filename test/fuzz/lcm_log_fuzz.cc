// LCM log files (what `omni replay`, `omni-slam` and `octomap extract` read): any bytes, read
// strictly and with resynchronisation, and the fast framing check. The framing check and the
// strict reader must agree on whether a log is well framed. Seeds: LCM's own example log
// (../shared/datasets/lcm, written by lcm-logger) and a log of ours.
#include <sys/mman.h>
#include <unistd.h>

#include "fuzz.h"
#include "omni/io/lcm_log.h"

namespace {

// The input as a file (memfd: nothing touches the disk).
class MemFile {
 public:
  explicit MemFile(const std::string& bytes) : fd_(memfd_create("omni-fuzz", 0)) {
    OMNI_FUZZ_CHECK(fd_ >= 0);
    size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t n = write(fd_, bytes.data() + done, bytes.size() - done);
      OMNI_FUZZ_CHECK(n > 0);
      done += static_cast<size_t>(n);
    }
  }
  ~MemFile() { close(fd_); }
  std::string path() const { return "/proc/self/fd/" + std::to_string(fd_); }

 private:
  int fd_;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  MemFile file(bytes);
  const bool framing_ok = omni::io::CheckLcmLogFraming(file.path()).ok();
  for (bool resync : {false, true}) {
    auto reader = omni::io::LcmLogReader::Open(file.path());
    OMNI_FUZZ_CHECK(reader.ok());
    omni::io::LcmLogEvent e;
    size_t events = 0, payload = 0;
    bool clean_end = false;
    uint64_t last_offset = 0;
    while (true) {
      auto next = reader.value().Next(&e, resync);
      if (!next.ok()) break;
      if (!next.value()) {
        clean_end = true;
        break;
      }
      ++events;
      payload += e.channel.size() + e.data.size();
      OMNI_FUZZ_CHECK(payload <= size);
      OMNI_FUZZ_CHECK(events == 1 || e.offset > last_offset);
      OMNI_FUZZ_CHECK(e.offset < size);
      last_offset = e.offset;
    }
    OMNI_FUZZ_CHECK(reader.value().skipped_bytes() <= size);
    if (!resync) OMNI_FUZZ_CHECK(clean_end == framing_ok);
    if (resync && framing_ok) OMNI_FUZZ_CHECK(clean_end && reader.value().skipped_bytes() == 0);
  }
  return 0;
}

void omni::fuzz::Seeds(SeedList* seeds) {
  seeds->AddDataset("lcm/example.lcmlog", 1 << 16);
  // Three events of ours, one with an empty payload.
  std::string log;
  auto be = [&log](uint64_t v, int bytes) {
    for (int i = bytes - 1; i >= 0; --i) log += static_cast<char>((v >> (8 * i)) & 0xff);
  };
  const char* channels[] = {"LIDAR_SCAN", "WHEEL_ODOM", "HEARTBEAT"};
  for (int i = 0; i < 3; ++i) {
    const std::string channel = channels[i];
    const std::string payload(static_cast<size_t>(i) * 7, static_cast<char>('a' + i));
    be(0xEDA1DA01u, 4);
    be(static_cast<uint64_t>(i), 8);
    be(1700000000000000ull + 20000u * i, 8);
    be(channel.size(), 4);
    be(payload.size(), 4);
    log += channel + payload;
  }
  seeds->Add(log);
}
