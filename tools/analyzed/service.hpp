// nccomp-analyzed's work (docs/analyzed.md): follows nccompd's rotating measurement log
// (tools/mqtt LogSource: complete rows only, rotation, a cursor that survives a restart), keeps the
// rows it took in the work directory, and when min_new_rows new rows have come in runs the
// analysis of `nccomp analyze` on the latest max_rows of them, writes the run's folder
// (measurements.csv, summary.json, report.md, plots/, model.toml, decision.json) and hands the
// model to the daemon as a candidate (`model candidate PATH`, as `nccomp model candidate`) when
// it predicts the analysed rows better than the live model by min_improvement_um.
//
// Crash safety: rows are appended to rows.csv and fsynced before the state file (cursor, the
// length of rows.csv it covers, counters) is replaced atomically; at start rows.csv is cut back to
// the length the state names, so rows taken after the last state are read again, once.
// Not real-time; single-threaded.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "tools/analyzed/analyzed_config.hpp"
#include "tools/mqtt/log_source.hpp"

namespace nccomp::tools::analyzed {

/// What survives a restart (work_directory/state).
struct ServiceState {
  mqtt::LogCursor cursor;
  /// Bytes of rows.csv (header included) that hold the rows taken.
  std::uint64_t rows_bytes{0};
  std::uint64_t rows_total{0};
  /// rows_total when the last run started.
  std::uint64_t rows_at_last_run{0};
  std::uint64_t runs{0};
  std::uint64_t submitted{0};
  /// Rows or files of the log skipped (malformed, not v2, rotated away unread).
  std::uint64_t rows_skipped{0};
  /// FNV-1a of the last submitted model's terms (0: none).
  std::uint64_t last_submitted_hash{0};

  [[nodiscard]] std::string to_text() const;
  /// Throws std::invalid_argument naming what is wrong.
  static ServiceState parse(const std::string& text);
};

/// The figures of one run and what was done with its model.
struct RunOutcome {
  std::string directory;
  std::size_t rows{0};
  bool analysed{false};
  /// RMS error [µm] on the analysed rows: the live model's (as it is; known once the daemon
  /// named it and it could be evaluated on these rows), the new model's.
  bool live_known{false};
  double live_rms_um{0.0};
  double new_rms_um{0.0};
  std::size_t effects_added{0};
  /// submitted, written (not submitted: why in reason), refused, failed.
  std::string decision;
  std::string reason;
};

struct ServiceDeps {
  /// One request to the daemon's status socket (client::query); throws when it is away.
  std::function<std::string(std::string_view request)> query;
  /// One journal line: level ("info", "warning", "error") and text.
  std::function<void(std::string_view level, const std::string& line)> log;
};

class Service {
 public:
  /// Reads (or starts) the state in config.work_directory. Throws std::runtime_error when the
  /// work directory cannot be made or written.
  Service(AnalyzedConfig config, ServiceDeps deps);

  /// Takes the new complete rows of the log and, if enough came in, runs the analysis. Never
  /// throws for the log's content, the analysis or the daemon: each is logged and counted.
  void poll();

  [[nodiscard]] const ServiceState& state() const noexcept { return state_; }
  /// Runs that could not analyse (too few rows, a row the analysis refuses, a bad config).
  [[nodiscard]] std::uint64_t failed_runs() const noexcept { return failed_runs_; }
  /// Candidates the daemon refused or could not be asked (it is away).
  [[nodiscard]] std::uint64_t submit_errors() const noexcept { return submit_errors_; }
  /// The latest runs (up to 100), oldest first.
  [[nodiscard]] const std::vector<RunOutcome>& outcomes() const noexcept { return outcomes_; }
  /// The rows taken so far (rows.csv), header first.
  [[nodiscard]] std::string rows_path() const;

 private:
  /// Rows taken from the log in one batch (saved with the state), or kBatchFailed.
  std::size_t take_batch();
  void take_rows(std::vector<mqtt::LogRow>& rows);
  void save_state();
  /// rows.csv cut back to the length the state names, its header read again.
  void cut_back_rows();
  RunOutcome run();
  void prune_runs();

  AnalyzedConfig config_;
  ServiceDeps deps_;
  mqtt::LogSource source_;
  ServiceState state_;
  std::vector<std::string> header_;
  std::uint64_t failed_runs_{0};
  std::uint64_t submit_errors_{0};
  std::vector<RunOutcome> outcomes_;
};

}  // namespace nccomp::tools::analyzed
