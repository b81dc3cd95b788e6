// The one TOML reader of nccomp's file formats: typed, range-checked accessors on one table that
// report every problem to a Diagnostics (file:line:column, key path) and go on, and unknown keys.
//
// One wording for every format:
//   missing required key            must be a number            must be a number in [a, b], got x
//   must be an integer              must be an integer in [a, b], got n
//   must be true or false           must be a string            must be one of "a", "b", got "x"
//   must be a table                 must be an array of …       unknown key
//
// Not real-time: everything here allocates.
#pragma once

#include <toml++/toml.h>

#include <cstdint>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "formats/toml/diagnostics.hpp"

namespace nccomp::formats {

/// Reads one TOML table with typed, range-checked accessors and reports unknown keys.
/// Every accessor marks its key as known; finish() reports the keys nobody asked for.
/// A `def` of nullopt makes the key required ("missing required key" at the table).
class TableReader {
 public:
  TableReader(const toml::table& table, std::string key_path, Diagnostics& diag);
  TableReader(const TableReader&) = delete;
  TableReader& operator=(const TableReader&) = delete;
  ~TableReader();

  /// A finite number (integer or float) in [min, max]; def if absent or wrong.
  double number(std::string_view key, std::optional<double> def, double min, double max);
  /// Any finite number (integer or float); def if absent or wrong.
  double number(std::string_view key, std::optional<double> def);
  std::int64_t integer(std::string_view key, std::optional<std::int64_t> def, std::int64_t min,
                       std::int64_t max);
  /// An integer in [min, max] that is a power of two (ring capacities); def if absent or wrong.
  std::int64_t power_of_two(std::string_view key, std::int64_t def, std::int64_t min,
                            std::int64_t max);
  bool boolean(std::string_view key, std::optional<bool> def);
  std::string string(std::string_view key, std::optional<std::string> def);
  /// One of `choices`; reports the allowed ones otherwise.
  std::string choice(std::string_view key, std::optional<std::string> def,
                     const std::vector<std::string>& choices);
  /// The value named by the key's string, from `names`; def if absent or not one of them.
  template <typename E>
  E pick(std::string_view key, E def, const std::vector<std::pair<std::string, E>>& names) {
    std::vector<std::string> choices;
    std::optional<std::string> def_name;
    for (const auto& [name, value] : names) {
      choices.push_back(name);
      if (value == def) def_name = name;
    }
    const std::string v = choice(key, def_name.value_or(choices.front()), choices);
    for (const auto& [name, value] : names) {
      if (name == v) return value;
    }
    return def;
  }
  /// Integers in [min, max]; empty if absent.
  std::vector<std::int64_t> integer_list(std::string_view key, std::int64_t min, std::int64_t max);
  /// Finite numbers (integers or floats) in [min, max]; empty if absent.
  std::vector<double> number_list(std::string_view key, double min, double max);
  /// A sub-table (nullptr if absent; an error if present and not a table).
  const toml::table* table(std::string_view key);
  /// An array of tables (nullptr if absent; an error if present with any non-table element).
  const toml::array* table_array(std::string_view key);
  /// The key's node as it is (nullptr if absent), marked as known: for values of a shape no
  /// accessor reads (e.g. an array of pairs or tables).
  const toml::node* value(std::string_view key);

  /// An error at the key (at the table if the key is absent).
  void error(std::string_view key, std::string message);

  [[nodiscard]] std::string path(std::string_view key) const;
  [[nodiscard]] Where where(std::string_view key) const;
  [[nodiscard]] const toml::table& node() const noexcept { return table_; }
  [[nodiscard]] Diagnostics& diagnostics() noexcept { return diag_; }
  /// Reports unknown keys (also done by the destructor if not called).
  void finish();

  /// Test hook (the man page check, tests/unit/docs): called with the key path of every key a
  /// section parser asks a TableReader for, present or not. Not thread-safe; nullptr = off.
  static void set_key_observer(void (*observer)(const std::string& key_path)) noexcept;
  /// Test hook (the man page check of defaults): called with the key path and the default a
  /// parser passes for it (numbers as written by `<<` at 17 digits, strings as they are, booleans
  /// as true/false), whether or not the key is present. Not thread-safe; nullptr = off.
  static void set_default_observer(void (*observer)(const std::string& key_path,
                                                    const std::string& default_text)) noexcept;

 private:
  const toml::node* get(std::string_view key);
  void note_default(std::string_view key, const std::string& text) const;
  template <typename T>
  void note_default(std::string_view key, const std::optional<T>& def) const;
  const toml::table& table_;
  std::string path_;
  Diagnostics& diag_;
  std::set<std::string, std::less<>> known_;
  bool finished_{false};
};

}  // namespace nccomp::formats
