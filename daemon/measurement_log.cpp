#include "daemon/measurement_log.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <limits>
#include <stdexcept>
#include <system_error>

namespace nccomp::daemon {

namespace ml = formats::measurement_log;

namespace {

constexpr std::int64_t kNsPerS = 1'000'000'000;
constexpr std::size_t kMaxBatchBytes = 64 * 1024;

std::int64_t clock_ns(clockid_t id) {
  timespec ts{};
  clock_gettime(id, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * kNsPerS + ts.tv_nsec;
}

/// CLOCK_REALTIME − CLOCK_MONOTONIC now (the monotonic reading taken on both sides).
std::int64_t monotonic_to_realtime_ns() {
  const std::int64_t m0 = clock_ns(CLOCK_MONOTONIC);
  const std::int64_t r = clock_ns(CLOCK_REALTIME);
  const std::int64_t m1 = clock_ns(CLOCK_MONOTONIC);
  return r - (m0 + (m1 - m0) / 2);
}

}  // namespace

MeasurementLogWriter::MeasurementLogWriter(MeasurementLogOptions options)
    : options_(std::move(options)),
      directory_(options_.directory),
      header_(ml::csv_header(options_.context_columns)),
      ring_(options_.ring_capacity),
      face_probe_(options_.face_probe) {
  if (options_.context_columns.size() > core::kMaxContextValues) {
    throw std::invalid_argument("measurement log: at most " +
                                std::to_string(core::kMaxContextValues) + " context columns");
  }
  context_count_ = options_.context_columns.size();
  for (std::size_t k = 0; k < context_count_; ++k) {
    sensors_[k] = options_.context_columns[k].sensor;
  }
}

MeasurementLogWriter::MeasurementLogWriter(std::string directory, std::uint64_t max_file_bytes,
                                           int keep_files, std::size_t ring_capacity)
    : MeasurementLogWriter(MeasurementLogOptions{
          std::move(directory), max_file_bytes, keep_files, ring_capacity, {}, {}, true, 1.0, {}}) {
}

MeasurementLogWriter::~MeasurementLogWriter() { stop(); }

void MeasurementLogWriter::stamp(core::MeasurementRecord& r,
                                 const core::engine::MachineContext& c) const noexcept {
  for (std::size_t k = 0; k < context_count_; ++k) {
    r.context[k] = c.temperature_c(sensors_[k]);
  }
}

void MeasurementLogWriter::open_current(bool may_rotate) {
  const std::string path = current_path();
  fd_ = ::open(path.c_str(), O_RDWR | O_APPEND | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    throw std::system_error(errno, std::generic_category(),
                            "cannot open measurement log '" + path + "'");
  }
  struct stat st {};
  file_bytes_ = ::fstat(fd_, &st) == 0 ? static_cast<std::uint64_t>(st.st_size) : 0U;
  if (file_bytes_ > 0) {
    // A file of another format (v1, other context columns) is kept as it is: rotated away.
    if (may_rotate && ml::read_at(fd_, 0, header_.size() + 1) != header_ + "\n") {
      rotate();
      return;
    }
    // A partial last row (a crash in the middle of a write) is cut: appending after it would
    // glue the next row to it.
    std::uint64_t keep = file_bytes_;
    while (keep > 0) {
      const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(keep, 4096));
      const std::size_t nl = ml::read_at(fd_, keep - n, n).rfind('\n');
      if (nl != std::string::npos) {
        keep = keep - n + nl + 1;
        break;
      }
      keep -= n;
    }
    if (keep < file_bytes_) {
      errors_.fetch_add(1);
      if (::ftruncate(fd_, static_cast<off_t>(keep)) == 0) file_bytes_ = keep;
    }
  }
  if (file_bytes_ > 0) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(file_bytes_, 4096));
    last_time_s_ = ml::last_row_time_s(ml::read_at(fd_, file_bytes_ - n, n), n == file_bytes_);
    return;
  }
  last_time_s_ = -std::numeric_limits<double>::infinity();
  batch_ = header_ + "\n";
  batch_rows_ = 0;
  write_batch();
  if (file_bytes_ == 0) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    throw std::system_error(err, std::generic_category(),
                            "cannot write the header of measurement log '" + path + "'");
  }
}

void MeasurementLogWriter::start() {
  std::filesystem::create_directories(directory_);
  open_current();
  last_sync_ns_ = clock_ns(CLOCK_MONOTONIC);
  stop_.store(false);
  thread_ = std::thread([this] { run(); });
}

void MeasurementLogWriter::stop() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) {
    thread_.join();
  }
  if (fd_ >= 0) {
    if (unsynced_) ::fdatasync(fd_);
    ::close(fd_);
    fd_ = -1;
  }
}

void MeasurementLogWriter::rotate() {
  if (unsynced_) ::fdatasync(fd_);
  unsynced_ = false;
  ::close(fd_);
  fd_ = -1;
  namespace fs = std::filesystem;
  const std::string base = current_path();
  std::error_code ec;
  fs::remove(base + "." + std::to_string(options_.keep_files), ec);
  for (int i = options_.keep_files - 1; i >= 1; --i) {
    fs::rename(base + "." + std::to_string(i), base + "." + std::to_string(i + 1), ec);
  }
  fs::rename(base, base + ".1", ec);
  if (ec) {
    errors_.fetch_add(1);
  }
  rotations_.fetch_add(1);
  open_current(false);
}

void MeasurementLogWriter::write_batch() {
  if (batch_.empty()) return;
  std::size_t done = 0;
  while (done < batch_.size()) {
    const ssize_t k = ::write(fd_, batch_.data() + done, batch_.size() - done);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) break;
    done += static_cast<std::size_t>(k);
  }
  if (done < batch_.size()) {
    // A full disk or an I/O error: the rows of this batch are lost, but no partial row stays.
    errors_.fetch_add(1);
    rows_lost_.fetch_add(batch_rows_);
    if (done > 0 && ::ftruncate(fd_, static_cast<off_t>(file_bytes_)) != 0) {
      errors_.fetch_add(1);
    }
  } else {
    file_bytes_ += batch_.size();
    rows_.fetch_add(batch_rows_);
    unsynced_ = true;
  }
  batch_.clear();
  batch_rows_ = 0;
}

void MeasurementLogWriter::write_row(const core::MeasurementRecord& r,
                                     std::int64_t mono_to_real_ns) {
  const std::int64_t real_ns =
      options_.monotonic_record_clock ? r.clock_ns + mono_to_real_ns : clock_ns(CLOCK_REALTIME);
  const std::string row =
      ml::format_row(r, options_.machine_id, ml::format_utc(real_ns), context_count_);
  // As written (6 decimals): the comparison sees what a reader of the file will see.
  const double t_s = std::strtod(row.c_str(), nullptr);
  const bool back_in_time = t_s < last_time_s_;
  const std::uint64_t size_after = file_bytes_ + batch_.size() + row.size() + 1;
  if (back_in_time || (size_after > options_.max_file_bytes && file_bytes_ + batch_.size() > 0)) {
    write_batch();
    try {
      rotate();
    } catch (const std::exception&) {
      errors_.fetch_add(1);
      rows_lost_.fetch_add(1);
      return;
    }
    if (back_in_time) time_rotations_.fetch_add(1);
  }
  last_time_s_ = t_s;
  batch_ += row;
  batch_ += '\n';
  ++batch_rows_;
}

void MeasurementLogWriter::run() {
  for (;;) {
    const bool stopping = stop_.load(std::memory_order_acquire);
    if (fd_ < 0) {
      // The file could not be reopened after a rotation: try again every poll.
      try {
        open_current();
      } catch (const std::exception&) {
      }
    }
    if (fd_ >= 0) {
      const std::int64_t offset_ns = monotonic_to_realtime_ns();
      core::MeasurementRecord r;
      while (fd_ >= 0 && ring_.try_pop(r)) {
        write_row(r, offset_ns);
        if (observer_) observer_(r);
        // A producer as fast as this thread would keep the loop going forever.
        if (batch_.size() >= kMaxBatchBytes) write_batch();
      }
      if (fd_ >= 0) write_batch();
      const std::int64_t now_ns = clock_ns(CLOCK_MONOTONIC);
      if (fd_ >= 0 && unsynced_ &&
          static_cast<double>(now_ns - last_sync_ns_) >= options_.fsync_interval_s * 1e9) {
        ::fdatasync(fd_);
        unsynced_ = false;
        last_sync_ns_ = now_ns;
      }
    }
    if (stopping) {
      return;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

}  // namespace nccomp::daemon
