// The measurement log's CSV format (architecture.md, "Measurement log"; docs/daemon.md): the
// columns of v1 and v2, the machine id rule, one row from a measurement record, and reading the
// last row's time of a file's tail. nccompd's writer (daemon/measurement_log), `nccomp publish`
// (which reads the log) and `nccomp collect` (which writes one log per machine) share it, so that
// all of them agree on the format. Not real-time.
//
// Format v2: the v1 columns in their v1 order, then machine, utc, session and the configured
// context columns. The column set marks the version (a v2 header has machine, utc and session);
// a reader that only knows v1 reads a v2 file unchanged (extra columns are ignored), which a
// version comment line or a changed column order would break. Unknown values are empty cells.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "core/common/types.hpp"

namespace nccomp::formats::measurement_log {

/// The v1 columns, in order.
inline constexpr const char* kV1Header =
    "time_s,part,tool,kind,point,x_mm,y_mm,z_mm,angle_deg,path_mm,temp_c,measured_um,applied_um";
/// The columns v2 adds after the v1 columns (then the context columns).
inline constexpr const char* kV2Columns = "machine,utc,session";

/// A context column of the log: a named value of the machine context (a bus input).
struct ContextColumn {
  std::string name;
  /// The TemperatureSample channel (sensor 0 … 255) whose last value is logged.
  int sensor{0};
};

/// A machine id (the `machine` column, MQTT topic levels, collected file names): 1 … 64 of
/// [A-Za-z0-9._-], starting with a letter or digit.
[[nodiscard]] bool valid_machine_id(std::string_view id);

/// The machine id when the config names none: the host name up to its first '.', characters
/// other than [A-Za-z0-9._-] replaced by '-' ("machine" if there is no host name).
[[nodiscard]] std::string host_machine_id();

/// The header row for these context columns (v2).
[[nodiscard]] std::string csv_header(const std::vector<ContextColumn>& columns);

/// ISO 8601 UTC with milliseconds, e.g. "2024-05-06T07:08:09.123Z", of a CLOCK_REALTIME time.
[[nodiscard]] std::string format_utc(std::int64_t unix_ns);

/// One CSV row (no newline): the v1 cells, then machine, utc, session and the first
/// `context_count` context values.
[[nodiscard]] std::string format_row(const core::MeasurementRecord& r, std::string_view machine,
                                     std::string_view utc, std::size_t context_count);

/// time_s of the last complete data row in `tail`, the end of a log file (`whole`: the tail is
/// the whole file, so its first line is complete); −inf if there is none (a header only, bytes
/// that are no row). Any bytes are accepted.
[[nodiscard]] double last_row_time_s(std::string_view tail, bool whole) noexcept;

/// Where a file name stands in nccompd's log rotation: 0 for a log itself (`<name>.csv`), N for
/// its rotated file `<name>.csv.N` (N = 1 the newest, 1 … 999 999 999), −1 for any other name.
/// `log` receives the log's own name (`<name>.csv`) for 0 and N. A log's files read oldest first
/// are the highest N first and the log itself last.
[[nodiscard]] long rotation_number(std::string_view file_name, std::string& log);

/// Up to `n` bytes of the open file `fd` at `offset` (fewer at its end or on a read error).
[[nodiscard]] std::string read_at(int fd, std::uint64_t offset, std::size_t n);

}  // namespace nccomp::formats::measurement_log
