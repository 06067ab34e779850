// One bus message of the simulation, and the encoding every simulated source uses.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace omni::sim {

struct SimEvent {
  std::string channel;
  int64_t utime = 0;
  std::vector<uint8_t> payload;  // the encoded LCM message
};

template <class Msg>
SimEvent EncodeEvent(const std::string& channel, int64_t utime, const Msg& msg) {
  SimEvent e;
  e.channel = channel;
  e.utime = utime;
  e.payload.resize(static_cast<size_t>(msg.getEncodedSize()));
  msg.encode(e.payload.data(), 0, static_cast<int>(e.payload.size()));
  return e;
}

}  // namespace omni::sim
