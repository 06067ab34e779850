#include "omni/bus/map_save.h"

#include <filesystem>
#include <utility>

#include "omni/common/log.h"
#include "omni/map_save_reply_t.hpp"
#include "omni/map_save_request_t.hpp"

namespace omni::bus {

MapSaveService::MapSaveService(Bus* bus, std::string process, std::string default_dir,
                               const Clock* clock, Heartbeat* heartbeat)
    : bus_(bus), process_(std::move(process)), default_dir_(std::move(default_dir)), clock_(clock) {
  bus_->Subscribe<omni::map_save_request_t>(
      kMapSaveChannel, [this](const omni::map_save_request_t& m, int64_t) {
        if (!m.process.empty() && m.process != process_) return;  // another process's
        if (pending_.size() >= 16) {  // a flood: answered as refused, nothing written
          Reply(
              m.seq, "",
              MakeError(ErrorCode::kUnavailable, "too many map save requests waiting; try again"));
          return;
        }
        std::string dir = default_dir_;
        if (!m.directory.empty())
          dir = m.process.empty() ? m.directory + "/" + process_ : m.directory;
        pending_.push_back({m.seq, std::move(dir)});
      });
  if (heartbeat != nullptr) {
    heartbeat->AddCounter("maps_saved", [this] { return saved_; });
    heartbeat->AddCounter("map_save_errors", [this] { return failed_; });
  }
}

int MapSaveService::Serve(const WriteFn& write) {
  const std::vector<Request> requests = std::move(pending_);
  pending_.clear();
  for (const Request& r : requests) {
    std::error_code ec;
    std::filesystem::create_directories(r.directory, ec);
    if (ec)
      Reply(
          r.seq, r.directory,
          MakeError(ErrorCode::kIo, "cannot create folder '" + r.directory + "': " + ec.message()));
    else
      Reply(r.seq, r.directory, write(r.directory));
  }
  return static_cast<int>(requests.size());
}

void MapSaveService::Reply(int64_t seq, const std::string& directory, const Status& s) {
  omni::map_save_reply_t reply{};
  reply.utime = clock_->NowUtime();
  reply.seq = seq;
  reply.process = process_;
  reply.directory = directory;
  reply.ok = s.ok();
  reply.message = s.ok() ? "maps written to " + directory : s.message();
  if (s.ok()) {
    ++saved_;
    LOG_INFO << "map save request " << seq << ": written to " << directory;
  } else {
    ++failed_;
    LOG_WARN << "map save request " << seq << " failed: " << s.message();
  }
  bus_->Publish(kMapSaveReplyChannel, reply);
}

}  // namespace omni::bus
