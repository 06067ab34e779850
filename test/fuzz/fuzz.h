// The fuzz targets' common parts.
//
// Each target in this folder defines LLVMFuzzerTestOneInput (libFuzzer's entry point) and
// omni::fuzz::Seeds, the inputs a run starts from: bytes made by our own encoders, and real
// bytes read in place from ../shared/datasets (a prefix of each file; never copied here).
//
// Two ways to run a target (docs/fuzzing.md):
//   - the test suite links it with fuzz_main.cc, which runs every seed and a fixed number of
//     seeded mutations of them (deterministic, a few seconds; `ctest -L fuzz`);
//   - `./omni fuzz NAME` builds it with clang's libFuzzer (coverage-guided, ASan + UBSan) and
//     runs it for as long as asked, starting from the same seeds.
// A target checks what must hold for any input with OMNI_FUZZ_CHECK; a failed check aborts,
// so both drivers report it as a crash and keep the input that caused it.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

#define OMNI_FUZZ_CHECK(cond)                                                            \
  do {                                                                                   \
    if (!(cond)) {                                                                       \
      std::fprintf(stderr, "%s:%d: fuzz check failed: %s\n", __FILE__, __LINE__, #cond); \
      std::abort();                                                                      \
    }                                                                                    \
  } while (0)

namespace omni::fuzz {

struct SeedList {
  std::vector<std::string> inputs;
  // Dataset files wanted but absent (printed, so a run without ../shared says what it missed).
  std::vector<std::string> missing;

  void Add(std::string bytes) { inputs.push_back(std::move(bytes)); }
  void Add(const void* data, size_t size) {
    inputs.emplace_back(static_cast<const char*>(data), size);
  }
  // Up to `max_bytes` of `relative_path` under the datasets folder (gzip is inflated first).
  // Returns false (and records it as missing) when the file is not there.
  bool AddDataset(const std::string& relative_path, size_t max_bytes);
  // The same for a text file, cut after its last whole line within `max_bytes`.
  bool AddDatasetLines(const std::string& relative_path, size_t max_bytes);
};

// The datasets folder: $OMNI_DATASETS_DIR, else the one the build was configured with.
std::string DatasetsDir();

// Implemented by each target.
void Seeds(SeedList* seeds);

// Reads typed values off the front of a fuzz input; past its end it yields zeros, so a target
// can take what it needs without checking the length first.
class Reader {
 public:
  Reader(const uint8_t* data, size_t size) : data_(data), size_(size) {}
  bool empty() const { return pos_ >= size_; }
  size_t remaining() const { return pos_ < size_ ? size_ - pos_ : 0; }
  uint8_t U8() { return pos_ < size_ ? data_[pos_++] : 0; }
  // Little-endian. Each read is its own statement: the operands of `|` are unsequenced, so
  // `U8() | (U8() << 8)` read the bytes in either order, and GCC's sanitizer build and its
  // plain build disagreed on what an input meant.
  uint16_t U16() {
    const uint16_t lo = U8();
    const uint16_t hi = U8();
    return static_cast<uint16_t>(lo | (hi << 8));
  }
  uint32_t U32() {
    const uint32_t lo = U16();
    const uint32_t hi = U16();
    return lo | (hi << 16);
  }
  // The next `n` bytes (fewer at the end).
  std::string Bytes(size_t n) {
    n = n < remaining() ? n : remaining();
    std::string out(reinterpret_cast<const char*>(data_ + pos_), n);
    pos_ += n;
    return out;
  }
  std::string Rest() { return Bytes(remaining()); }
  const uint8_t* here() const { return data_ + (pos_ < size_ ? pos_ : size_); }

 private:
  const uint8_t* data_;
  size_t size_;
  size_t pos_ = 0;
};

// Appends `v` as Reader::U16 reads it back (little-endian), for seeds written as scripts.
inline void AppendU16(std::string* s, int v) {
  const auto u = static_cast<uint16_t>(v);
  s->push_back(static_cast<char>(u & 0xff));
  s->push_back(static_cast<char>(u >> 8));
}

// Numbers for the scripted stream targets (mapper_stream, octomap_stream), read off the script:
// a value, mostly `scale` times a signed 16-bit fraction; codes 250-255 give NaN, +-inf, a power
// of ten from 1 to 1e312 (inf), the smallest denormal and 0.
double ScriptValue(Reader& r, double scale);
// A clock step in microseconds: mostly 0-255 ms forward; codes 250-254 step an hour back or
// forward, up to 255 ms back, or to half the int64 maximum or minimum.
int64_t ScriptTimeStep(Reader& r, int64_t now);

}  // namespace omni::fuzz
