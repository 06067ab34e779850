// The command line of omni's programs: options read one by one, values checked where they are
// read, and every mistake an exit with status 2 and a message naming the program, the option and
// the value (a number that does not parse is never read as 0).
//
//   omni::ArgReader args(argc, argv, "rbpf_mapper", Usage);
//   while (args.Next()) {
//     if (args.Is("--out")) out = args.Value();
//     else if (args.Is("--idle-exit")) idle_s = args.Number(0, 1e6);
//     else args.Unknown();
//   }
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>

namespace omni {

class ArgReader {
 public:
  // `usage(f)` prints the program's usage to f (stdout for --help, stderr after a mistake).
  ArgReader(int argc, char** argv, std::string program, void (*usage)(std::FILE*));

  // Moves to the next argument; false at the end. --help and -h print the usage and exit 0.
  bool Next();
  const std::string& arg() const { return arg_; }
  bool Is(const char* option) const { return arg_ == option; }
  // The LCM URL option, which every process takes under both names: --url and --lcm-url.
  bool IsUrl() const { return arg_ == "--url" || arg_ == "--lcm-url"; }

  // The value after the current option (exit 2 when there is none).
  std::string Value();
  // The value as a finite number in [lo, hi], or an integer in [lo, hi] (exit 2 otherwise).
  double Number(double lo, double hi);
  int64_t Integer(int64_t lo, int64_t hi);

  // The current argument is not an option of this program: exit 2 with the usage.
  [[noreturn]] void Unknown();
  // Any other mistake found after parsing (a missing option, two that exclude each other).
  [[noreturn]] void Fail(const std::string& message);

 private:
  int argc_;
  char** argv_;
  int i_ = 0;
  std::string program_, arg_;
  void (*usage_)(std::FILE*);
};

// The options every mapper process takes (rbpf_mapper, pose_graph_mapper, odom_mapper,
// map_fusion, octomap_builder): --config FILE, --out DIR, --url LCM_URL, --idle-exit S.
struct MapperArgs {
  std::string config, out = "out", url;  // each mapper sets its own --out default
  double idle_exit_s = 0;                // > 0: stop this long after the last message
};
// True when the current argument is one of them (its value is read into *a).
bool ReadMapperArg(ArgReader& args, MapperArgs* a);

}  // namespace omni
