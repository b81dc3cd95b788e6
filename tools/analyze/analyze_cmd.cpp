// `nccomp analyze --log LOG.csv --config CONF.toml --out DIR [--map MAP.toml]`: fits the declared
// model to the measurement log, searches the residual for the effect the model lacks, and writes
// DIR/summary.json, DIR/report.md (+ DIR/plots/*.svg) and DIR/model.toml (issue 11).
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "core/model/analysis.hpp"
#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"
#include "tools/analyze/fleet.hpp"
#include "tools/analyze/report.hpp"
#include "tools/nccomp/command.hpp"

namespace {

namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;
using nccomp::tools::CommandError;

struct Options {
  std::vector<std::string> logs;
  std::vector<std::string> maps;
  std::string config;
  std::string out = "analysis";
  std::string validate;
};

void write_file(const std::filesystem::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f << text;
  f.close();
  if (!f) throw CommandError(nccomp::tools::kExitFailure, p.string() + ": cannot write");
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw CommandError(nccomp::tools::kExitInvalidInput, path + ": cannot open");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void run(const Options& given) {
  Options opt = given;
  if (opt.maps.empty()) {
    // Logs of several machines (v2, or nccomp collect's directory): the fleet analysis.
    std::vector<nccomp::tools::analyze::MachineLogs> fleet;
    try {
      fleet = nccomp::tools::analyze::group_logs(opt.logs);
    } catch (const std::invalid_argument& e) {
      throw CommandError(nccomp::tools::kExitInvalidInput, e.what());
    }
    if (fleet.size() > 1) {
      nccomp::tools::analyze::run_fleet(fleet, opt.config, opt.out, opt.validate == "sessions");
      return;
    }
    opt.logs = fleet.empty() ? opt.logs : fleet[0].files;
  }
  if (!opt.maps.empty() && opt.maps.size() != 1 && opt.maps.size() != opt.logs.size()) {
    throw CommandError(nccomp::tools::kExitUsage,
                       "--map: give one mapping for all logs or one per --log");
  }
  if (!opt.maps.empty()) {
    // A directory of foreign CSVs: each of its files with that --log's mapping.
    std::vector<std::string> logs;
    std::vector<std::string> maps;
    for (std::size_t i = 0; i < opt.logs.size(); ++i) {
      std::vector<std::string> files;
      try {
        files = nccomp::tools::analyze::foreign_log_files(opt.logs[i]);
      } catch (const std::invalid_argument& e) {
        throw CommandError(nccomp::tools::kExitInvalidInput, e.what());
      }
      for (auto& f : files) {
        logs.push_back(std::move(f));
        maps.push_back(opt.maps[opt.maps.size() == 1 ? 0 : i]);
      }
    }
    opt.logs = std::move(logs);
    if (opt.maps.size() != 1) opt.maps = std::move(maps);
  }
  io::ModelFile cfg;
  std::vector<io::Mapping> maps;
  cm::Dataset data;
  try {
    cfg = io::read_model_text(read_text(opt.config), opt.config, false);
    for (const auto& m : opt.maps) maps.push_back(io::read_mapping_file(m));
    data.extra_columns = cfg.extra_columns;
    auto& kinds = cfg.config.search.column_is_temperature;
    for (std::size_t i = 0; i < maps.size(); ++i) {
      for (const auto& [name, temperature] : maps[i].column_kind) {
        const int c = cm::column_index(name, cfg.extra_columns);
        if (c < 0) continue;  // a column this model does not use
        bool found = false;
        for (const auto& [k, t] : kinds) {
          if (k != c) continue;
          found = true;
          if (t != temperature) {
            throw CommandError(nccomp::tools::kExitInvalidInput,
                               opt.maps[i] + ": column_kind." + name + ": declared otherwise in " +
                                   opt.config + " or another map");
          }
        }
        if (!found) kinds.emplace_back(c, temperature);
      }
    }
    for (std::size_t i = 0; i < opt.logs.size(); ++i) {
      const io::Mapping none;
      const io::Mapping& m = maps.empty() ? none : maps[maps.size() == 1 ? 0 : i];
      io::read_log_file(opt.logs[i], m, data);
    }
  } catch (const nccomp::formats::DiagnosticsError& e) {
    throw CommandError(nccomp::tools::kExitInvalidInput, e.what());
  }
  cfg.config.validate_sessions = opt.validate == "sessions";
  cm::AnalysisResult result;
  try {
    result = cm::analyze(data, cfg.config);
  } catch (const cm::AnalysisError& e) {
    throw CommandError(nccomp::tools::kExitInvalidInput, std::string("analysis: ") + e.what());
  }
  const std::filesystem::path out(opt.out);
  std::filesystem::create_directories(out / "plots");
  write_file(out / "summary.json", nccomp::tools::analyze::summary_json(data, result));
  const auto plotted = nccomp::tools::analyze::plotted_columns(data);
  for (int c : plotted) {
    const std::string name = cm::column_name(c, data.extra_columns);
    write_file(out / "plots" / ("residual_" + nccomp::tools::analyze::safe_name(name) + ".svg"),
               nccomp::tools::analyze::residual_svg(data, result, c));
  }
  std::vector<std::string> inputs = opt.logs;
  inputs.push_back(opt.config);
  for (const auto& m : opt.maps) inputs.push_back(m);
  write_file(out / "report.md",
             nccomp::tools::analyze::report_markdown(data, result, inputs, plotted));
  std::vector<std::string> header = {"Compensation model fitted by `nccomp analyze` on all " +
                                     std::to_string(data.rows()) + " rows of:"};
  for (const auto& l : opt.logs) header.push_back("  " + l);
  header.push_back("Load it in nccompd as an include; use it as --config to analyze again.");
  write_file(out / "model.toml", io::write_model_toml(result.final_model, cfg.config, header));

  std::cout << "rows: " << data.rows() << " (fitted " << result.declared.fitted.rows
            << ", held out " << result.declared.heldout.rows << ")\n";
  // No held-out rows: no held-out figure (an RMS over nothing would read as 0 µm).
  auto heldout = [](const cm::ErrorStats& e) {
    std::ostringstream o;
    if (e.rows > 0) {
      o << e.rms_um << " µm";
    } else {
      o << "n/a";
    }
    return o.str();
  };
  std::cout << "declared model: RMS " << result.declared.fitted.rms_um << " µm, held-out RMS "
            << heldout(result.declared.heldout) << "\n";
  for (const auto& e : result.effects) {
    std::cout << "added " << cm::effect_label(e.spec.name, e.spec.per, data.extra_columns) << " ("
              << cm::term_column_name(e.spec, data.extra_columns) << ", "
              << cm::form_name(e.spec.form) << "): RMS " << e.before.fitted.rms_um << " -> "
              << e.after.fitted.rms_um << " µm, held-out " << heldout(e.before.heldout) << " -> "
              << heldout(e.after.heldout) << ", p = " << e.p_value << "\n";
  }
  std::cout << "final RMS " << result.final_stats.fitted.rms_um << " µm (held-out "
            << heldout(result.final_stats.heldout) << "), noise floor " << result.noise_floor_um
            << " µm\n";
  if (!result.session_folds.empty()) {
    std::cout << "leave-one-session-out (" << result.session_folds.size()
              << " sessions): declared RMS " << result.sessions_declared.rms_um << " µm, final RMS "
              << result.sessions_final.rms_um << " µm\n";
  }
  for (const auto& w : result.warnings)
    std::cout << "warning " << w.code << ": " << w.message << "\n";
  std::cout << "wrote " << (out / "summary.json").string() << ", " << (out / "report.md").string()
            << ", " << (out / "model.toml").string() << "\n";
}

void setup(CLI::App& app) {
  auto opt = std::make_shared<Options>();
  auto* sub = app.add_subcommand(
      "analyze",
      "Fit the declared model to a measurement log, find and add the effect it lacks, report the "
      "error before and after");
  sub->add_option(
         "--log", opt->logs,
         "measurement log CSV, or a directory of them (repeat for several; logs of several "
         "machines: the fleet analysis)")
      ->required();
  sub->add_option("--config", opt->config, "TOML file with the [model] table")->required();
  sub->add_option("--map", opt->maps,
                  "column mapping TOML for a foreign CSV (one for all logs, or one per --log)");
  sub->add_option("--out", opt->out, "output directory")->capture_default_str();
  sub->add_option("--validate", opt->validate,
                  "sessions: hold each session (file, warm start, gap > session_gap_s) out in "
                  "turn and predict it from the others")
      ->check(CLI::IsMember({"sessions"}));
  sub->callback([opt] { run(*opt); });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(analyze, setup);
