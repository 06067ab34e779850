// A pseudo-terminal for device emulators and tests: the emulator owns the master side and
// drivers open the slave path (or a stable symlink to it, like a udev rule's /dev/rplidar).
// The slave is put in raw mode at once (no echo), so bytes pass through unchanged.
#pragma once

#include <memory>
#include <string>

#include "omni/common/result.h"

namespace omni::serial {

class Pty {
 public:
  // Creates a pty. When `link_path` is not empty, a symlink there points at the slave (an
  // existing symlink is replaced; any other existing file is an error naming it).
  static Result<std::unique_ptr<Pty>> Create(const std::string& link_path = "");
  // Closes the master (the device "vanishes": readers of the slave get a hangup) and removes the
  // symlink.
  ~Pty();
  Pty(const Pty&) = delete;
  Pty& operator=(const Pty&) = delete;

  int master_fd() const { return master_; }
  const std::string& slave_path() const { return slave_path_; }
  // The path drivers should open: the symlink if any, else the slave device.
  const std::string& path() const { return link_path_.empty() ? slave_path_ : link_path_; }

 private:
  Pty() = default;
  int master_ = -1;
  int slave_keepalive_ = -1;  // keeps the line open so the master never reads EIO
  std::string slave_path_;
  std::string link_path_;
};

}  // namespace omni::serial
