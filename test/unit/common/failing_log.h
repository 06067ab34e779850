// An LCM log in memory behind a stdio stream that fails on demand, for tests of readers and
// of their callers.
#pragma once

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "omni/io/lcm_log.h"

namespace omni::testing {

// A log in memory behind a stdio stream (fopencookie) whose reads fail with EIO over
// [fail_from, fail_to) while `failing` is set: a disk or network file system that fails and
// comes back. Reads stop short of the failing range, as the kernel returns what it could read.
struct FailingLog {
  std::string bytes;
  long pos = 0;
  long fail_from = 0, fail_to = 0;
  bool failing = true;
  bool seeks_fail = false;
  int failed_reads = 0;

  static ssize_t Read(void* cookie, char* buf, size_t size) {
    auto* m = static_cast<FailingLog*>(cookie);
    if (m->failing && m->pos >= m->fail_from && m->pos < m->fail_to) {
      ++m->failed_reads;
      errno = EIO;
      return -1;
    }
    long end = std::min<long>(static_cast<long>(m->bytes.size()), m->pos + static_cast<long>(size));
    if (m->failing && m->pos < m->fail_from) end = std::min(end, m->fail_from);
    const long n = std::max<long>(0, end - m->pos);
    std::copy_n(m->bytes.data() + m->pos, n, buf);
    m->pos += n;
    return n;
  }
  static int Seek(void* cookie, off64_t* offset, int whence) {
    auto* m = static_cast<FailingLog*>(cookie);
    if (m->seeks_fail) {
      errno = EIO;
      return -1;
    }
    const long base = whence == SEEK_SET   ? 0
                      : whence == SEEK_CUR ? m->pos
                                           : static_cast<long>(m->bytes.size());
    if (base + *offset < 0) return -1;
    m->pos = static_cast<long>(base + *offset);
    *offset = m->pos;
    return 0;
  }
  io::LcmLogReader Reader() {
    pos = 0;
    cookie_io_functions_t io{};
    io.read = &FailingLog::Read;
    io.seek = &FailingLog::Seek;
    auto r = io::LcmLogReader::FromStream(fopencookie(this, "rb", io), "failing.lcmlog");
    if (!r.ok()) ADD_FAILURE() << r.error().message;
    return std::move(*r);
  }
};

}  // namespace omni::testing
