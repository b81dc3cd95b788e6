#include "daemon/config/config.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "formats/toml_guard.hpp"

namespace nccomp::daemon::config {

void register_builtin_sections();  // builtin_sections.cpp

namespace fs = std::filesystem;

std::string format(const Diagnostic& d) {
  std::ostringstream s;
  s << (d.where.file.empty() ? "<config>" : d.where.file);
  if (d.where.line > 0) {
    s << ':' << d.where.line << ':' << d.where.column;
  }
  s << ": ";
  if (!d.where.key_path.empty()) {
    s << d.where.key_path << ": ";
  }
  s << d.message;
  return s.str();
}

void Diagnostics::error(Where where, std::string message) {
  items_.push_back(Diagnostic{std::move(where), std::move(message)});
}

void Diagnostics::error(const toml::node* node, std::string key_path, std::string message) {
  error(where_of(node, std::move(key_path)), std::move(message));
}

std::string Diagnostics::to_string() const {
  std::string out;
  for (const auto& d : items_) {
    out += format(d);
    out += '\n';
  }
  return out;
}

Where where_of(const toml::node* node, std::string key_path) {
  Where w;
  w.key_path = std::move(key_path);
  if (node != nullptr) {
    const auto& src = node->source();
    if (src.path) {
      w.file = *src.path;
    }
    w.line = static_cast<int>(src.begin.line);
    w.column = static_cast<int>(src.begin.column);
  }
  return w;
}

// ------------------------------------------------------------------------------------------
// TableReader

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

namespace {
void (*g_key_observer)(const std::string&) = nullptr;
}  // namespace

void TableReader::set_key_observer(void (*observer)(const std::string&)) noexcept {
  g_key_observer = observer;
}

const toml::node* TableReader::get(std::string_view key) {
  known_.insert(std::string(key));
  if (g_key_observer != nullptr) {
    g_key_observer(path(key));
  }
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

// ------------------------------------------------------------------------------------------
// Registry

namespace {
struct Registry {
  std::vector<std::unique_ptr<SectionParser>> parsers;
};

Registry& registry_storage() {
  static Registry r;
  return r;
}

Registry& registry() {
  // Built-in sections are registered on first use, after any static registrations began: the
  // order of static initialisation across files does not matter.
  static const bool builtins = [] {
    register_builtin_sections();
    return true;
  }();
  (void)builtins;
  return registry_storage();
}
}  // namespace

int register_section(std::unique_ptr<SectionParser> parser) {
  if (!parser) {
    throw std::invalid_argument("register_section: null parser");
  }
  auto& r = registry_storage();
  for (const auto& p : r.parsers) {
    if (p->name() == parser->name()) {
      throw std::logic_error("config section '" + std::string(parser->name()) +
                             "' registered twice");
    }
  }
  r.parsers.push_back(std::move(parser));
  return 0;
}

std::vector<const SectionParser*> section_parsers() {
  std::vector<const SectionParser*> out;
  for (const auto& p : registry().parsers) {
    out.push_back(p.get());
  }
  std::sort(out.begin(), out.end(),
            [](const SectionParser* a, const SectionParser* b) { return a->name() < b->name(); });
  return out;
}

const SectionParser* find_section_parser(std::string_view name) {
  for (const auto& p : registry().parsers) {
    if (p->name() == name) {
      return p.get();
    }
  }
  return nullptr;
}

// ------------------------------------------------------------------------------------------
// Config

bool Config::has(std::string_view section) const { return sections_.count(section) > 0; }

std::vector<std::string> Config::section_names() const {
  std::vector<std::string> out;
  for (const auto& [k, v] : sections_) {
    out.push_back(k);
  }
  return out;
}

std::string Config::resolve(const std::string& path) const {
  if (path.empty() || fs::path(path).is_absolute()) {
    return path;
  }
  return (fs::path(base_dir_) / path).lexically_normal().string();
}

void Config::set_section(std::string name, std::unique_ptr<Section> section) {
  sections_[std::move(name)] = std::move(section);
}

// ------------------------------------------------------------------------------------------
// Loader

namespace {

constexpr int kMaxIncludeDepth = 8;

struct Loaded {
  std::string path;
  toml::table table;
};

struct Loader {
  Diagnostics diag;
  std::vector<std::unique_ptr<Loaded>> docs;
  std::set<std::string> open_files;  // for cycle detection

  void report_parse_error(const toml::parse_error& e, const std::string& name) {
    Where w;
    w.file = e.source().path ? *e.source().path : name;
    w.line = static_cast<int>(e.source().begin.line);
    w.column = static_cast<int>(e.source().begin.column);
    diag.error(std::move(w), "TOML syntax error: " + std::string(e.description()));
  }

  void add(toml::table table, const std::string& path, const std::string& base_dir, int depth) {
    auto doc = std::make_unique<Loaded>(Loaded{path, std::move(table)});
    Loaded* d = doc.get();
    docs.push_back(std::move(doc));
    const toml::node* inc = d->table.get("include");
    if (inc == nullptr) {
      return;
    }
    const auto* arr = inc->as_array();
    if (arr == nullptr) {
      diag.error(inc, "include", "expected an array of file names");
      return;
    }
    for (std::size_t i = 0; i < arr->size(); ++i) {
      const toml::node& e = *arr->get(i);
      const std::string key = "include[" + std::to_string(i) + "]";
      const auto* s = e.as_string();
      if (s == nullptr || s->get().empty()) {
        diag.error(&e, key, "expected a file name");
        continue;
      }
      fs::path p(s->get());
      if (p.is_relative()) {
        p = fs::path(base_dir) / p;
      }
      if (depth + 1 > kMaxIncludeDepth) {
        diag.error(&e, key, "includes nested deeper than 8 files");
        continue;
      }
      load(p.lexically_normal().string(), &e, key, depth + 1);
    }
  }

  void load(const std::string& path, const toml::node* from, const std::string& key, int depth) {
    std::error_code ec;
    const fs::path canon = fs::weakly_canonical(path, ec);
    const std::string id = ec ? path : canon.string();
    if (open_files.count(id) > 0) {
      diag.error(from, key, "'" + path + "' is included twice (or includes itself)");
      return;
    }
    // The reason as the system gives it: a configuration the service's user may not read must
    // say "Permission denied", not look like a missing file.
    std::string why;
    struct stat sb {};
    if (::stat(path.c_str(), &sb) != 0) {
      why = std::strerror(errno);
    } else if (!S_ISREG(sb.st_mode)) {
      why = "not a regular file";
    } else if (const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC); fd < 0) {
      why = std::strerror(errno);
    } else {
      ::close(fd);
    }
    if (!why.empty()) {
      Where w = from != nullptr ? where_of(from, key) : Where{path, 0, 0, ""};
      diag.error(std::move(w), "cannot read '" + path + "': " + why);
      return;
    }
    open_files.insert(id);
    try {
      toml::table t = formats::parse_toml_file(path);
      add(std::move(t), path, fs::path(path).parent_path().string(), depth);
    } catch (const toml::parse_error& e) {
      report_parse_error(e, path);
    }
  }

  // Moves the content of `from` (a later file) into `into` (the first file that defines the
  // same key path). Tables merge recursively; arrays of tables below the top level are appended
  // (e.g. one [[creep.deflection]] table file per tool); anything else defined twice is an error.
  // Moved nodes keep their source position, so later errors still name the file they came from.
  void merge(toml::node& into, toml::node& from, const std::string& path, bool top_level) {
    auto* a = into.as_table();
    auto* b = from.as_table();
    if (a != nullptr && b != nullptr && !a->is_inline() && !b->is_inline()) {
      for (auto&& [k, v] : *b) {
        const std::string key(k.str());
        const std::string sub = path + "." + key;
        if (toml::node* existing = a->get(key)) {
          merge(*existing, v, sub, false);
        } else {
          a->insert(toml::key(k), std::move(v));
        }
      }
      return;
    }
    auto* x = into.as_array();
    auto* y = from.as_array();
    if (!top_level && x != nullptr && y != nullptr && x->is_array_of_tables() &&
        y->is_array_of_tables()) {
      for (auto&& e : *y) {
        x->push_back(std::move(e));
      }
      return;
    }
    const Where first = where_of(&into, path);
    diag.error(&from, path,
               std::string(top_level ? "section" : "key") + " is already defined at " + first.file +
                   ":" + std::to_string(first.line));
  }

  static void record_keys(Config& config, const toml::node& node, const std::string& path) {
    Config::KeyInfo info{where_of(&node, path), {}};
    if (const auto* str = node.as_string()) {
      info.value = str->get();
    } else if (const auto* i = node.as_integer()) {
      info.value = std::to_string(i->get());
    }
    config.add_key(path, std::move(info));
    if (const auto* t = node.as_table()) {
      for (const auto& [k, v] : *t) {
        record_keys(config, v, path + "." + std::string(k.str()));
      }
    } else if (const auto* a = node.as_array()) {
      for (std::size_t i = 0; i < a->size(); ++i) {
        record_keys(config, *a->get(i), path + "[" + std::to_string(i) + "]");
      }
    }
  }

  LoadResult finish(const std::string& base_dir) {
    LoadResult result;
    auto config = std::make_unique<Config>();
    config->set_base_directory(base_dir);
    for (const auto& d : docs) {
      config->add_file(d->path);
    }
    // Every top-level key → the node that holds it. A section may be split over several files:
    // its tables are merged key by key (e.g. [creep] in the main file, [[creep.deflection]] in
    // an included table file); a key defined in two files is an error naming both places.
    std::map<std::string, toml::node*> owners;
    for (const auto& d : docs) {
      for (auto&& [k, v] : d->table) {
        const std::string name(k.str());
        if (name == "include") {
          continue;
        }
        auto [it, inserted] = owners.emplace(name, &v);
        if (!inserted) {
          merge(*it->second, v, name, true);
        }
      }
    }
    for (const auto& [name, node] : owners) {
      record_keys(*config, *node, name);
    }
    for (const auto& [name, node] : owners) {
      const SectionParser* parser = find_section_parser(name);
      if (parser == nullptr) {
        std::string known;
        for (const auto* p : section_parsers()) {
          known += (known.empty() ? "" : ", ") + std::string(p->name());
        }
        diag.error(node, name, "unknown section (known sections: " + known + ")");
        continue;
      }
      try {
        config->set_section(name, parser->parse(*node, diag));
      } catch (const std::exception& e) {
        diag.error(node, name, e.what());
      }
    }
    for (const auto* parser : section_parsers()) {
      if (!config->has(parser->name())) {
        if (auto def = parser->absent()) {
          config->set_section(std::string(parser->name()), std::move(def));
        }
      }
    }
    if (diag.ok()) {
      for (const auto* parser : section_parsers()) {
        try {
          parser->cross_check(*config, diag);
        } catch (const std::exception& e) {
          diag.error(Where{"", 0, 0, std::string(parser->name())}, e.what());
        }
      }
    }
    result.diagnostics = std::move(diag);
    if (result.diagnostics.ok()) {
      result.config = std::move(config);
    }
    return result;
  }
};

}  // namespace

LoadResult load_file(const std::string& path) {
  Loader loader;
  std::error_code ec;
  fs::path abs = fs::absolute(path, ec);
  const std::string p = (ec ? fs::path(path) : abs).lexically_normal().string();
  loader.load(p, nullptr, "", 0);
  return loader.finish(fs::path(p).parent_path().string());
}

LoadResult load_string(std::string_view text, const std::string& name,
                       const std::string& base_dir) {
  Loader loader;
  try {
    toml::table t = formats::parse_toml(text, name);
    loader.open_files.insert(name);
    loader.add(std::move(t), name, base_dir, 0);
  } catch (const toml::parse_error& e) {
    loader.report_parse_error(e, name);
  }
  return loader.finish(base_dir);
}

}  // namespace nccomp::daemon::config
