// The measurement log writer (architecture.md, "Measurement log"): measurement records from the
// loop (SPSC) → CSV rows in <directory>/measurements.csv, rotated by size to .1, .2, ... The
// input of `nccomp analyze`. Unknown values are empty cells.
#pragma once

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <mutex>
#include <string>
#include <thread>

#include "core/common/types.hpp"
#include "core/rt/spsc_ring.hpp"

namespace nccomp::daemon {

/// The header row (v1 columns, in order).
inline constexpr const char* kMeasurementCsvHeader =
    "time_s,part,tool,kind,point,x_mm,y_mm,z_mm,angle_deg,path_mm,temp_c,measured_um,applied_um";

/// One CSV row (no newline) for a record.
[[nodiscard]] std::string format_measurement_row(const core::MeasurementRecord& r);

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
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> rows_{0};
  std::atomic<std::uint64_t> rotations_{0};
  std::atomic<std::uint64_t> errors_{0};
  std::thread thread_;
};

}  // namespace nccomp::daemon
