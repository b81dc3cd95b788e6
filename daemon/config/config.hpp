// The daemon's configuration: one TOML file plus included files, split into sections that are
// parsed by registered section parsers.
//
// - `include = ["reference-nc-modbus.toml", ...]` at the top of a file loads more files, relative
//   to the including file. Each top-level key (section) may be defined in one file only.
// - Every top-level key must belong to a registered section parser: a section nobody registered
//   is an error ("unknown section"), as is every unknown key inside a section.
// - Every error names the file, line, column and key path; the loader collects all of them.
//
// Adding a section (creep, checkpoints, modbus, ...) does not touch the loader: write a
// SectionParser and register it, e.g. in daemon/sections/<name>/ with nccomp_config_section()
// (daemon/CMakeLists.txt) and NCCOMP_REGISTER_CONFIG_SECTION(YourParser).
//
// Not real-time: everything here allocates and may throw.
#pragma once

#include <toml++/toml.h>

#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "core/engine/engine.hpp"
#include "drivers/bus.hpp"
#include "formats/toml/diagnostics.hpp"
#include "formats/toml/table_reader.hpp"

namespace nccomp::daemon::config {

/// Parsed content of one section. Section parsers derive their own type from it.
class Section {
 public:
  virtual ~Section() = default;
};

class Config;

/// Parses one top-level section. Register one instance per section name.
class SectionParser {
 public:
  virtual ~SectionParser() = default;
  /// The top-level key, e.g. "creep".
  [[nodiscard]] virtual std::string_view name() const noexcept = 0;
  /// Parses the section's node (a table, or an array of tables for [[name]] sections). Report
  /// problems to diag (with where_of()/TableReader) and return what could be parsed.
  virtual std::unique_ptr<Section> parse(const toml::node& node,
                                         formats::Diagnostics& diag) const = 0;
  /// The section's value when the file does not have it; nullptr = the section stays absent.
  [[nodiscard]] virtual std::unique_ptr<Section> absent() const { return nullptr; }
  /// After every section is parsed: checks references to other sections.
  virtual void cross_check(const Config& config, formats::Diagnostics& diag) const {
    (void)config;
    (void)diag;
  }
  /// Adds the engine modules this section configures (none by default). Not real-time.
  virtual void add_modules(const Config& config,
                           std::vector<std::unique_ptr<core::engine::Module>>& modules) const {
    (void)config;
    (void)modules;
  }
  /// True if this section describes a bus; make_bus() then builds it (not started).
  [[nodiscard]] virtual bool provides_bus() const noexcept { return false; }
  [[nodiscard]] virtual std::unique_ptr<drivers::Bus> make_bus(const Config& config) const {
    (void)config;
    return nullptr;
  }
};

/// Adds a parser (static initialisation or explicit call). Throws on a duplicate name.
int register_section(std::unique_ptr<SectionParser> parser);
/// All registered parsers, built-in ones included, sorted by name.
[[nodiscard]] std::vector<const SectionParser*> section_parsers();
[[nodiscard]] const SectionParser* find_section_parser(std::string_view name);

/// A loaded configuration.
class Config {
 public:
  /// The main file and every included file, in load order (absolute paths).
  [[nodiscard]] const std::vector<std::string>& files() const noexcept { return files_; }
  /// Directory of the main file: relative paths in the config are relative to it.
  [[nodiscard]] const std::string& base_directory() const noexcept { return base_dir_; }
  [[nodiscard]] bool has(std::string_view section) const;
  /// The section's parsed value as T (nullptr if absent or of another type).
  template <typename T>
  [[nodiscard]] const T* find(std::string_view section) const {
    auto it = sections_.find(section);
    return it == sections_.end() ? nullptr : dynamic_cast<const T*>(it->second.get());
  }
  /// Names of the sections present (parsed or defaulted).
  [[nodiscard]] std::vector<std::string> section_names() const;
  /// Resolves a path from the config against base_directory().
  [[nodiscard]] std::string resolve(const std::string& path) const;

  /// Where a key is, and its value as text when it is a string or an integer ("" otherwise).
  struct KeyInfo {
    formats::Where where;
    std::string value;
  };
  /// Every key of every section ("creep.output.z_register", "registers[8].name", tables
  /// included), recorded by the loader: errors found after loading (the engine's) can name the
  /// file, line and key they concern.
  [[nodiscard]] const std::map<std::string, KeyInfo, std::less<>>& keys() const noexcept {
    return keys_;
  }

  // Used by the loader.
  void set_section(std::string name, std::unique_ptr<Section> section);
  void add_key(std::string key_path, KeyInfo info) {
    keys_.emplace(std::move(key_path), std::move(info));
  }
  void add_file(std::string path) { files_.push_back(std::move(path)); }
  void set_base_directory(std::string dir) { base_dir_ = std::move(dir); }

 private:
  std::vector<std::string> files_;
  std::string base_dir_;
  std::map<std::string, std::unique_ptr<Section>, std::less<>> sections_;
  std::map<std::string, KeyInfo, std::less<>> keys_;
};

struct LoadResult {
  std::unique_ptr<Config> config;  // null if there were errors
  formats::Diagnostics diagnostics;
};

/// Loads path and its includes, parses every section, cross-checks. Never throws for bad input.
[[nodiscard]] LoadResult load_file(const std::string& path);
/// Same for a TOML text (name is used in messages; includes resolve against base_dir).
[[nodiscard]] LoadResult load_string(std::string_view text, const std::string& name,
                                     const std::string& base_dir);

}  // namespace nccomp::daemon::config

#define NCCOMP_REGISTER_CONFIG_SECTION(Type)                                \
  namespace {                                                               \
  [[maybe_unused]] const int nccomp_config_section_registered_##Type =      \
      ::nccomp::daemon::config::register_section(std::make_unique<Type>()); \
  }
