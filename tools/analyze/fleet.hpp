// `nccomp analyze` over several machines' logs (issue 23): which machine a log belongs to, the
// fleet run, and its outputs (summary.json and report.md with a fleet section, one model per
// machine, the type's prior model).
#pragma once

#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include "core/model/fleet.hpp"

namespace nccomp::tools::analyze {

/// The logs of one machine, oldest first.
struct MachineLogs {
  std::string machine;  // "" for a log without a machine column (v1)
  std::vector<std::string> files;
};

/// The `machine` of a v2 log: the cell of its first row, whose line goes to `line` ("" for a
/// v1 log or a log without rows). Throws std::invalid_argument when unreadable.
std::string log_machine(const std::string& path, std::size_t* line = nullptr);

/// `--log` arguments, a directory standing for the *.csv files under it (sorted by path),
/// grouped by their machine in order of first appearance; one group of all files, in the
/// order given, when they name at most one machine (v1 logs among them). Throws
/// std::invalid_argument (file:line) when the logs name more than one machine and one has none, an
/// id that is not 1–64 of A-Z a-z 0-9 . _ - starting with a letter or digit (it names a file), or
/// "type".
std::vector<MachineLogs> group_logs(const std::vector<std::string>& logs);

/// A foreign log's `--log` argument (read with a --map): a directory stands for its *.csv files
/// in name order (day01.csv, day02.csv, ...); a file is returned as given. Throws
/// std::invalid_argument for a directory without *.csv files or one that cannot be read.
std::vector<std::string> foreign_log_files(const std::string& log);

/// The fleet run: reads each machine's logs, analyze_fleet(), writes DIR/summary.json,
/// DIR/report.md, DIR/model-<machine>.toml, DIR/model-type.toml and each machine's own search
/// under DIR/machines/<machine>/. Throws tools::CommandError.
void run_fleet(const std::vector<MachineLogs>& fleet, const std::string& config_path,
               const std::string& out_dir, bool validate_sessions);

/// summary.json of a fleet run; `models` = (machine, file name) of the written models.
std::string fleet_summary_json(const core::model::FleetResult& result,
                               const std::vector<std::string>& extras,
                               const std::vector<std::pair<std::string, std::string>>& models);

/// report.md of a fleet run.
std::string fleet_report_markdown(const core::model::FleetResult& result,
                                  const std::vector<std::string>& extras,
                                  const std::vector<MachineLogs>& inputs,
                                  const std::string& config_path);

}  // namespace nccomp::tools::analyze
