// The configuration of nccomp-analyzed (config/nccomp-analyzed.toml, docs/analyzed.md). TOML read
// with formats/ TableReader: every error names file:line:column and key path, unknown keys and
// sections are refused. Relative paths are taken from the file's directory.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "formats/toml/diagnostics.hpp"

namespace nccomp::tools::analyzed {

struct AnalyzedConfig {
  /// nccompd's [measurement_log] directory (measurements.csv and its rotated files).
  std::string log_directory{"/var/log/nccompd"};
  /// How often the log is looked at [s].
  double poll_interval_s{5.0};
  /// The [model] the analysis fits (what `nccomp analyze --config` takes).
  std::string analysis_config;
  /// New rows since the last run that start the next one.
  std::int64_t min_new_rows{200};
  /// The latest rows an analysis uses (older ones are dropped from the work directory).
  std::int64_t max_rows{100'000};
  /// How much lower the new model's RMS error on the analysed rows must be than the live
  /// model's for it to be a candidate [µm].
  double min_improvement_um{0.5};
  /// State, the rows taken, and one folder per run.
  std::string work_directory{"/var/lib/nccomp-analyzed"};
  /// Run folders kept (older ones are removed; 0 = all kept).
  std::int64_t keep_runs{20};
  std::string status_socket{"/run/nccompd/status.sock"};
  /// false: the model is written, never handed to the daemon.
  bool submit{true};
  /// CPUs this process never runs on (the loop's CPU of nccompd's [daemon.realtime]).
  std::vector<int> avoid_cpus;
};

/// Reads and validates the file; nullopt with every error in diag.
[[nodiscard]] std::optional<AnalyzedConfig> load_analyzed_config(
    const std::string& path, nccomp::formats::Diagnostics& diag);

}  // namespace nccomp::tools::analyzed
