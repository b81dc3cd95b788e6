// The fleet run of `nccomp analyze` (fleet.hpp): logs grouped by machine, read, analysed
// together, and the outputs written.
#include <algorithm>
#include <cctype>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "formats/measurement_log/measurement_log.hpp"
#include "formats/model/model_io.hpp"
#include "tools/analyze/fleet.hpp"
#include "tools/analyze/report.hpp"
#include "tools/nccomp/command.hpp"

namespace nccomp::tools::analyze {

namespace {

namespace cm = core::model;
namespace io = formats::model_io;
namespace fs = std::filesystem;
namespace ml = formats::measurement_log;

std::vector<std::string> split_header(const std::string& line) {
  std::vector<std::string> out(1);
  for (char c : line) {
    if (c == ',') {
      out.emplace_back();
    } else if (c != '\r' && c != '"') {
      out.back() += c;
    }
  }
  for (auto& s : out) {
    const auto b = s.find_first_not_of(" \t");
    const auto e = s.find_last_not_of(" \t");
    s = b == std::string::npos ? "" : s.substr(b, e - b + 1);
  }
  return out;
}

bool valid_machine_id(const std::string& id) {
  if (id.empty() || id.size() > 64) return false;
  if (!std::isalnum(static_cast<unsigned char>(id[0]))) return false;
  return std::all_of(id.begin(), id.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '.' || c == '_' || c == '-';
  });
}

void write_file(const fs::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f << text;
  f.close();
  if (!f) throw CommandError(kExitFailure, p.string() + ": cannot write");
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw CommandError(kExitInvalidInput, path + ": cannot open");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

std::string log_machine(const std::string& path, std::size_t* line) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::invalid_argument(path + ": cannot open");
  std::string text;
  std::size_t line_no = 0;
  std::vector<std::string> header;
  std::size_t column = 0;
  while (std::getline(in, text)) {
    ++line_no;
    if (text.find_first_not_of(" \t\r") == std::string::npos) continue;
    if (header.empty()) {
      header = split_header(text);
      const auto it = std::find(header.begin(), header.end(), "machine");
      if (it == header.end()) return "";
      column = static_cast<std::size_t>(it - header.begin());
      continue;
    }
    const std::vector<std::string> fields = split_header(text);
    if (line != nullptr) *line = line_no;
    return column < fields.size() ? fields[column] : "";
  }
  return "";
}

std::vector<std::string> foreign_log_files(const std::string& log) {
  std::error_code ec;
  if (!fs::is_directory(log, ec)) return {log};
  std::vector<std::string> files;
  for (const auto& e : fs::directory_iterator(log, ec)) {
    if (e.is_regular_file(ec) && e.path().extension() == ".csv") files.push_back(e.path().string());
  }
  if (ec) throw std::invalid_argument(log + ": cannot read the directory: " + ec.message());
  if (files.empty()) throw std::invalid_argument(log + ": no *.csv file in the directory");
  std::sort(files.begin(), files.end());
  return files;
}

std::vector<MachineLogs> group_logs(const std::vector<std::string>& logs) {
  std::vector<std::string> files;
  for (const std::string& l : logs) {
    std::error_code ec;
    if (!fs::is_directory(l, ec)) {
      files.push_back(l);
      continue;
    }
    // *.csv and nccompd's rotated files *.csv.N (N = 1 the newest): each log's rotated files
    // oldest first, then the log itself, so that its rows keep their order.
    std::vector<std::pair<std::string, std::uint64_t>> found;  // (the log's path, N; 0 = itself)
    for (const auto& e : fs::recursive_directory_iterator(l, ec)) {
      if (!e.is_regular_file()) continue;
      std::string log;
      const long n = ml::rotation_number(e.path().filename().string(), log);
      if (n >= 0) found.emplace_back((e.path().parent_path() / log).string(), n);
    }
    if (ec) throw std::invalid_argument(l + ": cannot read the directory: " + ec.message());
    if (found.empty()) throw std::invalid_argument(l + ": no *.csv file in the directory");
    std::sort(found.begin(), found.end(), [](const auto& a, const auto& b) {
      if (a.first != b.first) return a.first < b.first;
      // The log itself (0) last, its rotated files from the highest number (the oldest) down.
      if ((a.second == 0) != (b.second == 0)) return b.second == 0;
      return a.second > b.second;
    });
    for (const auto& [path, n] : found) {
      files.push_back(n == 0 ? path : path + "." + std::to_string(n));
    }
  }
  std::vector<MachineLogs> out;
  std::vector<std::string> where;  // file:line of each machine's first row
  std::vector<std::string> ids;
  for (const std::string& f : files) {
    std::size_t line = 0;
    ids.push_back(log_machine(f, &line));
    const std::string& id = ids.back();
    auto it =
        std::find_if(out.begin(), out.end(), [&](const MachineLogs& m) { return m.machine == id; });
    if (it == out.end()) {
      out.push_back({id, {}});
      where.push_back(f + ":" + std::to_string(line) + ": column 'machine': ");
      it = out.end() - 1;
    }
    it->files.push_back(f);
  }
  const auto named = std::count_if(out.begin(), out.end(),
                                   [](const MachineLogs& m) { return !m.machine.empty(); });
  if (named <= 1) {
    // One machine (its v1 logs among them, in the order given): no fleet.
    std::string id;
    for (const auto& m : out) id = m.machine.empty() ? id : m.machine;
    return {{id, files}};
  }
  if (out.size() > 1) {
    for (std::size_t i = 0; i < out.size(); ++i) {
      const MachineLogs& m = out[i];
      if (m.machine.empty()) {
        throw std::invalid_argument(
            m.files[0] + ": no machine column (a v1 log, or no rows) among the logs of " +
            std::to_string(out.size() - 1) +
            " machines: a fleet analysis reads v2 logs (nccompd's "
            "measurement log, nccomp collect)");
      }
      // The id names the machine's model file.
      if (!valid_machine_id(m.machine)) {
        throw std::invalid_argument(
            where[i] + "'" + m.machine +
            "' is not a machine id (1-64 of A-Z a-z 0-9 . _ -, starting with "
            "a letter or digit)");
      }
      if (m.machine == "type") {
        throw std::invalid_argument(
            where[i] +
            "'type' is reserved in a fleet analysis (model-type.toml is the "
            "type's prior)");
      }
    }
  }
  return out;
}

void run_fleet(const std::vector<MachineLogs>& fleet, const std::string& config_path,
               const std::string& out_dir, bool validate_sessions) {
  io::ModelFile cfg;
  std::vector<cm::FleetMachine> machines;
  try {
    cfg = io::read_model_text(read_text(config_path), config_path, false);
    for (const MachineLogs& m : fleet) {
      cm::FleetMachine fm;
      fm.id = m.machine;
      fm.data.extra_columns = cfg.extra_columns;
      for (const std::string& f : m.files) {
        io::read_log_file(f, io::Mapping{}, fm.data);
      }
      machines.push_back(std::move(fm));
    }
  } catch (const std::invalid_argument& e) {
    throw CommandError(kExitInvalidInput, e.what());
  }
  cfg.config.validate_sessions = validate_sessions;
  cm::FleetResult result;
  try {
    result = cm::analyze_fleet(machines, cfg.config);
  } catch (const cm::AnalysisError& e) {
    throw CommandError(kExitInvalidInput, std::string("fleet analysis: ") + e.what());
  }
  const fs::path out(out_dir);
  fs::create_directories(out);
  std::vector<std::pair<std::string, std::string>> models;
  for (std::size_t m = 0; m < machines.size(); ++m) {
    const std::string name = "model-" + machines[m].id + ".toml";
    std::vector<std::string> header = {
        "Compensation model of machine " + machines[m].id +
        ", fitted by `nccomp analyze` over a "
        "fleet of " +
        std::to_string(machines.size()) +
        " machines: its declared and common "
        "effects shrunk toward the type (BLUP), its own effects as measured on it. Logs:"};
    for (const auto& f : fleet[m].files) header.push_back("  " + f);
    header.push_back("Load it in nccompd as an include.");
    write_file(out / name, io::write_model_toml(result.machine_models[m], cfg.config, header));
    models.emplace_back(machines[m].id, name);
    // The machine's own search, with its figures, as a single-machine run writes them.
    const fs::path dir = out / "machines" / machines[m].id;
    fs::create_directories(dir / "plots");
    const cm::Dataset& data = machines[m].data;
    const cm::AnalysisResult& search = result.searches[m];
    write_file(dir / "summary.json", summary_json(data, search));
    const auto plotted = plotted_columns(data);
    for (int c : plotted) {
      write_file(dir / "plots" /
                     ("residual_" + safe_name(cm::column_name(c, data.extra_columns)) + ".svg"),
                 residual_svg(data, search, c));
    }
    std::vector<std::string> inputs = fleet[m].files;
    inputs.push_back(config_path);
    write_file(dir / "report.md", report_markdown(data, search, inputs, plotted));
  }
  write_file(
      out / "model-type.toml",
      io::write_model_toml(
          result.type_model, cfg.config,
          {"Prior model of the machine type: the declared and common effects at the type "
           "mean over " +
               std::to_string(machines.size()) + " machines (nccomp analyze, fleet analysis).",
           "For a machine of this type without data of its own; load it in nccompd as an "
           "include."}));
  models.emplace_back("type", "model-type.toml");
  write_file(out / "summary.json", fleet_summary_json(result, cfg.extra_columns, models));
  write_file(out / "report.md",
             fleet_report_markdown(result, cfg.extra_columns, fleet, config_path));

  std::cout << "fleet of " << machines.size() << " machines (each and the pooled rows searched at "
            << "alpha " << result.machine_alpha
            << (result.pooled_searched ? "" : "; the pooled search skipped") << ")\n";
  for (const cm::FleetTerm& t : result.terms) {
    if (t.role == cm::FleetRole::kDeclared) continue;
    std::cout << cm::fleet_role_name(t.role) << ": "
              << cm::effect_label(t.spec.name, t.spec.per, cfg.extra_columns) << " ("
              << cm::term_column_name(t.spec, cfg.extra_columns) << ", "
              << cm::form_name(t.spec.form) << ")";
    if (t.role == cm::FleetRole::kMachine) std::cout << " of " << result.machines[t.owner];
    if (t.pooled) std::cout << ", found pooled";
    std::cout << ", significant on";
    for (std::size_t m = 0; m < t.significant.size(); ++m) {
      if (t.significant[m] != 0U) std::cout << " " << result.machines[m];
    }
    std::cout << "\n";
  }
  for (std::size_t m = 0; m < machines.size(); ++m) {
    std::cout << machines[m].id << ": RMS " << result.fits[m].own.rms_um << " µm with its model, "
              << result.fits[m].type.rms_um << " µm with the type's (" << result.fits[m].own.rows
              << " rows)\n";
  }
  for (const auto& w : result.warnings) {
    std::cout << "warning " << w.code << ": " << w.message << "\n";
  }
  std::cout << "wrote " << (out / "summary.json").string() << ", " << (out / "report.md").string()
            << ", " << models.size() << " models\n";
}

}  // namespace nccomp::tools::analyze
