// The measurement log writer (architecture.md, "Measurement log"): measurement records from the
// loop (SPSC) → CSV rows in <directory>/measurements.csv, rotated by size to .1, .2, ... The
// input of `nccomp analyze` and of `nccomp publish`. Unknown values are empty cells.
//
// The format (columns, rows, machine ids): formats/measurement_log.
//
// time_s: the records leave the engine with the time since the machine's warm start
// (core/engine/context.hpp), so time_s starts again near 0 at every warm start (and session
// counts up). A row earlier than the file's last row starts a new file (the current one is
// rotated to .1), so that time_s never goes backwards within a file. The last row's time of an
// existing file is read when the writer opens it (a restart appends); a file whose header is not
// this writer's (a v1 file, other context columns) is rotated first.
//
// utc: the writer thread, not the loop, reads the wall clock. It converts the record's step-clock
// time (clock_ns, CLOCK_MONOTONIC) to UTC through the offset between CLOCK_REALTIME and
// CLOCK_MONOTONIC it reads when it writes the batch; in lock-step runs (the step clock is the
// simulator's) utc is the time the row is written.
//
// Crash safety: rows are written whole, a batch with one write(2) after each poll (20 ms); a
// failed or short write is cut back to the last complete row, and a file that ends in a partial
// row (a crash of an older writer, a full disk) is cut back to its last complete row when it is
// opened. A crash of the daemon loses the rows still in the ring (those of the last poll period,
// at most ring_capacity); a power cut also loses what the kernel had not yet written, at most the
// rows of the last fsync_interval_s.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <thread>
#include <utility>
#include <vector>

#include "core/common/types.hpp"
#include "core/engine/context.hpp"
#include "core/rt/spsc_ring.hpp"
#include "daemon/measurement_log_probe.hpp"
#include "formats/measurement_log/measurement_log.hpp"

namespace nccomp::daemon {

/// A context column of the log (the format's).
using ContextColumn = formats::measurement_log::ContextColumn;

struct MeasurementLogOptions {
  std::string directory;
  std::uint64_t max_file_bytes{16U * 1024U * 1024U};
  int keep_files{8};
  std::size_t ring_capacity{4096};
  /// The `machine` column.
  std::string machine_id;
  /// At most core::kMaxContextValues.
  std::vector<ContextColumn> context_columns;
  /// True: records' clock_ns is CLOCK_MONOTONIC (utc from it); false (lock-step): utc is the time
  /// the row is written.
  bool monotonic_record_clock{true};
  /// Rows are flushed to the disk (fdatasync) at least this often [s]; 0 = after every batch.
  double fsync_interval_s{1.0};
  /// Probe readings of the finished face as contour rows (measurement_log_probe.hpp).
  FaceProbeConfig face_probe;
};

class MeasurementLogWriter {
 public:
  /// Not real-time (allocates the ring). Throws std::invalid_argument for more context columns
  /// than a record carries.
  explicit MeasurementLogWriter(MeasurementLogOptions options);
  /// The v2 writer with no machine id and no context columns (tests).
  MeasurementLogWriter(std::string directory, std::uint64_t max_file_bytes, int keep_files,
                       std::size_t ring_capacity = 4096);
  ~MeasurementLogWriter();

  /// Opens (appends to) measurements.csv and starts the thread. Throws std::system_error.
  void start();
  /// Writes what is queued, closes the file. Idempotent.
  void stop();

  /// Called on the writer thread with every record it writes (the candidate in shadow,
  /// sections/model/shadow.hpp). Set before start().
  void set_observer(std::function<void(const core::MeasurementRecord&)> observer) {
    observer_ = std::move(observer);
  }

  /// Real-time safe (loop thread): fills the record's context values from the machine context.
  void stamp(core::MeasurementRecord& r, const core::engine::MachineContext& c) const noexcept;
  /// Loop thread (producer).
  core::rt::SpscRing<core::MeasurementRecord>& ring() noexcept { return ring_; }
  /// Loop thread: the face probe's capture (disabled unless configured).
  FaceProbeCapture& face_probe() noexcept { return face_probe_; }

  [[nodiscard]] std::string current_path() const { return directory_ + "/measurements.csv"; }
  [[nodiscard]] const std::string& header() const noexcept { return header_; }
  [[nodiscard]] std::uint64_t rows() const noexcept { return rows_.load(); }
  [[nodiscard]] std::uint64_t rotations() const noexcept { return rotations_.load(); }
  /// Rotations because time_s went back (a warm start); included in rotations().
  [[nodiscard]] std::uint64_t time_rotations() const noexcept { return time_rotations_.load(); }
  /// Write, rotation and open failures, and partial rows cut from a file.
  [[nodiscard]] std::uint64_t errors() const noexcept { return errors_.load(); }
  /// Rows that could not be written (the file could not be opened or written).
  [[nodiscard]] std::uint64_t rows_lost() const noexcept { return rows_lost_.load(); }

 private:
  void run();
  /// may_rotate: a file with another header is rotated away first.
  void open_current(bool may_rotate = true);
  void rotate();
  void write_row(const core::MeasurementRecord& r, std::int64_t mono_to_real_ns);
  /// Writes batch_ whole or not at all.
  void write_batch();

  MeasurementLogOptions options_;
  std::string directory_;
  std::string header_;
  std::array<int, core::kMaxContextValues> sensors_{};
  std::size_t context_count_{0};
  core::rt::SpscRing<core::MeasurementRecord> ring_;
  FaceProbeCapture face_probe_;
  int fd_{-1};
  std::uint64_t file_bytes_{0};
  std::string batch_;
  std::size_t batch_rows_{0};
  std::int64_t last_sync_ns_{0};
  bool unsynced_{false};
  /// time_s of the current file's last row; −inf when it has none.
  double last_time_s_{0.0};
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> rows_{0};
  std::atomic<std::uint64_t> rotations_{0};
  std::atomic<std::uint64_t> time_rotations_{0};
  std::atomic<std::uint64_t> errors_{0};
  std::atomic<std::uint64_t> rows_lost_{0};
  std::function<void(const core::MeasurementRecord&)> observer_;
  std::thread thread_;
};

}  // namespace nccomp::daemon
