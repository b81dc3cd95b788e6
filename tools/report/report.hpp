// `nccomp report`: figures of a machined result (an ncsim result directory, contract C3).
//
// Everything is computed from the CSVs; result.json only supplies the run's description. The
// figures an operator judges a compensation by:
//   - step: the largest |Δ error_um| between neighbouring samples of one pass (a wear correction
//     applied at once cuts a step of its full height into the surface; a creeping one leaves
//     about h·Δs/L), and separately the largest change of the offset in force, within a pass and
//     from one pass to the next;
//   - the step between neighbouring passes at the same position along the pass (a correction
//     applied between passes shows there);
//   - form error: RMS and maximum of |error_um| over the surface or the walls;
//   - per checkpoint (side_wall): the wall error after machining, part after part;
//   - touches (touch): per probe / axis / direction / variant, how the triggers moved and how
//     well they followed the true drift.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "tools/report/result_io.hpp"

namespace nccomp::tools::report {

/// A figure and where it occurred. `group` is the pass (surface) or part (walls); `position_mm`
/// the path / contour position; `line` the CSV line of the sample.
struct Located {
  double value_um{0.0};
  long long group{-1};
  double position_mm{0.0};
  std::size_t line{0};
};

struct FormError {
  std::size_t samples{0};
  double mean_um{0.0};
  double rms_um{0.0};
  /// Largest |error_um| (value_um keeps its sign).
  Located max_abs;
};

struct SurfaceFigures {
  std::size_t passes{0};
  FormError form;
  /// Largest |Δ error_um| between neighbouring samples of one pass (sorted by path_mm).
  Located max_step;
  /// Largest |Δ error_um| between a sample and the previous pass interpolated at the same
  /// position along the pass (the axis x/y/z that varies most within a pass).
  Located max_step_between_passes;
  /// Largest |Δ offset_um| between neighbouring samples of one pass.
  Located max_offset_step;
  /// Largest |Δ offset_um| from the last sample of a pass to the first of the next.
  Located max_offset_jump_between_passes;
  /// The coordinate used along a pass: "x_mm", "y_mm" or "z_mm" (empty with one pass).
  std::string along;
};

/// Figures of surface.csv (mould_face, roll). Throws ReportInputError on an empty table.
SurfaceFigures analyze_surface(const CsvTable& surface);

struct PartForm {
  long long part{0};
  FormError form;
};

struct WallFigures {
  std::size_t parts{0};
  std::size_t layers{0};
  FormError form;
  /// Largest |Δ error_um| between neighbouring samples of one (part, layer), sorted by s_mm.
  Located max_step;
  Located max_offset_step;
  std::vector<PartForm> per_part;
};

/// Figures of walls.csv (side_wall). Throws ReportInputError on an empty table.
WallFigures analyze_walls(const CsvTable& walls);

struct CheckpointFigures {
  long long checkpoint{0};
  long long layer{0};
  double z_mm{0.0};
  double s_mm{0.0};
  std::size_t parts{0};
  long long first_part{0};
  long long last_part{0};
  double first_error_um{0.0};
  double last_error_um{0.0};
  double max_abs_error_um{0.0};
  double rms_error_um{0.0};
  /// RMS of probed_um − error_um: what the probe got wrong.
  double probe_rms_um{0.0};
};

/// Per checkpoint of checkpoints.csv, ordered by checkpoint id.
std::vector<CheckpointFigures> analyze_checkpoints(const CsvTable& checkpoints);

struct TouchGroup {
  long long probe{0};
  long long axis{0};
  long long direction{0};
  long long variant{0};
  std::size_t touches{0};
  double trigger_mean_mm{0.0};
  /// max − min of the trigger positions [µm].
  double trigger_spread_um{0.0};
  double drift_first_um{0.0};
  double drift_last_um{0.0};
  /// RMS of (trigger − first trigger) − (true drift − first true drift) [µm]: how far the
  /// touches miss the drift they are meant to measure (noise and unmodelled effects).
  double tracking_rms_um{0.0};
};

/// Per (probe, axis, direction, variant) of touches.csv.
std::vector<TouchGroup> analyze_touches(const CsvTable& touches);

struct RegisterWrites {
  long long register_index{0};
  std::size_t writes{0};
  double first_value_um{0.0};
  double last_value_um{0.0};
  double min_value_um{0.0};
  double max_value_um{0.0};
  /// Largest |Δ value_um| between successive writes of this register.
  double max_change_um{0.0};
  /// Mean of effective_t_s − t_s [s].
  double mean_latency_s{0.0};
};

/// Per register of writes.csv.
std::vector<RegisterWrites> analyze_writes(const CsvTable& writes);

struct FileRows {
  std::string file;
  std::size_t rows{0};
  std::size_t bad_rows{0};
};

/// The whole report of one result directory.
struct Report {
  std::string dir;
  ResultInfo info;
  std::optional<SurfaceFigures> surface;
  std::optional<WallFigures> walls;
  std::vector<CheckpointFigures> checkpoints;
  std::vector<TouchGroup> touches;
  std::vector<RegisterWrites> writes;
  std::vector<FileRows> files;
  std::size_t bad_rows{0};
  /// The first few bad rows of every file, "file:line: what".
  std::vector<std::string> bad_row_messages;
};

/// The tables a report was computed from (kept for plotting).
struct ResultTables {
  std::optional<CsvTable> surface;
  std::optional<CsvTable> walls;
  std::optional<CsvTable> checkpoints;
  std::optional<CsvTable> touches;
  std::optional<CsvTable> writes;
};

/// Reads and analyses DIR (result.json and the CSVs the program needs; writes.csv when present
/// or listed). Throws ReportInputError naming the file.
Report load_report(const std::string& dir, ResultTables* tables = nullptr);

/// The operator's text.
std::string report_text(const Report& r);
/// The same as one JSON object (keys documented in docs/report.md).
std::string report_json(const Report& r);

/// An SVG plot: error_um against path_mm (surface: one line per pass, light → dark in cut
/// order) or against s_mm (walls: one line per part and layer), the offset in force dashed on a
/// second axis. Throws ReportInputError when the tables hold nothing to plot.
std::string plot_svg(const Report& r, const ResultTables& t);

}  // namespace nccomp::tools::report
