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

/// Splits at commas into at most kMaxFields fields; count = the number of fields found.
constexpr std::size_t kMaxFields = 5;
void split(std::string_view line, std::array<std::string_view, kMaxFields>& out,
           std::size_t& count) {
  count = 0;
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = line.find(',', start);
    const std::string_view f = trim(line.substr(
        start, comma == std::string_view::npos ? std::string_view::npos : comma - start));
    if (count < kMaxFields) out[count] = f;
    ++count;
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
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

constexpr const char* kHeaders =
    "expected the header 'path_mm,nx,ny,nz', 'path_mm,nx,ny,nz,removal_mm2' or "
    "'path_mm,removal_mm2'";

}  // namespace

ToolpathTable parse_toolpath(std::string_view text, std::string_view source) {
  ToolpathTable table;
  std::size_t columns = 0;  // 0 until the header is read
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
    std::array<std::string_view, kMaxFields> f{};
    std::size_t count = 0;
    split(line, f, count);
    if (columns == 0) {
      const bool normals = count >= 4 && f[0] == "path_mm" && f[1] == "nx" && f[2] == "ny" &&
                           f[3] == "nz" && (count == 4 || (count == 5 && f[4] == "removal_mm2"));
      const bool removal_only = count == 2 && f[0] == "path_mm" && f[1] == "removal_mm2";
      if (!normals && !removal_only) fail(source, line_no, kHeaders);
      table.has_normals = normals;
      table.has_removal = removal_only || count == 5;
      columns = count;
      continue;
    }
    if (count != columns) {
      fail(source, line_no,
           "expected " + std::to_string(columns) + " columns, got " + std::to_string(count));
    }
    if (table.rows.size() == kMaxToolpathRows) {
      fail(source, line_no, "more than " + std::to_string(kMaxToolpathRows) + " rows");
    }
    ToolpathRow r;
    r.path_mm = number(f[0], source, line_no, "path_mm");
    if (table.has_normals) {
      r.normal = {number(f[1], source, line_no, "nx"), number(f[2], source, line_no, "ny"),
                  number(f[3], source, line_no, "nz")};
      const double len = std::sqrt(r.normal[0] * r.normal[0] + r.normal[1] * r.normal[1] +
                                   r.normal[2] * r.normal[2]);
      if (!(std::fabs(len - 1.0) <= 0.01)) {
        fail(source, line_no, "normal is not a unit vector (|n| = " + std::to_string(len) + ")");
      }
      for (auto& v : r.normal) v /= len;
    }
    if (table.has_removal) {
      r.removal_mm2 = number(f[columns - 1], source, line_no, "removal_mm2");
      if (r.removal_mm2 < 0.0 || r.removal_mm2 > kMaxRemovalMm2) {
        fail(source, line_no,
             "removal_mm2 must be 0.." + std::to_string(static_cast<int>(kMaxRemovalMm2)) +
                 " mm², got " + std::string(f[columns - 1]));
      }
    }
    if (!table.rows.empty() && !(r.path_mm > table.rows.back().path_mm)) {
      fail(source, line_no,
           "path_mm must be strictly increasing (" + std::to_string(r.path_mm) + " after " +
               std::to_string(table.rows.back().path_mm) + ")");
    }
    table.rows.push_back(r);
  }
  if (columns == 0) fail(source, line_no, std::string("empty file: ") + kHeaders);
  if (table.rows.size() < 2) fail(source, line_no, "needs at least 2 rows");
  return table;
}

}  // namespace nccomp::core::creep
