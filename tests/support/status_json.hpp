// Reads numbers out of nccompd's status JSON (the status socket's answer) for tests.
#pragma once

#include <nlohmann/json.hpp>

#include <optional>
#include <string>

namespace nccomp::test {

namespace status_json_detail {

// Depth-first in document order (ordered_json keeps it): the first member `key` whose value is a
// number, at any depth.
inline std::optional<double> find_number(const nlohmann::ordered_json& j, const std::string& key) {
  if (j.is_object()) {
    for (const auto& [k, v] : j.items()) {
      if (k == key && v.is_number()) return v.get<double>();
      if (auto found = find_number(v, key)) return found;
    }
  } else if (j.is_array()) {
    for (const auto& v : j) {
      if (auto found = find_number(v, key)) return found;
    }
  }
  return std::nullopt;
}

}  // namespace status_json_detail

/// The number of the first member named `key` (at any depth, in document order) of the JSON
/// text; nullopt if there is none or the text is not JSON.
inline std::optional<double> find_number(const std::string& json, const std::string& key) {
  const auto doc = nlohmann::ordered_json::parse(json, nullptr, false);
  if (doc.is_discarded()) return std::nullopt;
  return status_json_detail::find_number(doc, key);
}

/// find_number(), or -1e300 where there is none: a comparison with any expected value then
/// fails and prints the status.
inline double number(const std::string& json, const std::string& key) {
  return find_number(json, key).value_or(-1e300);
}

}  // namespace nccomp::test
