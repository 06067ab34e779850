// Recoverable errors as values: Status (ok or an error) and Result<T> (a value or an error).
// Errors carry a message written for the person who has to act on it: it names the file,
// line/offset, key or device involved.
#pragma once

#include <cassert>
#include <optional>
#include <string>
#include <utility>
#include <variant>

namespace omni {

enum class ErrorCode {
  kInvalidArgument,  // caller passed something malformed
  kNotFound,         // file, device, key absent
  kParse,            // bytes or text that do not follow the format
  kIo,               // the operating system refused (open, read, write)
  kUnavailable,      // a device or peer that may come back
  kOutOfRange,       // a value outside its allowed range
  kInternal,         // a bug: should not happen
};

const char* ErrorCodeName(ErrorCode code);

struct Error {
  ErrorCode code = ErrorCode::kInternal;
  std::string message;
  std::string ToString() const { return std::string(ErrorCodeName(code)) + ": " + message; }
};

class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(Error e) : error_(std::move(e)) {}  // NOLINT: implicit, so `return Error{...}` works
  static Status Ok() { return Status(); }
  bool ok() const { return !error_.has_value(); }
  const Error& error() const {
    assert(error_);
    return *error_;
  }
  std::string message() const { return error_ ? error_->message : std::string("ok"); }

 private:
  std::optional<Error> error_;
};

template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::move(value)) {}  // NOLINT
  Result(Error e) : v_(std::move(e)) {}      // NOLINT
  bool ok() const { return std::holds_alternative<T>(v_); }
  explicit operator bool() const { return ok(); }
  const Error& error() const {
    assert(!ok());
    return std::get<Error>(v_);
  }
  T& value() & {
    assert(ok());
    return std::get<T>(v_);
  }
  const T& value() const& {
    assert(ok());
    return std::get<T>(v_);
  }
  T&& value() && {
    assert(ok());
    return std::get<T>(std::move(v_));
  }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }
  Status status() const { return ok() ? Status() : Status(error()); }

 private:
  std::variant<T, Error> v_;
};

inline Error MakeError(ErrorCode code, std::string message) {
  return Error{code, std::move(message)};
}

}  // namespace omni
