#pragma once

#include <sys/wait.h>

#include <cstdio>
#include <string>

namespace omni::testing {

struct RunResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr together
};

// Runs a shell command line and captures its output and exit code.
inline RunResult Run(const std::string& cmd) {
  RunResult r;
  FILE* p = popen(("( " + cmd + " ) 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof(buf), p)) > 0) r.output.append(buf, n);
  const int status = pclose(p);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

inline std::string Bin(const std::string& name) {
  return std::string(OMNI_BINARY_DIR) + "/bin/" + name;
}

}  // namespace omni::testing
