// Seed loading shared by every fuzz target (both drivers), and the script numbers of the stream
// targets.
#include <zlib.h>

#include <cmath>
#include <cstdlib>
#include <limits>

#include "fuzz.h"

namespace omni::fuzz {

std::string DatasetsDir() {
  const char* env = std::getenv("OMNI_DATASETS_DIR");
  if (env != nullptr && *env != '\0') return env;
  return OMNI_DATASETS_DIR;
}

bool SeedList::AddDataset(const std::string& relative_path, size_t max_bytes) {
  const std::string path = DatasetsDir() + "/" + relative_path;
  // gzread reads plain files as they are, so one path serves .gz and uncompressed data.
  gzFile f = gzopen(path.c_str(), "rb");
  if (f == nullptr) {
    missing.push_back(path);
    return false;
  }
  std::string bytes(max_bytes, '\0');
  size_t have = 0;
  while (have < max_bytes) {
    const unsigned want = static_cast<unsigned>(std::min<size_t>(max_bytes - have, 1 << 20));
    const int n = gzread(f, bytes.data() + have, want);
    if (n <= 0) break;
    have += static_cast<size_t>(n);
  }
  gzclose(f);
  if (have == 0) {
    missing.push_back(path + " (empty or unreadable)");
    return false;
  }
  bytes.resize(have);
  inputs.push_back(std::move(bytes));
  return true;
}

bool SeedList::AddDatasetLines(const std::string& relative_path, size_t max_bytes) {
  if (!AddDataset(relative_path, max_bytes)) return false;
  std::string& text = inputs.back();
  const size_t end = text.rfind('\n');
  text.resize(end == std::string::npos ? 0 : end + 1);
  return true;
}

double ScriptValue(Reader& r, double scale) {
  const uint8_t code = r.U8();
  switch (code) {
    case 250:
      return std::numeric_limits<double>::quiet_NaN();
    case 251:
      return std::numeric_limits<double>::infinity();
    case 252:
      return -std::numeric_limits<double>::infinity();
    case 253: {
      const double sign = r.U8() & 1 ? -1 : 1;
      return sign * std::pow(10.0, r.U8() % 40 * 8);  // 1 .. 1e312 (inf)
    }
    case 254:
      return std::numeric_limits<double>::denorm_min();
    case 255:
      return 0.0;
    default:
      return scale * static_cast<int16_t>(r.U16()) / 32768.0;
  }
}

int64_t ScriptTimeStep(Reader& r, int64_t now) {
  const uint8_t code = r.U8();
  switch (code) {
    case 250:
      return -3600LL * 1000000;
    case 251:
      return 3600LL * 1000000;
    case 252:
      return -static_cast<int64_t>(r.U8()) * 1000;
    case 253:
      return std::numeric_limits<int64_t>::max() / 2 - now;
    case 254:
      return std::numeric_limits<int64_t>::min() / 2 - now;
    default:
      return static_cast<int64_t>(code) * 1000;
  }
}

}  // namespace omni::fuzz
