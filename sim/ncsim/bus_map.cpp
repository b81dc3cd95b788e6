#include "sim/ncsim/bus_map.hpp"

#include <string_view>

#include "formats/toml/diagnostics.hpp"
#include "formats/toml/guard.hpp"

namespace nccomp::sim::ncsim {
namespace {

std::string place(const toml::node& n, const std::string& fallback) {
  const auto& s = n.source();
  const std::string file = s.path && !s.path->empty() ? *s.path : fallback;
  return file + ":" + std::to_string(s.begin.line) + ":" + std::to_string(s.begin.column);
}

toml::table parse(const std::string& text, const std::string& file) {
  try {
    return formats::parse_toml(text, file);
  } catch (const toml::parse_error& e) {
    throw formats::DiagnosticsError(e, file);
  }
}

void merge(toml::node& into, toml::node& from, const std::string& path, const std::string& file) {
  auto* a = into.as_table();
  auto* b = from.as_table();
  if (a != nullptr && b != nullptr && !a->is_inline() && !b->is_inline()) {
    for (auto&& [k, v] : *b) {
      const std::string sub =
          path.empty() ? std::string(k.str()) : path + "." + std::string(k.str());
      if (toml::node* existing = a->get(k.str())) {
        merge(*existing, v, sub, file);
      } else {
        a->insert(toml::key(k), std::move(v));
      }
    }
    return;
  }
  auto* x = into.as_array();
  auto* y = from.as_array();
  if (x != nullptr && y != nullptr && x->is_array_of_tables() && y->is_array_of_tables()) {
    for (auto&& e : *y) {
      x->push_back(std::move(e));
    }
    return;
  }
  formats::Diagnostics diag;
  diag.error(&from, path, "already defined at " + place(into, ""));
  throw formats::DiagnosticsError(std::move(diag), file);
}

}  // namespace

toml::table merged_bus_map(const std::string& text, const std::string& file,
                           const std::vector<std::string>& extra_texts,
                           const std::vector<std::string>& extra_files) {
  toml::table root = parse(text, file);
  for (std::size_t i = 0; i < extra_texts.size(); ++i) {
    const std::string& f = i < extra_files.size() ? extra_files[i] : file;
    toml::table extra = parse(extra_texts[i], f);
    merge(root, extra, "", f);
  }
  return root;
}

}  // namespace nccomp::sim::ncsim
