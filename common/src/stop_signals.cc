#include "omni/common/stop_signals.h"

#include <signal.h>

#include <csignal>

namespace omni {

void AlsoStopOnHangup(void (*handler)(int)) {
  struct sigaction sa {};
  sa.sa_handler = handler;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;  // as std::signal's
  struct sigaction old {};
  if (!(sigaction(SIGHUP, nullptr, &old) == 0 && old.sa_handler == SIG_IGN))
    sigaction(SIGHUP, &sa, nullptr);
  std::signal(SIGPIPE, SIG_IGN);
}

}  // namespace omni
