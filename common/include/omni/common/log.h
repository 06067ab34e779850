// Levelled logging to stderr, prefixed with time, level and the process name.
// The level comes from SetLogLevel() or the OMNI_LOG_LEVEL environment variable
// (debug, info, warn, error). Logging is for people; programs get Status/Result values.
#pragma once

#include <sstream>
#include <string>

namespace omni {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarn = 2, kError = 3 };

void SetLogLevel(LogLevel level);
LogLevel GetLogLevel();
void SetLogProcessName(const std::string& name);
// Parses "debug|info|warn|error"; returns false for anything else.
bool ParseLogLevel(const std::string& text, LogLevel* level);
void LogLine(LogLevel level, const std::string& message);

namespace internal {
class LogMessage {
 public:
  explicit LogMessage(LogLevel level) : level_(level) {}
  ~LogMessage() { LogLine(level_, stream_.str()); }
  std::ostringstream& stream() { return stream_; }

 private:
  LogLevel level_;
  std::ostringstream stream_;
};
}  // namespace internal

}  // namespace omni

#define OMNI_LOG(level)                                  \
  if (::omni::LogLevel::level < ::omni::GetLogLevel()) { \
  } else                                                 \
    ::omni::internal::LogMessage(::omni::LogLevel::level).stream()
#define LOG_DEBUG OMNI_LOG(kDebug)
#define LOG_INFO OMNI_LOG(kInfo)
#define LOG_WARN OMNI_LOG(kWarn)
#define LOG_ERROR OMNI_LOG(kError)
