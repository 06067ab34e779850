// The command line every sensor driver process shares:
//   --config FILE  DEVICE_FLAG VALUE  --lcm-url URL  --duration-s S  --help
// DEVICE_FLAG names the device (--port for serial devices, --uri for OpenNI2).
#pragma once

#include <string>

namespace omni {

struct DriverArgs {
  std::string config;
  std::string device;  // value of the device flag ("" when not given)
  bool have_device = false;
  std::string lcm_url;
  bool have_url = false;
  double duration_s = -1;  // < 0: run until SIGINT/SIGTERM
};

// Parses argv. Returns -1 when the process should go on; otherwise the exit code after
// `usage(code)` has printed the usage (0 for --help, 2 for a bad command line, with the reason
// on stderr first: a missing value, a non-numeric duration, an unknown option, no --config).
int ParseDriverArgs(int argc, char** argv, const std::string& device_flag, int (*usage)(int code),
                    DriverArgs* out);

}  // namespace omni
