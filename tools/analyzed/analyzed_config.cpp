#include "tools/analyzed/analyzed_config.hpp"

#include <filesystem>

#include "formats/toml/guard.hpp"
#include "formats/toml/table_reader.hpp"

namespace nccomp::tools::analyzed {

namespace {

std::string resolve(const std::string& base, const std::string& p) {
  if (p.empty() || p.front() == '/') return p;
  return (std::filesystem::path(base) / p).lexically_normal().string();
}

}  // namespace

std::optional<AnalyzedConfig> load_analyzed_config(const std::string& path,
                                                   nccomp::formats::Diagnostics& diag) {
  toml::table root;
  try {
    root = formats::parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    diag.append(nccomp::formats::DiagnosticsError(e, path).diagnostics(), path);
    return std::nullopt;
  }
  const std::string base = std::filesystem::absolute(path).parent_path().string();
  for (auto&& [k, v] : root) {
    const std::string_view key = k.str();
    if (key != "source" && key != "analysis" && key != "output" && key != "daemon") {
      diag.error(&v, std::string(key), "unknown section (known: source, analysis, output, daemon)");
    } else if (!v.is_table()) {
      diag.error(&v, std::string(key), "expected a table ([" + std::string(key) + "])");
    }
  }
  if (root.get("analysis") == nullptr) {
    diag.error(nccomp::formats::Where{path, 1, 1, "analysis"}, "required section is missing");
    return std::nullopt;
  }
  const toml::table empty;
  auto section = [&](const char* name) -> const toml::table& {
    const toml::table* t = root.get_as<toml::table>(name);
    return t != nullptr ? *t : empty;
  };
  AnalyzedConfig c;
  {
    nccomp::formats::TableReader r(section("source"), "source", diag);
    c.log_directory = resolve(base, r.string("log_directory", c.log_directory));
    c.poll_interval_s = r.number("poll_interval_s", c.poll_interval_s, 0.05, 3600.0);
    r.finish();
  }
  {
    nccomp::formats::TableReader r(section("analysis"), "analysis", diag);
    c.analysis_config = resolve(base, r.string("config", std::nullopt));
    c.min_new_rows = r.integer("min_new_rows", c.min_new_rows, 10, 10'000'000);
    c.max_rows = r.integer("max_rows", c.max_rows, 10, 10'000'000);
    c.min_improvement_um = r.number("min_improvement_um", c.min_improvement_um, 0.0, 1000.0);
    if (c.max_rows < c.min_new_rows) {
      diag.error(r.where("max_rows"), "must be at least min_new_rows (" +
                                          std::to_string(c.min_new_rows) + "), got " +
                                          std::to_string(c.max_rows));
    }
    r.finish();
  }
  {
    nccomp::formats::TableReader r(section("output"), "output", diag);
    c.work_directory = resolve(base, r.string("directory", c.work_directory));
    c.keep_runs = r.integer("keep_runs", c.keep_runs, 0, 1'000'000);
    r.finish();
  }
  {
    nccomp::formats::TableReader r(section("daemon"), "daemon", diag);
    c.status_socket = resolve(base, r.string("status_socket", c.status_socket));
    c.submit = r.boolean("submit", c.submit);
    for (const std::int64_t cpu : r.integer_list("avoid_cpus", 0, 1023)) {
      c.avoid_cpus.push_back(static_cast<int>(cpu));
    }
    r.finish();
  }
  if (!diag.ok()) return std::nullopt;
  return c;
}

}  // namespace nccomp::tools::analyzed
