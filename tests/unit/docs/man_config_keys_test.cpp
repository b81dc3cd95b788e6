// GIVEN man/nccompd.toml.5.scd (the source of nccompd.toml(5)) and the daemon's configuration
// loader with every registered section parser, THEN the man page and the schema agree:
// - every key of every shipped configuration (config/*.toml, config/demo/*.toml and the files
//   they include, as the loader sees them; plus nccompd-model-context.toml here for [model] and
//   [measurement_context]) and every key a TableReader-based section parser asks for (present or
//   not: its full key list) is documented;
// - every documented key is known to the parsers: written into a configuration, it is not
//   refused as an unknown key (while two made-up keys in the same table are);
// - every default the page gives as a literal ("*key* = _number_, default 0.5", a quoted string,
//   true/false) is the default a parser passes to its TableReader for that key (where a parser
//   passes one: keys whose default is computed from other keys are not checked).
//
// The page documents a table with a heading "## [a.b]" ("## [[a.b]]" for an array of tables; a
// segment in capitals stands for any name: [modbus.GROUP.SIGNAL] is every Modbus signal) and each
// key with a line "*key* = ..." below it. Top-level keys stand under a heading without brackets.
// The fixtures nccompd-model-context.toml and nccompd-creep-extra.toml add the tables no shipped
// example has.
#include <gtest/gtest.h>
#include <toml++/toml.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "daemon/config/config.hpp"
#include "formats/toml/table_reader.hpp"

namespace {

namespace fs = std::filesystem;
namespace cfg = nccomp::daemon::config;

const fs::path kSource = NCCOMP_SOURCE_DIR;

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

/// "registers[3].name" -> "registers.name".
std::string strip_indices(const std::string& path) {
  return std::regex_replace(path, std::regex(R"(\[[0-9]+\])"), "");
}

std::vector<std::string> split(const std::string& path) {
  std::vector<std::string> parts;
  std::string cur;
  for (char c : path) {
    if (c == '.') {
      parts.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  parts.push_back(cur);
  return parts;
}

/// A documented key or table pattern matches a path segment by segment (an upper-case segment,
/// e.g. SIGNAL, stands for any one).
bool matches(const std::string& pattern, const std::string& path) {
  const auto p = split(pattern);
  const auto k = split(path);
  if (p.size() != k.size()) {
    return false;
  }
  for (std::size_t i = 0; i < p.size(); ++i) {
    const bool any =
        std::all_of(p[i].begin(), p[i].end(), [](char c) { return c >= 'A' && c <= 'Z'; });
    if (!any && p[i] != k[i]) {
      return false;
    }
  }
  return true;
}

struct ManPage {
  std::set<std::string> tables;  // "daemon.realtime", "registers", "modbus.GROUP.SIGNAL"
  std::set<std::string> arrays;  // the tables written [[...]]
  std::map<std::string, std::set<std::string>> keys;  // table ("" = top level) -> key names
  /// "table.key" -> the literal after "default" on the key's line (number, "string", true/false).
  std::map<std::string, std::string> defaults;
};

/// The literal a "default ..." names: a quoted string (with its quotes), true/false or a number;
/// empty if the default is not a literal (e.g. "default: none", "default the NC's value").
std::string default_literal(const std::string& line) {
  static const std::regex def(
      R"(, default ("[^"]*"|true|false|-?[0-9]+(\.[0-9]+)?(e-?[0-9]+)?)(?=[ ,;(]|$))");
  std::smatch m;
  return std::regex_search(line, m, def) ? m[1].str() : std::string{};
}

ManPage read_man_page() {
  ManPage m;
  std::istringstream in(slurp(kSource / "man/nccompd.toml.5.scd"));
  const std::regex heading(R"(^#{2,3} (\[\[?)([A-Za-z0-9_.]+)\]\]?\s*$)");
  const std::regex other_heading(R"(^#{1,3} )");
  const std::regex key(R"(^\*([a-z0-9_]+)\* = )");
  std::string table;
  std::string line;
  while (std::getline(in, line)) {
    std::smatch mm;
    if (std::regex_match(line, mm, heading)) {
      table = mm[2].str();
      m.tables.insert(table);
      if (mm[1].str() == "[[") {
        m.arrays.insert(table);
      }
    } else if (std::regex_search(line, other_heading)) {
      table.clear();
    } else if (std::regex_search(line, mm, key)) {
      m.keys[table].insert(mm[1].str());
      if (const std::string d = default_literal(line); !d.empty()) {
        m.defaults[table.empty() ? mm[1].str() : table + "." + mm[1].str()] = d;
      }
    }
  }
  return m;
}

/// Documented as a key (table.key) or as a table heading.
bool documented(const ManPage& m, const std::string& path) {
  for (const auto& t : m.tables) {
    if (matches(t, path)) {
      return true;
    }
  }
  const auto dot = path.rfind('.');
  const std::string table = dot == std::string::npos ? "" : path.substr(0, dot);
  const std::string name = dot == std::string::npos ? path : path.substr(dot + 1);
  for (const auto& [t, names] : m.keys) {
    if (names.count(name) > 0 && (t.empty() ? table.empty() : matches(t, table))) {
      return true;
    }
  }
  return false;
}

std::vector<std::string>* g_observed = nullptr;
void observe(const std::string& key_path) { g_observed->push_back(key_path); }

std::map<std::string, std::set<std::string>>* g_defaults = nullptr;
void observe_default(const std::string& key_path, const std::string& text) {
  (*g_defaults)[strip_indices(key_path)].insert(text);
}

/// The page's literal and a parser's default text name the same value.
bool same_default(const std::string& page, const std::string& parser) {
  if (page.size() >= 2 && page.front() == '"') {
    return page.substr(1, page.size() - 2) == parser;
  }
  if (page == "true" || page == "false") {
    return page == parser;
  }
  char* end = nullptr;
  const double a = std::strtod(page.c_str(), &end);
  const double b = std::strtod(parser.c_str(), &end);
  if (end == parser.c_str() || *end != '\0') {
    return false;
  }
  return std::fabs(a - b) <= 1e-12 * std::max(1.0, std::fabs(a));
}

/// The shipped configurations, copied with the files they include (config/ and
/// sim/ncsim/config/ keep their relative places), loaded with the key observer on.
class ManConfigKeys : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("nccomp_man_keys_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "sim/ncsim");
    fs::copy(kSource / "config", dir_ / "config", fs::copy_options::recursive);
    fs::copy(kSource / "sim/ncsim/config", dir_ / "sim/ncsim/config", fs::copy_options::recursive);
    fs::create_directories(dir_ / "fixture");
    fs::copy(kSource / "tests/unit/docs/nccompd-model-context.toml", dir_ / "fixture");
    fs::copy(kSource / "tests/unit/docs/nccompd-creep-extra.toml", dir_ / "fixture");
    fs::copy(kSource / "bench/model/figures/fl_thermal_ch1/model.toml", dir_ / "fixture");
  }
  void TearDown() override { fs::remove_all(dir_); }

  /// Every main configuration of config/ and config/demo/ (files that load as a whole: maps and
  /// parts meant to be included, ncsim's files and the analyze model config do not), and the
  /// fixture with what no shipped example has.
  std::vector<fs::path> mains() const {
    std::vector<fs::path> files;
    for (const auto& sub : {dir_ / "config", dir_ / "config/demo", dir_ / "fixture"}) {
      for (const auto& e : fs::directory_iterator(sub)) {
        const std::string name = e.path().filename().string();
        if (e.path().extension() == ".toml" && name.rfind("nccompd", 0) == 0) {
          files.push_back(e.path());
        }
      }
    }
    std::sort(files.begin(), files.end());
    return files;
  }

  fs::path dir_;
};

TEST_F(ManConfigKeys, EveryKnownKeyIsDocumentedAndEveryDocumentedKeyIsKnown) {
  const ManPage page = read_man_page();
  ASSERT_GT(page.tables.size(), 10U) << "man/nccompd.toml.5.scd: no table headings found";

  // 1. What the schema has: the keys of every loadable shipped configuration and every key a
  //    TableReader was asked for while loading them.
  std::vector<std::string> observed;
  g_observed = &observed;
  nccomp::formats::TableReader::set_key_observer(&observe);
  std::set<std::string> schema;
  // A loaded configuration per table instance ("modbus.axis.x_mm", "registers[0]"): where the
  // probe below writes a key.
  struct Instance {
    fs::path main;
    std::string path;  // with indices
    std::string file;  // the file that defines it
  };
  std::map<std::string, Instance> instance_of;  // stripped table path -> first instance
  int loaded = 0;
  for (const fs::path& main : mains()) {
    const cfg::LoadResult r = cfg::load_file(main.string());
    if (!r.config) {
      continue;  // e.g. a demo config whose model.toml is written by the demo run
    }
    ++loaded;
    for (const auto& [path, info] : r.config->keys()) {
      const std::string p = strip_indices(path);
      schema.insert(p);
      const auto last_dot = path.rfind('.');
      if (last_dot != std::string::npos) {
        const std::string table = path.substr(0, last_dot);
        instance_of.try_emplace(strip_indices(table), Instance{main, table, ""});
      }
    }
    for (auto& [table, inst] : instance_of) {
      if (inst.main == main && inst.file.empty()) {
        const auto it = r.config->keys().find(inst.path);
        if (it != r.config->keys().end()) {
          inst.file = it->second.where.file;
        }
      }
    }
  }
  nccomp::formats::TableReader::set_key_observer(nullptr);
  g_observed = nullptr;
  EXPECT_GE(loaded, 5) << "fewer shipped configurations load than expected";
  for (const auto& o : observed) {
    schema.insert(strip_indices(o));
  }
  for (const std::string& key : schema) {
    EXPECT_TRUE(documented(page, key)) << "key '" << key << "' is not in nccompd.toml(5)";
  }

  // 2. What the page names: each documented key written into a configuration that has its table
  //    must not be an unknown key. A probe writes every documented key of one table instance at
  //    once, plus two made-up keys that must come back as unknown (so a parser that stops at its
  //    first error cannot pass a table unchecked); where it does not report both, each key is
  //    written alone.
  for (const auto& [table, names] : page.keys) {
    if (table.empty()) {
      for (const std::string& n : names) {
        EXPECT_TRUE(n == "include") << "top-level key '" << n << "' is not a section";
      }
      continue;
    }
    std::optional<Instance> inst;
    for (const auto& [stripped, i] : instance_of) {
      if (matches(table, stripped) && !i.file.empty()) {
        inst = i;
        break;
      }
    }
    if (!inst) {
      ADD_FAILURE() << "documented table [" << table
                    << "] is in no shipped configuration: its keys cannot be checked";
      continue;
    }
    const std::string original = slurp(inst->file);
    // The instance path inside its file: the same path (the loader merges files key by key).
    const auto probe = [&](const std::vector<std::string>& keys) {
      toml::table doc = toml::parse(original, inst->file);
      toml::node* node = doc.at_path(inst->path).node();
      EXPECT_NE(node, nullptr) << inst->path << " in " << inst->file;
      if (node == nullptr || node->as_table() == nullptr) {
        return std::set<std::string>{};
      }
      for (const std::string& k : keys) {
        if (!node->as_table()->contains(k)) {
          node->as_table()->insert(k, 0);
        }
      }
      { std::ofstream(inst->file) << doc << "\n"; }
      const cfg::LoadResult r = cfg::load_file(inst->main.string());
      { std::ofstream(inst->file) << original; }
      std::set<std::string> unknown;
      for (const auto& d : r.diagnostics.items()) {
        if (d.message.rfind("unknown key", 0) == 0 || d.message.rfind("unknown signal", 0) == 0 ||
            d.message.rfind("unknown section", 0) == 0) {
          const std::string p = strip_indices(d.where.key_path);
          unknown.insert(p.substr(p.rfind('.') + 1));
        }
      }
      return unknown;
    };
    std::vector<std::string> batch(names.begin(), names.end());
    batch.push_back("nccomp_probe_a");
    batch.push_back("nccomp_probe_z");
    std::set<std::string> unknown = probe(batch);
    if (unknown.count("nccomp_probe_a") == 0 || unknown.count("nccomp_probe_z") == 0) {
      unknown.clear();
      for (const std::string& n : names) {
        const auto u = probe({n});
        unknown.insert(u.begin(), u.end());
      }
      EXPECT_EQ(probe({"nccomp_probe_a"}).count("nccomp_probe_a"), 1U)
          << "[" << table << "]: a made-up key is not refused, the probe sees nothing";
    }
    for (const std::string& n : names) {
      EXPECT_EQ(unknown.count(n), 0U) << "nccompd.toml(5) documents '" << table << "." << n
                                      << "', which the parser refuses as unknown (probed in "
                                      << inst->path << " of " << inst->file << ")";
    }
  }
}

TEST_F(ManConfigKeys, EveryLiteralDefaultOnThePageIsTheParsersDefault) {
  const ManPage page = read_man_page();
  ASSERT_GT(page.defaults.size(), 100U) << "man/nccompd.toml.5.scd: no defaults found";
  std::map<std::string, std::set<std::string>> defaults;  // key path -> parsers' defaults
  g_defaults = &defaults;
  nccomp::formats::TableReader::set_default_observer(&observe_default);
  for (const fs::path& main : mains()) {
    (void)cfg::load_file(main.string());
  }
  nccomp::formats::TableReader::set_default_observer(nullptr);
  g_defaults = nullptr;
  ASSERT_GT(defaults.size(), 100U) << "the parsers reported almost no defaults";

  std::size_t checked = 0;
  for (const auto& [doc_key, literal] : page.defaults) {
    const auto dot = doc_key.rfind('.');
    const std::string table = dot == std::string::npos ? "" : doc_key.substr(0, dot);
    const std::string name = dot == std::string::npos ? doc_key : doc_key.substr(dot + 1);
    std::set<std::string> seen;
    for (const auto& [path, texts] : defaults) {
      const auto pd = path.rfind('.');
      const std::string ptable = pd == std::string::npos ? "" : path.substr(0, pd);
      const std::string pname = pd == std::string::npos ? path : path.substr(pd + 1);
      if (pname == name && (table.empty() ? ptable.empty() : matches(table, ptable))) {
        seen.insert(texts.begin(), texts.end());
      }
    }
    if (seen.empty()) {
      continue;  // the parser computes this default itself (or reads the key without one)
    }
    ++checked;
    const bool found = std::any_of(seen.begin(), seen.end(),
                                   [&](const std::string& t) { return same_default(literal, t); });
    std::string list;
    for (const auto& t : seen) list += (list.empty() ? "" : ", ") + t;
    EXPECT_TRUE(found) << "nccompd.toml(5) says " << doc_key << " defaults to " << literal
                       << "; the parser's default: " << list;
  }
  EXPECT_GT(checked, 80U) << "too few documented defaults could be compared";
}

}  // namespace
