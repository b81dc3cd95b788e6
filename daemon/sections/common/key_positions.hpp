// Positions of every key of a config section, so that errors found after parsing (by a core
// validate(), by a module's attach()) point at the key they name. Header-only: shared by the
// module sections (creep, checkpoints, calibration) without a library of its own. Not real-time.
#pragma once

#include <map>
#include <string>
#include <string_view>
#include <utility>

#include "daemon/config/config.hpp"

namespace nccomp::daemon::sections {

/// Key path → position, e.g. "creep.edge.edge_points", "creep.deflection[0].wear_um[2]".
using KeyPositions = std::map<std::string, config::Where, std::less<>>;

/// Records the position of node and of every key below it (tables and arrays, [i] indices).
inline void record_positions(const toml::node& node, const std::string& path, KeyPositions& out) {
  out.emplace(path, config::where_of(&node, path));
  if (const auto* t = node.as_table()) {
    for (const auto& [k, v] : *t) {
      record_positions(v, path + "." + std::string(k.str()), out);
    }
  } else if (const auto* a = node.as_array()) {
    for (std::size_t i = 0; i < a->size(); ++i) {
      record_positions(*a->get(i), path + "[" + std::to_string(i) + "]", out);
    }
  }
}

/// The position of the key a message names: the first word starting with `prefix` (e.g.
/// "creep."), cut back to the nearest key present ("creep.deflection[0].wear_um[2]" →
/// "creep.deflection[0].wear_um" → ...). `fallback` if the message names none.
inline config::Where locate_key(const KeyPositions& positions, const config::Where& fallback,
                                std::string_view message, std::string_view prefix) {
  const auto start = message.find(prefix);
  if (start == std::string_view::npos) {
    return fallback;
  }
  std::size_t end = start;
  while (end < message.size() && message[end] != ' ' && message[end] != ':' &&
         message[end] != ',' && message[end] != '"') {
    ++end;
  }
  std::string key(message.substr(start, end - start));
  while (!key.empty()) {
    if (auto it = positions.find(key); it != positions.end()) {
      return it->second;
    }
    const auto cut = key.find_last_of(".[");
    if (cut == std::string::npos) {
      break;
    }
    key.resize(cut);
  }
  return fallback;
}

/// Reports message at the key it names (locate_key), without repeating a leading "key: " that the
/// diagnostic's own key path already shows.
inline void report_at_key(const KeyPositions& positions, const config::Where& fallback,
                          std::string message, std::string_view prefix, config::Diagnostics& diag) {
  config::Where where = locate_key(positions, fallback, message, prefix);
  const std::string lead = where.key_path + ": ";
  if (message.rfind(lead, 0) == 0) {
    message.erase(0, lead.size());
  }
  diag.error(std::move(where), std::move(message));
}

}  // namespace nccomp::daemon::sections
