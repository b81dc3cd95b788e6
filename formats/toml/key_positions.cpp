#include "formats/toml/key_positions.hpp"

namespace nccomp::formats {

void record_positions(const toml::node& node, const std::string& path, KeyPositions& out) {
  out.emplace(path, where_of(&node, path));
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

std::string_view parent_key(std::string_view key) noexcept {
  const auto cut = key.find_last_of(".[");
  return cut == std::string_view::npos ? std::string_view{} : key.substr(0, cut);
}

Where position_of(const KeyPositions& positions, std::string_view key, const Where& fallback) {
  Where w = fallback;
  for (std::string_view k = key; !k.empty(); k = parent_key(k)) {
    if (auto it = positions.find(k); it != positions.end()) {
      w = it->second;
      break;
    }
  }
  w.key_path = std::string(key);
  return w;
}

void report(const KeyPositions& positions, const Where& fallback, const core::ConfigInvalid& e,
            Diagnostics& diag) {
  for (const auto& issue : e.issues()) {
    diag.error(position_of(positions, issue.key, fallback), issue.reason);
  }
}

}  // namespace nccomp::formats
