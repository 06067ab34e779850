#include "omni/common/cli.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <utility>

namespace omni {

ArgReader::ArgReader(int argc, char** argv, std::string program, void (*usage)(std::FILE*))
    : argc_(argc), argv_(argv), program_(std::move(program)), usage_(usage) {}

bool ArgReader::Next() {
  if (++i_ >= argc_) return false;
  arg_ = argv_[i_];
  if (arg_ == "--help" || arg_ == "-h") {
    if (usage_ != nullptr) usage_(stdout);
    std::exit(0);
  }
  return true;
}

std::string ArgReader::Value() {
  if (i_ + 1 >= argc_) Fail(arg_ + " needs a value");
  return argv_[++i_];
}

double ArgReader::Number(double lo, double hi) {
  const std::string option = arg_, v = Value();
  char* end = nullptr;
  errno = 0;
  const double x = std::strtod(v.c_str(), &end);
  if (v.empty() || *end != '\0' || errno == ERANGE || !std::isfinite(x) || x < lo || x > hi) {
    char range[96];
    std::snprintf(range, sizeof(range), "[%g, %g]", lo, hi);
    Fail(option + " expects a number in " + range + ", got '" + v + "'");
  }
  return x;
}

int64_t ArgReader::Integer(int64_t lo, int64_t hi) {
  const std::string option = arg_, v = Value();
  char* end = nullptr;
  errno = 0;
  const long long x = std::strtoll(v.c_str(), &end, 10);
  if (v.empty() || *end != '\0' || errno == ERANGE || x < lo || x > hi)
    Fail(option + " expects a whole number in [" + std::to_string(lo) + ", " + std::to_string(hi) +
         "], got '" + v + "'");
  return x;
}

void ArgReader::Unknown() {
  std::fprintf(stderr, "%s: unknown option '%s'\n", program_.c_str(), arg_.c_str());
  if (usage_ != nullptr) usage_(stderr);
  std::exit(2);
}

void ArgReader::Fail(const std::string& message) {
  std::fprintf(stderr, "%s: %s\n", program_.c_str(), message.c_str());
  std::exit(2);
}

bool ReadMapperArg(ArgReader& args, MapperArgs* a) {
  if (args.Is("--config")) {
    a->config = args.Value();
  } else if (args.Is("--out")) {
    a->out = args.Value();
  } else if (args.IsUrl()) {
    a->url = args.Value();
  } else if (args.Is("--idle-exit")) {
    a->idle_exit_s = args.Number(0, 1e6);
  } else {
    return false;
  }
  return true;
}

}  // namespace omni
