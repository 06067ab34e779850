// One YAML file per process, read into a typed options struct.
//
// Usage (in the options struct's loader):
//   auto reader = ConfigReader::FromFile(path);          // Result: missing/unparsable file
//   reader->Get("particles", &opt.particles, Required(), InRange(1, 1000));
//   auto motion = reader->Section("motion");
//   motion.Get("alpha1", &opt.alpha1, Optional(), NonNegative());
//   Status s = reader->Finish();                          // + keys nobody asked for
// Every problem (missing required key, wrong type, out-of-range value, unknown or misspelled
// key) is an error naming the file, line, key, value and the rule; Finish() reports all of them.
#pragma once

#include <cmath>
#include <functional>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "omni/common/result.h"

namespace omni {

struct Required {};
struct Optional {};

// A rule checks a value and returns "" if fine, else the rule's wording (e.g. "must be > 0").
template <typename T>
using Rule = std::function<std::string(const T&)>;

template <typename T>
Rule<T> InRange(T lo, T hi) {
  return [lo, hi](const T& v) -> std::string {
    if (v >= lo && v <= hi) return "";
    std::ostringstream s;
    s << "must be in [" << lo << ", " << hi << "]";
    return s.str();
  };
}
template <typename T>
Rule<T> Positive() {
  return [](const T& v) -> std::string { return v > T(0) ? "" : "must be > 0"; };
}
template <typename T>
Rule<T> NonNegative() {
  return [](const T& v) -> std::string { return v >= T(0) ? "" : "must be >= 0"; };
}
inline Rule<std::string> OneOf(std::vector<std::string> allowed) {
  return [allowed](const std::string& v) -> std::string {
    for (const auto& a : allowed)
      if (a == v) return "";
    std::string s = "must be one of:";
    for (const auto& a : allowed) s += " " + a;
    return s;
  };
}
inline Rule<std::string> NonEmpty() {
  return [](const std::string& v) -> std::string { return v.empty() ? "must not be empty" : ""; };
}

class ConfigReader {
 public:
  static Result<ConfigReader> FromFile(const std::string& path);
  static Result<ConfigReader> FromString(const std::string& yaml_text, const std::string& name);

  template <typename T>
  void Get(const std::string& key, T* out, Required, Rule<T> rule = nullptr) {
    GetImpl(key, out, /*required=*/true, std::move(rule));
  }
  template <typename T>
  void Get(const std::string& key, T* out, Optional, Rule<T> rule = nullptr) {
    GetImpl(key, out, /*required=*/false, std::move(rule));
  }
  // A nested map. A missing section reads as empty (its required keys then fail by name).
  ConfigReader Section(const std::string& key);
  bool Has(const std::string& key) const;
  // The keys of this section in file order (for sections whose keys are names, e.g. one entry
  // per supervised process); empty when it is not a map.
  std::vector<std::string> Keys() const;

  // Adds an error for a cross-field rule (e.g. "min_range_m < max_range_m").
  void AddError(const std::string& key, const std::string& message);
  // Checks for keys that nobody read (misspellings) and returns every error found.
  Status Finish();
  const std::string& file() const { return state_->file; }

 private:
  struct State {
    std::string file;
    YAML::Node root;
    std::set<std::string> used;
    std::vector<std::string> errors;
  };
  ConfigReader(std::shared_ptr<State> state, YAML::Node node, std::string prefix)
      : state_(std::move(state)), node_(std::move(node)), prefix_(std::move(prefix)) {}

  std::string FullKey(const std::string& key) const {
    return prefix_.empty() ? key : prefix_ + "." + key;
  }
  std::string Where(const YAML::Node& n) const;
  void Fail(const YAML::Node& at, const std::string& key, const std::string& value,
            const std::string& rule);
  void CollectUnknown(const YAML::Node& n, const std::string& path);

  template <typename T>
  void GetImpl(const std::string& key, T* out, bool required, Rule<T> rule) {
    const std::string full = FullKey(key);
    state_->used.insert(full);
    const YAML::Node n = node_.IsMap() ? node_[key] : YAML::Node();
    if (!n.IsDefined()) {
      if (required) Fail(node_, full, "", "required key is missing");
      return;
    }
    if (n.IsNull()) {  // `key:` with nothing after it: a value lost in editing, not "default"
      Fail(n, full, "", "has no value (give one, or delete the key for the default)");
      return;
    }
    T value{};
    try {
      value = n.as<T>();
    } catch (const YAML::Exception&) {
      Fail(n, full, Dump(n), std::string("has the wrong type: expected ") + TypeName<T>());
      return;
    }
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(value)) {
        Fail(n, full, Dump(n), "must be a finite number");
        return;
      }
    }
    if (rule) {
      const std::string why = rule(value);
      if (!why.empty()) {
        Fail(n, full, Dump(n), why);
        return;
      }
    }
    *out = value;
  }
  static std::string Dump(const YAML::Node& n);
  template <typename T>
  static const char* TypeName() {
    if constexpr (std::is_same_v<T, bool>)
      return "true/false";
    else if constexpr (std::is_integral_v<T>)
      return "an integer";
    else if constexpr (std::is_floating_point_v<T>)
      return "a number";
    else if constexpr (std::is_same_v<T, std::string>)
      return "a string";
    else
      return "a list";
  }

  std::shared_ptr<State> state_;
  YAML::Node node_;
  std::string prefix_;
};

}  // namespace omni
