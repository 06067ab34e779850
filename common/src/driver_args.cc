#include "omni/common/driver_args.h"

#include <cstdio>
#include <cstdlib>

namespace omni {

int ParseDriverArgs(int argc, char** argv, const std::string& device_flag, int (*usage)(int code),
                    DriverArgs* out) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") return usage(0);
    const bool takes_value = a == "--config" || a == device_flag || a == "--lcm-url" ||
                             a == "--url" || a == "--duration-s";
    if (!takes_value) {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      return usage(2);
    }
    if (i + 1 >= argc) {
      std::fprintf(stderr, "%s needs a value\n", a.c_str());
      return usage(2);
    }
    const std::string v = argv[++i];
    if (a == "--config") {
      out->config = v;
    } else if (a == device_flag) {
      out->device = v;
      out->have_device = true;
    } else if (a == "--lcm-url" || a == "--url") {
      out->lcm_url = v;
      out->have_url = true;
    } else {
      char* end = nullptr;
      out->duration_s = std::strtod(v.c_str(), &end);
      // NaN, infinities, negative and absurd values used to run the driver forever.
      if (end == v.c_str() || *end != '\0' || !(out->duration_s > 0 && out->duration_s <= 1e9)) {
        std::fprintf(stderr, "--duration-s: '%s' must be seconds in (0, 1e9]\n", v.c_str());
        return usage(2);
      }
    }
  }
  if (out->config.empty()) {
    std::fprintf(stderr, "--config is required\n");
    return usage(2);
  }
  return -1;
}

}  // namespace omni
