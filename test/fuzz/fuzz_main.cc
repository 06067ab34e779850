// The fuzz targets' driver in the test suite (no libFuzzer needed): runs every seed, every
// input file given, then --runs inputs made by mutating them with a seeded generator, so a run
// is the same on every machine. A crash or failed check aborts; the input that caused it is
// written first (to --crash-dir, default the working folder) so it can be replayed:
//   fuzz_NAME FILE            run one input (or every file of a folder) and nothing else
//   fuzz_NAME --runs N DIR    the seeds, DIR's files and N mutations of them all (the test)
//   fuzz_NAME --runs 20000    more mutations than the test's
//   fuzz_NAME --write-seeds DIR   write the seeds as files (./omni fuzz's starting corpus)
#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>

#include "fuzz.h"

extern "C" void __sanitizer_set_death_callback(void (*callback)()) __attribute__((weak));

namespace {

namespace fs = std::filesystem;

std::string g_current;     // the input being run
std::string g_crash_path;  // where it is written if the run dies

void WriteCurrent() {
  const int fd = ::open(g_crash_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  if (fd < 0) return;
  size_t done = 0;
  while (done < g_current.size()) {
    const ssize_t n = ::write(fd, g_current.data() + done, g_current.size() - done);
    if (n <= 0) break;
    done += static_cast<size_t>(n);
  }
  ::close(fd);
  static const char kMsg[] = "fuzz: the input that failed was written to ";
  (void)!::write(2, kMsg, sizeof(kMsg) - 1);
  (void)!::write(2, g_crash_path.data(), g_crash_path.size());
  (void)!::write(2, "\n", 1);
}

void OnSignal(int sig) {
  WriteCurrent();
  ::signal(sig, SIG_DFL);
  ::raise(sig);
}

void Run(const std::string& input) {
  g_current = input;
  LLVMFuzzerTestOneInput(reinterpret_cast<const uint8_t*>(g_current.data()), g_current.size());
}

// One random change of `s` (the usual byte-level mutations, plus text tokens for the parsers of
// text formats, and a splice with another input).
void Mutate(std::string* s, const std::vector<std::string>& pool, std::mt19937_64* rng,
            size_t max_len) {
  auto below = [rng](size_t n) { return n == 0 ? size_t{0} : static_cast<size_t>((*rng)() % n); };
  static const char* const kTokens[] = {
      "nan",        "-nan",        "inf", "-inf", "1e308", "-1", "0",      "4294967296",
      "2147483647", "-2147483648", " ",   "\n",   "\t",    "#",  "1e-320", "99999999999999999999"};
  static const uint32_t kInteresting[] = {
      0, 1, 0x7f, 0x80, 0xff, 0x7fff, 0x8000, 0xffff, 0x7fffffff, 0x80000000u, 0xffffffffu};
  switch (below(9)) {
    case 0:  // flip a bit
      if (!s->empty()) (*s)[below(s->size())] ^= static_cast<char>(1u << below(8));
      break;
    case 1:  // a random byte
      if (!s->empty()) (*s)[below(s->size())] = static_cast<char>((*rng)());
      break;
    case 2: {  // insert random bytes
      std::string bytes(1 + below(8), '\0');
      for (char& c : bytes) c = static_cast<char>((*rng)());
      s->insert(below(s->size() + 1), bytes);
      break;
    }
    case 3:  // erase a range
      if (!s->empty()) {
        const size_t at = below(s->size());
        s->erase(at, 1 + below(std::min<size_t>(32, s->size() - at)));
      }
      break;
    case 4:  // repeat a range
      if (!s->empty()) {
        const size_t at = below(s->size());
        const std::string piece = s->substr(at, 1 + below(64));
        s->insert(below(s->size() + 1), piece);
      }
      break;
    case 5:  // cut short
      s->resize(below(s->size() + 1));
      break;
    case 6:  // an interesting integer, 1, 2 or 4 bytes little-endian
      if (!s->empty()) {
        const uint32_t v = kInteresting[below(std::size(kInteresting))];
        const size_t width = size_t{1} << below(3);
        const size_t at = below(s->size());
        for (size_t i = 0; i < width && at + i < s->size(); ++i)
          (*s)[at + i] = static_cast<char>(v >> (8 * i));
      }
      break;
    case 7: {  // a text token, inserted or replacing a word
      const std::string token = kTokens[below(std::size(kTokens))];
      const size_t at = below(s->size() + 1);
      if (below(2) == 0) {
        s->insert(at, token);
      } else {
        size_t end = at;
        while (end < s->size() && (*s)[end] != ' ' && (*s)[end] != '\n') ++end;
        s->replace(at, end - at, token);
      }
      break;
    }
    default:  // splice with another input
      if (!pool.empty()) {
        const std::string& other = pool[below(pool.size())];
        const size_t cut = below(s->size() + 1);
        const size_t from = below(other.size() + 1);
        *s = s->substr(0, cut) + other.substr(from);
      }
      break;
  }
  if (s->size() > max_len) s->resize(max_len);
}

void AddPath(const fs::path& p, std::vector<std::string>* inputs) {
  std::vector<fs::path> files;
  if (fs::is_directory(p)) {
    for (const auto& e : fs::directory_iterator(p))
      if (e.is_regular_file()) files.push_back(e.path());
    std::sort(files.begin(), files.end());
  } else {
    files.push_back(p);
  }
  for (const auto& f : files) {
    std::ifstream in(f, std::ios::binary);
    if (!in) {
      std::cerr << "fuzz: cannot read " << f << "\n";
      std::exit(2);
    }
    std::ostringstream ss;
    ss << in.rdbuf();
    inputs->push_back(ss.str());
  }
}

}  // namespace

int main(int argc, char** argv) {
  const std::string name = fs::path(argv[0]).filename().string();
  long runs = 0;
  bool runs_given = false;
  uint64_t seed = 1;
  size_t max_len = 1 << 16;
  std::string write_seeds, crash_dir = ".";
  std::vector<std::string> paths;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << name << ": " << a << " needs a value\n";
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--runs") {
      runs = std::stol(value());
      runs_given = true;
    } else if (a == "--seed") {
      seed = std::stoull(value());
    } else if (a == "--max-len") {
      max_len = std::stoul(value());
    } else if (a == "--write-seeds") {
      write_seeds = value();
    } else if (a == "--crash-dir") {
      crash_dir = value();
    } else if (a == "-h" || a == "--help") {
      std::cout << "usage: " << name
                << " [--runs N] [--seed S] [--max-len BYTES] [--crash-dir DIR] [FILE|DIR]...\n"
                   "       "
                << name
                << " --write-seeds DIR\n"
                   "Runs the built-in seeds and the given inputs, then N seeded mutations of\n"
                   "them (default 2000). Inputs without --runs: runs only those (a replay).\n";
      return 0;
    } else if (!a.empty() && a[0] == '-') {
      std::cerr << name << ": unknown option " << a << "\n";
      return 2;
    } else {
      paths.push_back(a);
    }
  }
  // Files without --runs: replay just them (a crash being fixed); otherwise the seeds, the files
  // and the mutations.
  const bool replay_only = !paths.empty() && !runs_given;
  if (!runs_given) runs = paths.empty() ? 2000 : 0;

  omni::fuzz::SeedList seeds;
  omni::fuzz::Seeds(&seeds);
  for (const std::string& m : seeds.missing)
    std::cout << name << ": note: dataset file absent, its seed skipped: " << m << "\n";
  if (!write_seeds.empty()) {
    fs::create_directories(write_seeds);
    for (size_t i = 0; i < seeds.inputs.size(); ++i) {
      char file[32];
      std::snprintf(file, sizeof(file), "seed-%03zu", i);
      std::ofstream(fs::path(write_seeds) / file, std::ios::binary) << seeds.inputs[i];
    }
    std::cout << name << ": wrote " << seeds.inputs.size() << " seeds to " << write_seeds << "\n";
    return 0;
  }

  std::error_code made;
  fs::create_directories(crash_dir, made);  // a folder that is not there yet is made, not ignored
  g_crash_path = (fs::path(crash_dir) / ("crash-" + name)).string();
  for (int sig : {SIGABRT, SIGSEGV, SIGFPE, SIGBUS, SIGILL}) ::signal(sig, OnSignal);
  if (__sanitizer_set_death_callback != nullptr) __sanitizer_set_death_callback(WriteCurrent);

  std::vector<std::string> pool;
  if (!replay_only) pool = seeds.inputs;
  for (const std::string& p : paths) AddPath(p, &pool);
  if (pool.empty()) pool.emplace_back();

  const auto t0 = std::chrono::steady_clock::now();
  for (const std::string& input : pool) Run(input);
  std::mt19937_64 rng(seed);
  for (long i = 0; i < runs; ++i) {
    std::string input = pool[rng() % pool.size()];
    const int changes = 1 + static_cast<int>(rng() % 4);
    for (int k = 0; k < changes; ++k) Mutate(&input, pool, &rng, max_len);
    Run(input);
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::cout << name << ": " << pool.size() << " inputs as given and " << runs
            << " mutations of them (seed " << seed << ") ran without a failure in " << s << " s\n";
  return 0;
}
