#include "daemon/config/config.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <utility>

#include "formats/toml/guard.hpp"

namespace nccomp::daemon::config {

using formats::Diagnostics;
using formats::Where;
using formats::where_of;

void register_builtin_sections();  // builtin_sections.cpp

namespace fs = std::filesystem;

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
      diag.error(inc, "include", "must be an array of file names");
      return;
    }
    for (std::size_t i = 0; i < arr->size(); ++i) {
      const toml::node& e = *arr->get(i);
      const std::string key = "include[" + std::to_string(i) + "]";
      const auto* s = e.as_string();
      if (s == nullptr || s->get().empty()) {
        diag.error(&e, key, "must be a file name");
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
