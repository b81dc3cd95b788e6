#include "core/creep/toolpath.hpp"

#include <array>
#include <charconv>
#include <cmath>
#include <stdexcept>
#include <string>
#include <system_error>

namespace nccomp::core::creep {

namespace {

[[noreturn]] void fail(std::string_view source, std::size_t line, const std::string& what) {
  std::string msg(source);
  msg += ':';
  msg += std::to_string(line);
  msg += ": ";
  msg += what;
  throw std::invalid_argument(msg);
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) {
    s.remove_suffix(1);
  }
  return s;
}

/// Splits at commas into exactly N fields; false if the count differs.
template <std::size_t N>
bool split(std::string_view line, std::array<std::string_view, N>& out, std::size_t& count) {
  count = 0;
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = line.find(',', start);
    const std::string_view f = trim(line.substr(
        start, comma == std::string_view::npos ? std::string_view::npos : comma - start));
    if (count < N) out[count] = f;
    ++count;
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  return count == N;
}

double number(std::string_view f, std::string_view source, std::size_t line, const char* column) {
  double v = 0.0;
  const char* end = f.data() + f.size();
  const auto [ptr, ec] = std::from_chars(f.data(), end, v);
  if (f.empty() || ec != std::errc() || ptr != end || !std::isfinite(v)) {
    fail(source, line, std::string(column) + " is not a finite number: '" + std::string(f) + "'");
  }
  return v;
}

}  // namespace

std::vector<ToolpathNormal> parse_toolpath_normals(std::string_view text, std::string_view source) {
  std::vector<ToolpathNormal> rows;
  bool header = false;
  std::size_t line_no = 0;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t nl = text.find('\n', pos);
    const std::string_view raw =
        text.substr(pos, nl == std::string_view::npos ? std::string_view::npos : nl - pos);
    pos = nl == std::string_view::npos ? text.size() + 1 : nl + 1;
    ++line_no;
    const std::string_view line = trim(raw);
    if (line.empty() || line.front() == '#') continue;
    std::array<std::string_view, 4> f{};
    std::size_t count = 0;
    const bool four = split(line, f, count);
    if (!header) {
      if (!four || f[0] != "path_mm" || f[1] != "nx" || f[2] != "ny" || f[3] != "nz") {
        fail(source, line_no, "expected the header 'path_mm,nx,ny,nz'");
      }
      header = true;
      continue;
    }
    if (!four) fail(source, line_no, "expected 4 columns, got " + std::to_string(count));
    if (rows.size() == kMaxToolpathRows) {
      fail(source, line_no, "more than " + std::to_string(kMaxToolpathRows) + " rows");
    }
    ToolpathNormal r;
    r.path_mm = number(f[0], source, line_no, "path_mm");
    r.normal = {number(f[1], source, line_no, "nx"), number(f[2], source, line_no, "ny"),
                number(f[3], source, line_no, "nz")};
    const double len = std::sqrt(r.normal[0] * r.normal[0] + r.normal[1] * r.normal[1] +
                                 r.normal[2] * r.normal[2]);
    if (!(std::fabs(len - 1.0) <= 0.01)) {
      fail(source, line_no, "normal is not a unit vector (|n| = " + std::to_string(len) + ")");
    }
    for (auto& v : r.normal) v /= len;
    if (!rows.empty() && !(r.path_mm > rows.back().path_mm)) {
      fail(source, line_no,
           "path_mm must be strictly increasing (" + std::to_string(r.path_mm) + " after " +
               std::to_string(rows.back().path_mm) + ")");
    }
    rows.push_back(r);
  }
  if (!header) fail(source, line_no, "empty file: expected the header 'path_mm,nx,ny,nz'");
  if (rows.size() < 2) fail(source, line_no, "needs at least 2 rows");
  return rows;
}

}  // namespace nccomp::core::creep
