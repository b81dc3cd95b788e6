// Files of the compensation model (formats/model, in nccomp_formats: read and written by
// `nccomp analyze`, model.toml loaded by the daemon's [model] section):
//   - the `[model]` TOML table: declared terms, search options, fitted coefficients;
//   - the measurement log CSV (architecture.md, v1) and foreign CSVs through a column mapping.
// Every reader validates its input and throws formats::DiagnosticsError: file:line:column and key
// path for the TOML files, with every error of the file; file:row:field (1-based) and the column
// name for a CSV, at its first bad row. Nothing here is real-time: these run when configuring,
// never in the loop.
#pragma once

#include <istream>
#include <string>
#include <string_view>
#include <vector>

#include <toml++/toml.h>

#include "core/model/analysis.hpp"
#include "core/model/model.hpp"
#include "formats/toml/diagnostics.hpp"

namespace nccomp::formats::model_io {

/// The `[model]` table of an analysis config or of a fitted model file.
struct ModelFile {
  /// Extra (non-standard) columns the terms or the search refer to, in Row order.
  std::vector<std::string> extra_columns;
  core::model::AnalysisConfig config;
  /// Terms with coefficients (present in a fitted model file); empty in a config.
  std::vector<core::model::Term> fitted_terms;
};

/// Parses `[model]` of `root`. `source` names the file in errors (every error of the table, in
/// one DiagnosticsError). With require_fitted, every term must carry `groups` and `coef_um` (a
/// file the daemon loads).
ModelFile read_model_table(const toml::table& root, std::string_view source, bool require_fitted);

/// Parses TOML text and its `[model]` table (errors carry line and column).
ModelFile read_model_text(std::string_view text, std::string_view source, bool require_fitted);

/// Loads a fitted model file (model.toml written by `nccomp analyze`) into an evaluable Model.
core::model::Model load_model_file(const std::string& path);

/// The fitted model as a `[model]` TOML document, loadable by load_model_file() and usable as
/// the config of a further analysis. `header` lines are written as comments on top.
std::string write_model_toml(const core::model::Model& model,
                             const core::model::AnalysisConfig& config,
                             const std::vector<std::string>& header);

/// How a foreign CSV's columns become measurement-log columns (item 6 of issue 11).
struct Mapping {
  /// Standard column name (or "measured_um", "applied_um") → source header.
  std::vector<std::pair<std::string, std::string>> columns;
  /// Extra column name → source header.
  std::vector<std::pair<std::string, std::string>> extra;
  /// Multiplier applied after reading, per target column (standard, measured/applied, extra).
  std::vector<std::pair<std::string, double>> scale;
  /// Columns with one value for the whole file (kind as text, or numbers).
  std::vector<std::pair<std::string, double>> constant;
  /// Wide files: one measurement row per listed header, point = the matching `wide_points`.
  std::vector<std::string> wide_measured;
  std::vector<double> wide_points;
  /// Column → is a temperature (`[column_kind]`: how a linear effect in it is named).
  std::vector<std::pair<std::string, bool>> column_kind;
  /// `[ids]`: a column whose cells are text ids (a tool "T12", a cutter "c4") turned into group
  /// numbers, by a table of texts or by the digits of the text.
  struct TextIds {
    std::string column;
    /// The number is the one digit run of the text ("T12" → 12); else `table`.
    bool digits{false};
    std::vector<std::pair<std::string, double>> table;
  };
  std::vector<TextIds> ids;
  /// `[restarts]`: the one counter column whose restart starts a new run (session); empty if
  /// none. per_file: at each file; otherwise when it decreases.
  std::string restart_column;
  bool restart_per_file{false};
  /// Rows of the header (`header_rows`) and the one (1-based) holding the column names.
  int header_rows{1};
  int names_row{1};
  /// The file's field separator (`separator`: ',', ';' or a tab) and decimal mark (`decimal`:
  /// '.' or ','): a spreadsheet saved in a German or French locale writes `1,5;20,3`.
  char separator{','};
  char decimal{'.'};
  bool empty() const { return columns.empty() && extra.empty() && constant.empty(); }
};

/// Parses a mapping file's TOML text.
Mapping read_mapping_text(std::string_view text, std::string_view source);
Mapping read_mapping_file(const std::string& path);

/// Reads a CSV (the v1 or v2 log when `mapping` is empty, else mapped) and appends its rows to
/// `data`. In a v2 log (machine, utc and session columns) time_s restarts with each session.
/// Only the extra columns named in data.extra_columns are kept. `source` names the stream in
/// errors ("file:line:field: column: …").
void read_log(std::istream& in, std::string_view source, const Mapping& mapping,
              core::model::Dataset& data);

/// read_log() of the file at `path` (named `path` in errors). A path that cannot be opened, or
/// that is a directory (nccompd's log directory rather than its measurements.csv), is an error
/// naming the path.
void read_log_file(const std::string& path, const Mapping& mapping, core::model::Dataset& data);

/// Measurement kind from its log name (tool_wear / contour / calib); -1 if unknown.
int kind_from_name(std::string_view name) noexcept;

}  // namespace nccomp::formats::model_io
