#include "daemon/measurement_log.hpp"

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <system_error>

namespace nccomp::daemon {

namespace {
// Unknown values (NaN) are empty cells; `decimals` keeps the row short and exact enough.
void cell(std::string& s, double v, int decimals) {
  s += ',';
  if (std::isfinite(v)) {
    char buf[48];
    std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
    s += buf;
  }
}
// time_s of the last data row of an existing log file (its last 4 KiB); −inf if none.
double last_row_time_s_of_file(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rbe");
  if (f == nullptr) return -std::numeric_limits<double>::infinity();
  char buf[4096];
  long start = 0;
  if (std::fseek(f, 0, SEEK_END) == 0) {
    const long size = std::ftell(f);
    start = size > static_cast<long>(sizeof buf) ? size - static_cast<long>(sizeof buf) : 0;
  }
  std::size_t n = 0;
  if (std::fseek(f, start, SEEK_SET) == 0) n = std::fread(buf, 1, sizeof buf, f);
  std::fclose(f);
  return last_row_time_s(std::string_view(buf, n), start == 0);
}

const char* kind_name(core::MeasurementKind k) {
  switch (k) {
    case core::MeasurementKind::kToolWear:
      return "tool_wear";
    case core::MeasurementKind::kContour:
      return "contour";
    case core::MeasurementKind::kCalib:
      return "calib";
  }
  return "unknown";
}
}  // namespace

double last_row_time_s(std::string_view tail, bool whole) noexcept {
  // The last complete line that starts with a finite number followed by a comma.
  std::size_t end = tail.size();
  while (end > 0) {
    while (end > 0 && (tail[end - 1] == '\n' || tail[end - 1] == '\r')) --end;
    std::size_t begin = end;
    while (begin > 0 && tail[begin - 1] != '\n') --begin;
    if (begin == 0 && !whole) break;  // the first line of a tail may be cut
    const std::string_view line = tail.substr(begin, end - begin);
    const std::size_t comma = line.find(',');
    if (comma != std::string_view::npos && comma > 0 && comma < 40) {
      char num[48];
      line.copy(num, comma);
      num[comma] = '\0';
      char* stop = nullptr;
      const double v = std::strtod(num, &stop);
      if (stop == num + comma && std::isfinite(v)) return v;
    }
    end = begin;
  }
  return -std::numeric_limits<double>::infinity();
}

std::string format_measurement_row(const core::MeasurementRecord& r) {
  std::string s;
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.6f", core::seconds(r.time_ns));
  s += buf;
  s += ',' + std::to_string(r.part) + ',' + std::to_string(r.tool) + ',' + kind_name(r.kind) + ',' +
       std::to_string(r.point);
  for (double p : r.position_mm) {
    cell(s, p, 4);
  }
  cell(s, r.angle_deg, 4);
  cell(s, r.path_mm, 3);
  cell(s, r.temp_c, 3);
  cell(s, r.measured_um, 4);
  cell(s, r.applied_um, 4);
  return s;
}

MeasurementLogWriter::MeasurementLogWriter(std::string directory, std::uint64_t max_file_bytes,
                                           int keep_files, std::size_t ring_capacity)
    : directory_(std::move(directory)),
      max_file_bytes_(max_file_bytes),
      keep_files_(keep_files),
      ring_(ring_capacity) {}

MeasurementLogWriter::~MeasurementLogWriter() { stop(); }

void MeasurementLogWriter::open_current() {
  const std::string path = current_path();
  file_ = std::fopen(path.c_str(), "ae");
  if (file_ == nullptr) {
    throw std::system_error(errno, std::generic_category(),
                            "cannot open measurement log '" + path + "'");
  }
  std::error_code ec;
  file_bytes_ = std::filesystem::file_size(path, ec);
  if (ec) {
    file_bytes_ = 0;
  }
  last_time_s_ =
      file_bytes_ > 0 ? last_row_time_s_of_file(path) : -std::numeric_limits<double>::infinity();
  if (file_bytes_ == 0) {
    const int n = std::fprintf(file_, "%s\n", kMeasurementCsvHeader);
    file_bytes_ += n > 0 ? static_cast<std::uint64_t>(n) : 0U;
    std::fflush(file_);
  }
}

void MeasurementLogWriter::start() {
  std::filesystem::create_directories(directory_);
  open_current();
  stop_.store(false);
  thread_ = std::thread([this] { run(); });
}

void MeasurementLogWriter::stop() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) {
    thread_.join();
  }
  if (file_ != nullptr) {
    std::fclose(file_);
    file_ = nullptr;
  }
}

void MeasurementLogWriter::rotate() {
  std::fclose(file_);
  file_ = nullptr;
  namespace fs = std::filesystem;
  const std::string base = current_path();
  std::error_code ec;
  fs::remove(base + "." + std::to_string(keep_files_), ec);
  for (int i = keep_files_ - 1; i >= 1; --i) {
    fs::rename(base + "." + std::to_string(i), base + "." + std::to_string(i + 1), ec);
  }
  fs::rename(base, base + ".1", ec);
  if (ec) {
    errors_.fetch_add(1);
  }
  rotations_.fetch_add(1);
  open_current();
}

void MeasurementLogWriter::write_row(const core::MeasurementRecord& r) {
  const std::string row = format_measurement_row(r);
  // As written (6 decimals): the comparison sees what a reader of the file will see.
  const double t_s = std::strtod(row.c_str(), nullptr);
  const bool back_in_time = t_s < last_time_s_;
  if (back_in_time || (file_bytes_ + row.size() + 1 > max_file_bytes_ && file_bytes_ > 0)) {
    try {
      rotate();
    } catch (const std::exception&) {
      errors_.fetch_add(1);
      return;
    }
    if (back_in_time) time_rotations_.fetch_add(1);
  }
  last_time_s_ = t_s;
  if (std::fprintf(file_, "%s\n", row.c_str()) < 0) {
    errors_.fetch_add(1);
    return;
  }
  file_bytes_ += row.size() + 1;
  rows_.fetch_add(1);
}

void MeasurementLogWriter::run() {
  for (;;) {
    const bool stopping = stop_.load(std::memory_order_acquire);
    core::MeasurementRecord r;
    bool any = false;
    while (file_ != nullptr && ring_.try_pop(r)) {
      write_row(r);
      any = true;
    }
    if (any && file_ != nullptr) {
      std::fflush(file_);
    }
    if (stopping) {
      return;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

}  // namespace nccomp::daemon
