// omni-canbus: a tiny candump/cansend for the omni CAN bus URLs.
//   omni-canbus dump <url> [count]          print frames (id#data), forever or `count` frames
//   omni-canbus send <url> <id>#<hexdata>   send one frame, e.g. 022#0000000000000000
//   omni-canbus link <name> up|down         bring a user-space bus up or down
//   omni-canbus rm <name>                   remove a user-space bus file
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "omni/can/can_bus.h"
#include "omni/can/shm_can_bus.h"

namespace {

int Usage(int code) {
  std::fprintf(code == 0 ? stdout : stderr,
               "usage: omni-canbus dump <url> [count]\n"
               "       omni-canbus send <url> <id>#<hexdata>\n"
               "       omni-canbus link <name> up|down\n"
               "       omni-canbus rm <name>\n"
               "urls: shm:<name> (user-space bus), socketcan:<ifname> or just <ifname> (can0)\n");
  return code;
}

bool ParseFrame(const std::string& s, omni::can::Frame* f) {
  const auto hash = s.find('#');
  if (hash == std::string::npos || hash == 0) return false;
  char* end = nullptr;
  const unsigned long id = std::strtoul(s.substr(0, hash).c_str(), &end, 16);
  if (*end != '\0' || id > 0x1FFFFFFF) return false;
  const std::string hex = s.substr(hash + 1);
  if (hex.size() % 2 != 0 || hex.size() > 16) return false;
  f->id = static_cast<uint32_t>(id);
  f->extended = hash > 3;
  f->dlc = static_cast<uint8_t>(hex.size() / 2);
  for (size_t i = 0; i < hex.size(); i += 2) {
    const unsigned long b = std::strtoul(hex.substr(i, 2).c_str(), &end, 16);
    if (*end != '\0') return false;
    f->data[i / 2] = static_cast<uint8_t>(b);
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) return Usage(2);
  const std::string cmd = argv[1];
  if (cmd == "--help" || cmd == "-h") return Usage(0);
  if (argc < 3) return Usage(2);
  if (cmd == "link" && argc == 4) {
    const std::string state = argv[3];
    if (state != "up" && state != "down") return Usage(2);
    const omni::Status s = omni::can::ShmCanBus::SetLinkUp(argv[2], state == "up");
    if (!s.ok()) std::fprintf(stderr, "%s\n", s.error().ToString().c_str());
    return s.ok() ? 0 : 1;
  }
  if (cmd == "rm") {
    const omni::Status s = omni::can::ShmCanBus::Remove(argv[2]);
    if (!s.ok()) std::fprintf(stderr, "%s\n", s.error().ToString().c_str());
    return s.ok() ? 0 : 1;
  }
  auto bus = omni::can::OpenCanBus(argv[2]);
  if (!bus.ok()) {
    std::fprintf(stderr, "%s\n", bus.error().ToString().c_str());
    return 1;
  }
  if (cmd == "send" && argc == 4) {
    omni::can::Frame f;
    if (!ParseFrame(argv[3], &f)) return Usage(2);
    const omni::Status s = (*bus)->Send(f);
    if (!s.ok()) std::fprintf(stderr, "%s\n", s.error().ToString().c_str());
    return s.ok() ? 0 : 1;
  }
  if (cmd == "dump") {
    const long count = argc > 3 ? std::strtol(argv[3], nullptr, 10) : -1;
    for (long n = 0; count < 0 || n < count;) {
      omni::can::Frame f;
      auto r = (*bus)->Receive(&f, 1000);
      if (!r.ok()) {
        std::fprintf(stderr, "%s\n", r.error().ToString().c_str());
        return 1;
      }
      if (!r.value()) continue;
      std::printf(f.extended ? "%08X#" : "%03X#", f.id);
      for (int i = 0; i < f.dlc; ++i) std::printf("%02X", f.data[i]);
      std::printf("\n");
      std::fflush(stdout);
      ++n;
    }
    return 0;
  }
  return Usage(2);
}
