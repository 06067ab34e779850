// Stop signals for a process with its own stop handler.
#pragma once

namespace omni {

// SIGHUP (the terminal or SSH session went away) goes to `handler` as SIGINT and SIGTERM do,
// unless it is ignored already when this is called (`nohup`: the process was meant to outlive
// the terminal). SIGPIPE is ignored: a log line to a pipe whose reader is gone (`... | tee`, tee
// ended by the same hangup) fails instead of killing the process before it has stopped in order.
void AlsoStopOnHangup(void (*handler)(int));

}  // namespace omni
