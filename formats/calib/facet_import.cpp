#include "formats/calib/facet_import.hpp"

#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>

namespace nccomp::formats::calib {

namespace {

[[noreturn]] void fail(const std::string& source, std::size_t line, const std::string& why) {
  throw std::invalid_argument(source + ":" + std::to_string(line) + ": " + why);
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) {
    s.remove_suffix(1);
  }
  return s;
}

std::vector<std::string_view> split(std::string_view line, char sep) {
  std::vector<std::string_view> out;
  std::size_t start = 0;
  while (true) {
    const auto p = line.find(sep, start);
    out.push_back(trim(line.substr(start, p == std::string_view::npos ? p : p - start)));
    if (p == std::string_view::npos) break;
    start = p + 1;
  }
  return out;
}

std::string lower(std::string_view w) {
  std::string s(w);
  for (auto& ch : s) {
    if (ch >= 'A' && ch <= 'Z') ch = static_cast<char>(ch - 'A' + 'a');
  }
  return s;
}

// Shown in messages: at most 24 printable characters of what was found.
std::string shown(std::string_view w) {
  std::string s;
  for (const char ch : w.substr(0, 24)) {
    s += (ch >= 0x20 && ch < 0x7f) ? ch : '?';
  }
  return s;
}

double chord(std::string_view w, const std::string& source, std::size_t line, const char* col) {
  double v = 0.0;
  const auto res = std::from_chars(w.data(), w.data() + w.size(), v);
  if (w.empty() || res.ec != std::errc() || res.ptr != w.data() + w.size() || !std::isfinite(v)) {
    fail(source, line, std::string(col) + " must be a finite number in mm, got '" + shown(w) + "'");
  }
  if (v <= 0.0 || v > 1000.0) {
    fail(source, line, std::string(col) + " must be in (0, 1000] mm, got '" + shown(w) + "'");
  }
  return v;
}

}  // namespace

std::vector<FacetMeasurement> parse_facet_export(std::string_view text, const std::string& source) {
  if (text.size() > kMaxFacetExportBytes) {
    fail(source, 1, "larger than " + std::to_string(kMaxFacetExportBytes) + " bytes");
  }
  std::vector<FacetMeasurement> rows;
  std::vector<std::string> header;
  char sep = ',';
  std::size_t col_face = 0, col_plus = 0, col_minus = 0;
  std::size_t line_no = 0;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const auto nl = text.find('\n', pos);
    const std::string_view raw =
        text.substr(pos, nl == std::string_view::npos ? std::string_view::npos : nl - pos);
    pos = nl == std::string_view::npos ? text.size() + 1 : nl + 1;
    ++line_no;
    const std::string_view line = trim(raw);
    if (line.empty() || line.front() == '#') continue;
    if (line.find('"') != std::string_view::npos) {
      fail(source, line_no, "quoted fields are not supported");
    }
    if (line.find('\0') != std::string_view::npos) {
      fail(source, line_no, "a NUL byte (not a text export)");
    }
    if (header.empty()) {
      const auto commas = line.find(',') != std::string_view::npos;
      sep = commas ? ',' : ';';
      bool face = false, plus = false, minus = false;
      const auto names = split(line, sep);
      for (std::size_t i = 0; i < names.size(); ++i) {
        const std::string n = lower(names[i]);
        if (n.empty())
          fail(source, line_no, "header: column " + std::to_string(i + 1) + " has no name");
        for (const auto& h : header) {
          if (h == n) fail(source, line_no, "header: column '" + shown(n) + "' appears twice");
        }
        header.push_back(n);
        if (n == "face") {
          col_face = i;
          face = true;
        } else if (n == "chord_plus_mm") {
          col_plus = i;
          plus = true;
        } else if (n == "chord_minus_mm") {
          col_minus = i;
          minus = true;
        }
      }
      if (!face || !plus || !minus) {
        fail(source, line_no,
             "header must name the columns face, chord_plus_mm and chord_minus_mm, got '" +
                 shown(line) + "'");
      }
      continue;
    }
    const auto f = split(line, sep);
    if (f.size() != header.size()) {
      fail(source, line_no,
           std::to_string(f.size()) + " fields, the header has " + std::to_string(header.size()));
    }
    FacetMeasurement m;
    m.line = line_no;
    const std::string face = lower(f[col_face]);
    if (face == "lateral") {
      m.face = core::calib::Face::kLateral;
    } else if (face == "end-face") {
      m.face = core::calib::Face::kEndFace;
    } else {
      fail(source, line_no, "face must be lateral or end-face, got '" + shown(f[col_face]) + "'");
    }
    m.chord_plus_mm = chord(f[col_plus], source, line_no, "chord_plus_mm");
    m.chord_minus_mm = chord(f[col_minus], source, line_no, "chord_minus_mm");
    if (rows.size() == kMaxFacetRows) {
      fail(source, line_no, "more than " + std::to_string(kMaxFacetRows) + " rows");
    }
    rows.push_back(m);
  }
  if (header.empty()) fail(source, line_no, "no header line (face,chord_plus_mm,chord_minus_mm)");
  if (rows.empty()) fail(source, line_no, "no measurement row after the header");
  return rows;
}

std::vector<FacetMeasurement> read_facet_export(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw std::invalid_argument(path + ": cannot be read");
  }
  in.seekg(0, std::ios::end);
  const auto size = in.tellg();
  if (size < 0 || static_cast<std::size_t>(size) > kMaxFacetExportBytes) {
    throw std::invalid_argument(path + ": larger than " + std::to_string(kMaxFacetExportBytes) +
                                " bytes (not a facet export)");
  }
  in.seekg(0);
  std::ostringstream s;
  s << in.rdbuf();
  return parse_facet_export(s.str(), path);
}

}  // namespace nccomp::formats::calib
