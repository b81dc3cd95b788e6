#include "formats/toml/table_reader.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <utility>

namespace nccomp::formats {

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

const toml::node* TableReader::get(std::string_view key) {
  known_.insert(std::string(key));
  return table_.get(key);
}

double TableReader::number(std::string_view key, std::optional<double> def, double min,
                           double max) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), "required key is missing");
      return min;
    }
    return *def;
  }
  double v = 0.0;
  if (const auto* f = n->as_floating_point()) {
    v = f->get();
  } else if (const auto* i = n->as_integer()) {
    v = static_cast<double>(i->get());
  } else {
    diag_.error(n, path(key), "expected a number");
    return def.value_or(min);
  }
  if (!std::isfinite(v) || v < min || v > max) {
    std::ostringstream s;
    s << "value " << v << " is out of range [" << min << ", " << max << "]";
    diag_.error(n, path(key), s.str());
    return def.value_or(min);
  }
  return v;
}

std::int64_t TableReader::integer(std::string_view key, std::optional<std::int64_t> def,
                                  std::int64_t min, std::int64_t max) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), "required key is missing");
      return min;
    }
    return *def;
  }
  const auto* i = n->as_integer();
  if (i == nullptr) {
    diag_.error(n, path(key), "expected an integer");
    return def.value_or(min);
  }
  const std::int64_t v = i->get();
  if (v < min || v > max) {
    diag_.error(n, path(key),
                "value " + std::to_string(v) + " is out of range [" + std::to_string(min) + ", " +
                    std::to_string(max) + "]");
    return def.value_or(min);
  }
  return v;
}

bool TableReader::boolean(std::string_view key, std::optional<bool> def) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), "required key is missing");
      return false;
    }
    return *def;
  }
  const auto* b = n->as_boolean();
  if (b == nullptr) {
    diag_.error(n, path(key), "expected true or false");
    return def.value_or(false);
  }
  return b->get();
}

std::string TableReader::string(std::string_view key, std::optional<std::string> def) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (!def) {
      diag_.error(where_of(&table_, path(key)), "required key is missing");
      return {};
    }
    return *def;
  }
  const auto* s = n->as_string();
  if (s == nullptr) {
    diag_.error(n, path(key), "expected a string");
    return def.value_or(std::string{});
  }
  return s->get();
}

std::string TableReader::choice(std::string_view key, std::optional<std::string> def,
                                const std::vector<std::string>& choices) {
  const bool present = table_.get(key) != nullptr;
  std::string v = string(key, def);
  if (present && std::find(choices.begin(), choices.end(), v) == choices.end()) {
    std::string list;
    for (const auto& c : choices) {
      list += (list.empty() ? "\"" : ", \"") + c + "\"";
    }
    diag_.error(table_.get(key), path(key), "\"" + v + "\" is not one of " + list);
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
    diag_.error(n, path(key), "expected an array of integers");
    return out;
  }
  for (std::size_t i = 0; i < arr->size(); ++i) {
    const toml::node& e = *arr->get(i);
    const std::string p = path(key) + "[" + std::to_string(i) + "]";
    const auto* iv = e.as_integer();
    if (iv == nullptr) {
      diag_.error(&e, p, "expected an integer");
      continue;
    }
    if (iv->get() < min || iv->get() > max) {
      diag_.error(&e, p,
                  "value " + std::to_string(iv->get()) + " is out of range [" +
                      std::to_string(min) + ", " + std::to_string(max) + "]");
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
    diag_.error(n, path(key), "expected an array of numbers");
    return out;
  }
  for (std::size_t i = 0; i < arr->size(); ++i) {
    const toml::node& e = *arr->get(i);
    const std::string p = path(key) + "[" + std::to_string(i) + "]";
    double v = 0.0;
    if (const auto* f = e.as_floating_point()) {
      v = f->get();
    } else if (const auto* iv = e.as_integer()) {
      v = static_cast<double>(iv->get());
    } else {
      diag_.error(&e, p, "expected a number");
      continue;
    }
    if (!std::isfinite(v) || v < min || v > max) {
      std::ostringstream s;
      s << "value " << v << " is out of range [" << min << ", " << max << "]";
      diag_.error(&e, p, s.str());
      continue;
    }
    out.push_back(v);
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
  diag_.error(n, path(key), "expected a table");
  return nullptr;
}

const toml::array* TableReader::table_array(std::string_view key) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    return nullptr;
  }
  const auto* a = n->as_array();
  if (a == nullptr || !a->is_array_of_tables()) {
    diag_.error(n, path(key), "expected an array of tables ([[" + path(key) + "]])");
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
