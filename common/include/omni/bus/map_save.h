// Map saving on request (what ROS's map_saver does for a running mapper): a process that owns
// maps serves map_save_request_t on MAP_SAVE and answers on MAP_SAVE_REPLY, while it keeps
// mapping. `omni save-map` sends the request and prints the answers.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "omni/bus/bus.h"
#include "omni/bus/heartbeat.h"
#include "omni/common/result.h"
#include "omni/common/time.h"

namespace omni::bus {

inline constexpr const char* kMapSaveChannel = "MAP_SAVE";             // omni.map_save_request_t
inline constexpr const char* kMapSaveReplyChannel = "MAP_SAVE_REPLY";  // omni.map_save_reply_t

class MapSaveService {
 public:
  // Takes the requests addressed to `process` or to every mapper (process ""); a request
  // without a directory means `default_dir` (the process's --out). Adds the counters
  // maps_saved and map_save_errors to `heartbeat` when given.
  MapSaveService(Bus* bus, std::string process, std::string default_dir, const Clock* clock,
                 Heartbeat* heartbeat = nullptr);

  // Serves the requests that arrived since the last call: creates each one's folder, calls
  // `write(dir)` and publishes the reply (ok, or the folder's or the write's error). Returns how
  // many requests it served. Call it from the process's loop, between units of work.
  using WriteFn = std::function<Status(const std::string& dir)>;
  int Serve(const WriteFn& write);

  int64_t saved() const { return saved_; }
  int64_t failed() const { return failed_; }

 private:
  struct Request {
    int64_t seq;
    std::string directory;
  };
  // Counts, logs and publishes the answer to request `seq` (ok when s is).
  void Reply(int64_t seq, const std::string& directory, const Status& s);
  Bus* bus_;
  std::string process_, default_dir_;
  const Clock* clock_;
  std::vector<Request> pending_;
  int64_t saved_ = 0, failed_ = 0;
};

}  // namespace omni::bus
