#include "formats/toml/table_reader.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <type_traits>
#include <utility>

namespace nccomp::formats {

namespace {

constexpr const char* kMissing = "missing required key";

template <typename T>
std::string range_message(const char* what, T min, T max, T v) {
  std::ostringstream s;
  s << "must be " << what << " in [" << min << ", " << max << "], got " << v;
  return s.str();
}

/// A number node's value; nullopt if the node is no number.
std::optional<double> as_number(const toml::node& n) {
  if (const auto* f = n.as_floating_point()) return f->get();
  if (const auto* i = n.as_integer()) return static_cast<double>(i->get());
  return std::nullopt;
}

}  // namespace

TableReader::TableReader(const toml::table& table, std::string key_path, Diagnostics& diag)
    : table_(table), path_(std::move(key_path)), diag_(diag) {}

TableReader::~TableReader() {
  if (!finished_) {
    finish();
  }
}

std::string TableReader::path(std::string_view key) const {
  return path_.empty() ? std::string(key) : path_ + "." + std::string(key);
}

Where TableReader::where(std::string_view key) const {
  const toml::node* n = table_.get(key);
  return where_of(n != nullptr ? n : &table_, path(key));
}

void TableReader::error(std::string_view key, std::string message) {
  diag_.error(where(key), std::move(message));
}

namespace {
void (*g_key_observer)(const std::string&) = nullptr;
void (*g_default_observer)(const std::string&, const std::string&) = nullptr;
}  // namespace

void TableReader::set_key_observer(void (*observer)(const std::string&)) noexcept {
  g_key_observer = observer;
}

void TableReader::set_default_observer(void (*observer)(const std::string&,
                                                        const std::string&)) noexcept {
  g_default_observer = observer;
}

void TableReader::note_default(std::string_view key, const std::string& text) const {
  if (g_default_observer != nullptr) {
    g_default_observer(path(key), text);
  }
}

template <typename T>
void TableReader::note_default(std::string_view key, const std::optional<T>& def) const {
  if (g_default_observer == nullptr || !def) {
    return;
  }
  if constexpr (std::is_same_v<T, bool>) {
    note_default(key, *def ? "true" : "false");
  } else if constexpr (std::is_same_v<T, std::string>) {
    note_default(key, *def);
  } else {
    std::ostringstream s;
    s.precision(17);
    s << *def;
    note_default(key, s.str());
  }
}

const toml::node* TableReader::get(std::string_view key) {
  known_.insert(std::string(key));
  if (g_key_observer != nullptr) {
    g_key_observer(path(key));
  }
  return table_.get(key);
}

const toml::node* TableReader::value(std::string_view key) { return get(key); }

double TableReader::number(std::string_view key, std::optional<double> def, double min,
                           double max) {
  note_default(key, def);
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), kMissing);
      return min;
    }
    return *def;
  }
  const auto v = as_number(*n);
  if (!v) {
    diag_.error(n, path(key), "must be a number");
    return def.value_or(min);
  }
  if (!std::isfinite(*v) || *v < min || *v > max) {
    diag_.error(n, path(key), range_message("a number", min, max, *v));
    return def.value_or(min);
  }
  return *v;
}

double TableReader::number(std::string_view key, std::optional<double> def) {
  note_default(key, def);
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), kMissing);
      return 0.0;
    }
    return *def;
  }
  const auto v = as_number(*n);
  if (!v || !std::isfinite(*v)) {
    std::ostringstream s;
    s << "must be a finite number";
    if (v) s << ", got " << *v;
    diag_.error(n, path(key), s.str());
    return def.value_or(0.0);
  }
  return *v;
}

std::int64_t TableReader::integer(std::string_view key, std::optional<std::int64_t> def,
                                  std::int64_t min, std::int64_t max) {
  note_default(key, def);
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), kMissing);
      return min;
    }
    return *def;
  }
  const auto* i = n->as_integer();
  if (i == nullptr) {
    diag_.error(n, path(key), "must be an integer");
    return def.value_or(min);
  }
  const std::int64_t v = i->get();
  if (v < min || v > max) {
    diag_.error(n, path(key), range_message("an integer", min, max, v));
    return def.value_or(min);
  }
  return v;
}

std::int64_t TableReader::power_of_two(std::string_view key, std::int64_t def, std::int64_t min,
                                       std::int64_t max) {
  const std::int64_t v = integer(key, def, min, max);
  if (v <= 0 || (v & (v - 1)) != 0) {
    error(key, "must be a power of two");
    return def;
  }
  return v;
}

bool TableReader::boolean(std::string_view key, std::optional<bool> def) {
  note_default(key, def);
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), kMissing);
      return false;
    }
    return *def;
  }
  const auto* b = n->as_boolean();
  if (b == nullptr) {
    diag_.error(n, path(key), "must be true or false");
    return def.value_or(false);
  }
  return b->get();
}

std::string TableReader::string(std::string_view key, std::optional<std::string> def) {
  note_default(key, def);
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), kMissing);
      return {};
    }
    return *def;
  }
  const auto* s = n->as_string();
  if (s == nullptr) {
    diag_.error(n, path(key), "must be a string");
    return def.value_or(std::string{});
  }
  return s->get();
}

std::string TableReader::choice(std::string_view key, std::optional<std::string> def,
                                const std::vector<std::string>& choices) {
  const toml::node* n = table_.get(key);
  const bool is_string = n != nullptr && n->is_string();
  std::string v = string(key, def);
  if (is_string && std::find(choices.begin(), choices.end(), v) == choices.end()) {
    std::string list;
    for (const auto& c : choices) {
      list += (list.empty() ? "\"" : ", \"") + c + "\"";
    }
    diag_.error(n, path(key), "must be one of " + list + ", got \"" + v + "\"");
    return def.value_or(choices.front());
  }
  return v;
}

std::vector<std::int64_t> TableReader::integer_list(std::string_view key, std::int64_t min,
                                                    std::int64_t max) {
  std::vector<std::int64_t> out;
  const toml::node* n = get(key);
  if (n == nullptr) {
    return out;
  }
  const auto* arr = n->as_array();
  if (arr == nullptr) {
    diag_.error(n, path(key), "must be an array of integers");
    return out;
  }
  for (std::size_t i = 0; i < arr->size(); ++i) {
    const toml::node& e = *arr->get(i);
    const std::string p = path(key) + "[" + std::to_string(i) + "]";
    const auto* iv = e.as_integer();
    if (iv == nullptr) {
      diag_.error(&e, p, "must be an integer");
      continue;
    }
    if (iv->get() < min || iv->get() > max) {
      diag_.error(&e, p, range_message("an integer", min, max, iv->get()));
      continue;
    }
    out.push_back(iv->get());
  }
  return out;
}

std::vector<double> TableReader::number_list(std::string_view key, double min, double max) {
  std::vector<double> out;
  const toml::node* n = get(key);
  if (n == nullptr) {
    return out;
  }
  const auto* arr = n->as_array();
  if (arr == nullptr) {
    diag_.error(n, path(key), "must be an array of numbers");
    return out;
  }
  for (std::size_t i = 0; i < arr->size(); ++i) {
    const toml::node& e = *arr->get(i);
    const std::string p = path(key) + "[" + std::to_string(i) + "]";
    const auto v = as_number(e);
    if (!v) {
      diag_.error(&e, p, "must be a number");
      continue;
    }
    if (!std::isfinite(*v) || *v < min || *v > max) {
      diag_.error(&e, p, range_message("a number", min, max, *v));
      continue;
    }
    out.push_back(*v);
  }
  return out;
}

const toml::table* TableReader::table(std::string_view key) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    return nullptr;
  }
  if (const auto* t = n->as_table()) {
    return t;
  }
  diag_.error(n, path(key), "must be a table");
  return nullptr;
}

const toml::array* TableReader::table_array(std::string_view key) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    return nullptr;
  }
  const auto* a = n->as_array();
  if (a == nullptr || !a->is_array_of_tables()) {
    diag_.error(n, path(key), "must be an array of tables ([[" + path(key) + "]])");
    return nullptr;
  }
  return a;
}

void TableReader::finish() {
  finished_ = true;
  for (const auto& [k, v] : table_) {
    if (known_.find(k.str()) == known_.end()) {
      diag_.error(&v, path(k.str()), "unknown key");
    }
  }
}

}  // namespace nccomp::formats
