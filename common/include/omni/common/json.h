// JSON text for the reports the tools write (stats.json, fusion.json, --json listings).
#pragma once

#include <string>

namespace omni {

// A string's contents for inside JSON quotes: quotes and backslashes escaped, control bytes as
// \u00XX; other bytes as they are (the caller's text is UTF-8).
std::string JsonEscape(const std::string& s);

}  // namespace omni
