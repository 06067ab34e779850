// Seed loading shared by every fuzz target (both drivers).
#include <zlib.h>

#include <cstdlib>

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

}  // namespace omni::fuzz
