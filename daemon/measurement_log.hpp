// The measurement log writer (architecture.md, "Measurement log"): measurement records from the
// loop (SPSC) → CSV rows in <directory>/measurements.csv, rotated by size to .1, .2, ... The
// input of `nccomp analyze`. Unknown values are empty cells.
//
// time_s: the records leave the engine with the time since the machine's warm start
// (core/engine/context.hpp), so time_s starts again near 0 at every warm start. A row earlier
// than the file's last row starts a new file (the current one is rotated to .1), so that time_s
// never goes backwards within a file (`nccomp analyze` requires it; give it the files oldest
// first). The last row's time of an existing file is read when the writer opens it (a restart
// appends).
#pragma once

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>

#include "core/common/types.hpp"
#include "core/rt/spsc_ring.hpp"

namespace nccomp::daemon {

/// The header row (v1 columns, in order).
inline constexpr const char* kMeasurementCsvHeader =
    "time_s,part,tool,kind,point,x_mm,y_mm,z_mm,angle_deg,path_mm,temp_c,measured_um,applied_um";

/// One CSV row (no newline) for a record.
[[nodiscard]] std::string format_measurement_row(const core::MeasurementRecord& r);

/// time_s of the last complete data row in `tail`, the end of a log file (`whole`: the tail is
/// the whole file, so its first line is complete); −inf if there is none (a header only, bytes
/// that are no row). Any bytes are accepted.
[[nodiscard]] double last_row_time_s(std::string_view tail, bool whole) noexcept;

class MeasurementLogWriter {
 public:
  /// Not real-time (allocates the ring).
  MeasurementLogWriter(std::string directory, std::uint64_t max_file_bytes, int keep_files,
                       std::size_t ring_capacity = 4096);
  ~MeasurementLogWriter();

  /// Opens (appends to) measurements.csv and starts the thread. Throws std::system_error.
  void start();
  /// Writes what is queued, closes the file. Idempotent.
  void stop();

  /// Loop thread (producer).
  core::rt::SpscRing<core::MeasurementRecord>& ring() noexcept { return ring_; }

  [[nodiscard]] std::string current_path() const { return directory_ + "/measurements.csv"; }
  [[nodiscard]] std::uint64_t rows() const noexcept { return rows_.load(); }
  [[nodiscard]] std::uint64_t rotations() const noexcept { return rotations_.load(); }
  /// Rotations because time_s went back (a warm start); included in rotations().
  [[nodiscard]] std::uint64_t time_rotations() const noexcept { return time_rotations_.load(); }
  [[nodiscard]] std::uint64_t errors() const noexcept { return errors_.load(); }

 private:
  void run();
  void open_current();
  void rotate();
  void write_row(const core::MeasurementRecord& r);

  std::string directory_;
  std::uint64_t max_file_bytes_;
  int keep_files_;
  core::rt::SpscRing<core::MeasurementRecord> ring_;
  std::FILE* file_{nullptr};
  std::uint64_t file_bytes_{0};
  /// time_s of the current file's last row; −inf when it has none.
  double last_time_s_{0.0};
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> rows_{0};
  std::atomic<std::uint64_t> rotations_{0};
  std::atomic<std::uint64_t> time_rotations_{0};
  std::atomic<std::uint64_t> errors_{0};
  std::thread thread_;
};

}  // namespace nccomp::daemon
