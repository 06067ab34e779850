#include "omni/common/config.h"

#include <fstream>
#include <map>
#include <sstream>

namespace omni {

Result<ConfigReader> ConfigReader::FromFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) return MakeError(ErrorCode::kNotFound, "config file '" + path + "' cannot be opened");
  std::stringstream ss;
  ss << in.rdbuf();
  return FromString(ss.str(), path);
}

Result<ConfigReader> ConfigReader::FromString(const std::string& yaml_text,
                                              const std::string& name) {
  auto state = std::make_shared<State>();
  state->file = name;
  try {
    state->root = YAML::Load(yaml_text);
  } catch (const YAML::ParserException& e) {
    return MakeError(ErrorCode::kParse, name + ":" + std::to_string(e.mark.line + 1) + ":" +
                                            std::to_string(e.mark.column + 1) +
                                            ": not valid YAML: " + e.msg);
  }
  if (!state->root.IsDefined() || state->root.IsNull())
    state->root = YAML::Node(YAML::NodeType::Map);
  if (!state->root.IsMap()) {
    return MakeError(ErrorCode::kParse, name + ": the top level must be a map of key: value");
  }
  YAML::Node root = state->root;
  return ConfigReader(std::move(state), root, "");
}

ConfigReader ConfigReader::Section(const std::string& key) {
  const std::string full = FullKey(key);
  state_->used.insert(full);
  YAML::Node n = node_.IsMap() ? node_[key] : YAML::Node();
  if (n.IsDefined() && !n.IsNull() && !n.IsMap()) {
    Fail(n, full, Dump(n), "must be a map (a section of keys)");
    n = YAML::Node(YAML::NodeType::Map);
  }
  if (!n.IsDefined() || n.IsNull()) n = YAML::Node(YAML::NodeType::Map);
  return ConfigReader(state_, n, full);
}

bool ConfigReader::Has(const std::string& key) const {
  if (!node_.IsMap()) return false;
  const YAML::Node n = node_[key];
  return n.IsDefined() && !n.IsNull();
}

std::vector<std::string> ConfigReader::Keys() const {
  std::vector<std::string> out;
  if (!node_.IsMap()) return out;
  for (const auto& kv : node_)
    if (kv.first.IsScalar()) out.push_back(kv.first.Scalar());  // others: an error in Finish()
  return out;
}

void ConfigReader::AddError(const std::string& key, const std::string& message) {
  const YAML::Node n = node_.IsMap() ? node_[key] : YAML::Node();
  Fail(n.IsDefined() ? n : node_, FullKey(key), n.IsDefined() ? Dump(n) : "", message);
}

std::string ConfigReader::Where(const YAML::Node& n) const {
  std::string w = state_->file;
  if (n.IsDefined() && n.Mark().line >= 0) w += ":" + std::to_string(n.Mark().line + 1);
  return w;
}

void ConfigReader::Fail(const YAML::Node& at, const std::string& key, const std::string& value,
                        const std::string& rule) {
  std::string msg = Where(at) + ": key '" + key + "'";
  if (!value.empty()) msg += " = '" + value + "'";
  msg += ": " + rule;
  state_->errors.push_back(msg);
}

std::string ConfigReader::Dump(const YAML::Node& n) {
  std::string s;
  if (n.IsScalar()) {
    s = n.Scalar();
  } else {
    YAML::Emitter e;
    e << YAML::Flow << n;
    s = e.c_str();
  }
  // An error quotes the value, not a whole document that an alias or a pasted blob put there.
  constexpr size_t kMax = 80;
  if (s.size() <= kMax) return s;
  size_t cut = kMax;
  while (cut > 0 && (static_cast<unsigned char>(s[cut]) & 0xC0) == 0x80) --cut;  // UTF-8
  return s.substr(0, cut) + "... (" + std::to_string(s.size()) + " bytes)";
}

void ConfigReader::CollectUnknown(const YAML::Node& n, const std::string& path) {
  if (!n.IsMap()) return;
  // A key written twice: the reader takes the first, most YAML tools the last; either way one
  // of the two settings is silently lost.
  std::map<std::string, int> first_line;
  for (const auto& kv : n) {
    if (!kv.first.IsScalar()) continue;
    const std::string key = kv.first.Scalar();
    const int line = kv.first.Mark().line + 1;
    auto [it, fresh] = first_line.emplace(key, line);
    if (!fresh)
      state_->errors.push_back(
          Where(kv.first) + ": key '" + (path.empty() ? key : path + "." + key) +
          "' is given twice (also on line " + std::to_string(it->second) + "): delete one");
  }
  for (const auto& kv : n) {
    // YAML allows a list or a map as a key; no option has such a name.
    if (!kv.first.IsScalar()) {
      state_->errors.push_back(Where(kv.first) + ": key '" + Dump(kv.first) + "'" +
                               (path.empty() ? "" : " in '" + path + "'") +
                               " is not a name (a list or map used as a key)");
      continue;
    }
    const std::string key = kv.first.Scalar();
    const std::string full = path.empty() ? key : path + "." + key;
    if (!state_->used.count(full)) {
      state_->errors.push_back(Where(kv.first) + ": key '" + full +
                               "' is not a known option (misspelled?)");
      continue;
    }
    CollectUnknown(kv.second, full);
  }
}

Status ConfigReader::Finish() {
  CollectUnknown(state_->root, "");
  if (state_->errors.empty()) return Status::Ok();
  std::string all;
  for (size_t i = 0; i < state_->errors.size(); ++i) {
    if (i) all += "\n";
    all += state_->errors[i];
  }
  state_->errors.clear();
  return MakeError(ErrorCode::kInvalidArgument, all);
}

}  // namespace omni
