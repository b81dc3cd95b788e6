#include "formats/measurement_log/measurement_log.hpp"

#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <limits>

namespace nccomp::formats::measurement_log {

namespace {

constexpr std::int64_t kNsPerS = 1'000'000'000;

// Unknown values (NaN) are empty cells; `decimals` keeps the row short and exact enough.
void cell(std::string& s, double v, int decimals) {
  s += ',';
  if (std::isfinite(v)) {
    char buf[48];
    std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
    s += buf;
  }
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

bool valid_machine_id(std::string_view id) {
  if (id.empty() || id.size() > 64) return false;
  const auto alnum = [](char ch) {
    return (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9');
  };
  if (!alnum(id.front())) return false;
  for (char ch : id) {
    if (!alnum(ch) && ch != '.' && ch != '_' && ch != '-') return false;
  }
  return true;
}

std::string host_machine_id() {
  char buf[256] = {};
  if (::gethostname(buf, sizeof buf - 1) != 0) buf[0] = '\0';
  std::string id(buf);
  id = id.substr(0, id.find('.'));
  for (char& ch : id) {
    const bool ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') ||
                    (ch >= '0' && ch <= '9') || ch == '_' || ch == '-';
    if (!ok) ch = '-';
  }
  if (id.size() > 64) id.resize(64);
  if (id.empty() || id.front() == '-' || id.front() == '_') id = "machine" + id;
  return id.substr(0, 64);
}

std::string csv_header(const std::vector<ContextColumn>& columns) {
  std::string h = kV1Header;
  h += ',';
  h += kV2Columns;
  for (const ContextColumn& c : columns) {
    h += ',';
    h += c.name;
  }
  return h;
}

std::string format_utc(std::int64_t unix_ns) {
  std::int64_t s = unix_ns / kNsPerS;
  std::int64_t ms = (unix_ns % kNsPerS) / 1'000'000;
  if (ms < 0) {
    ms += 1000;
    --s;
  }
  const std::time_t t = static_cast<std::time_t>(s);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[96];
  std::snprintf(buf, sizeof buf, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900,
                tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, static_cast<int>(ms));
  return buf;
}

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

std::string format_row(const core::MeasurementRecord& r, std::string_view machine,
                       std::string_view utc, std::size_t context_count) {
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
  s += ',';
  s += machine;
  s += ',';
  s += utc;
  s += ',' + std::to_string(r.session);
  for (std::size_t k = 0; k < context_count && k < r.context.size(); ++k) {
    cell(s, r.context[k], 4);
  }
  return s;
}

std::string read_at(int fd, std::uint64_t offset, std::size_t n) {
  std::string s(n, '\0');
  std::size_t got = 0;
  while (got < n) {
    const ssize_t k = ::pread(fd, s.data() + got, n - got, static_cast<off_t>(offset + got));
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) break;
    got += static_cast<std::size_t>(k);
  }
  s.resize(got);
  return s;
}

long rotation_number(std::string_view file_name, std::string& log) {
  constexpr std::string_view kCsv = ".csv";
  const auto ends_with_csv = [&](std::string_view n) {
    return n.size() > kCsv.size() && n.substr(n.size() - kCsv.size()) == kCsv;
  };
  if (ends_with_csv(file_name)) {
    log = std::string(file_name);
    return 0;
  }
  const std::size_t dot = file_name.rfind('.');
  if (dot == std::string_view::npos) return -1;
  const std::string_view digits = file_name.substr(dot + 1);
  const std::string_view base = file_name.substr(0, dot);
  if (digits.empty() || digits.size() > 9 || digits.front() == '0' ||
      digits.find_first_not_of("0123456789") != std::string_view::npos || !ends_with_csv(base)) {
    return -1;
  }
  long n = 0;
  for (const char c : digits) n = n * 10 + (c - '0');
  log = std::string(base);
  return n;
}

}  // namespace nccomp::formats::measurement_log
