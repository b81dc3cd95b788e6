// Fuzz target: the measurement-log CSV reader (v1 and mapped). Any bytes must either parse or
// raise formats::DiagnosticsError; nothing may crash or trip a sanitizer. The first byte picks the
// mode: mapped, wide, text ids, a restarting counter (time or path, on decrease or per file),
// several header rows, the text read as two files. In mapped mode the input's length picks the
// separator and decimal mark (size % 4: ",.", ";.", ";,", tab and ",").
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>

#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"

namespace io = nccomp::formats::model_io;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::string text(reinterpret_cast<const char*>(data) + 1, size - 1);
  io::Mapping mapping;
  nccomp::core::model::Dataset d;
  if ((data[0] & 1U) != 0U) {
    mapping.columns = {{"time_s", "時間(s)"}, {"measured_um", "ch1(um)"}, {"path_mm", "cut"}};
    mapping.constant = {{"kind", 2.0}};
    mapping.scale = {{"path_mm", 108.0}};
    mapping.extra = {{"t1_c", "t1(°C)"}};
    d.extra_columns = {"t1_c"};
    if ((data[0] & 2U) != 0U) {
      mapping.columns.erase(mapping.columns.begin() + 1);
      mapping.wide_measured = {"flute_1", "flute_2"};
      mapping.wide_points = {1.0, 2.0};
    }
    if ((data[0] & 4U) != 0U) {
      mapping.columns.emplace_back("tool", "tool");
      io::Mapping::TextIds ids{"tool", (data[0] & 8U) != 0U, {{"c1", 1.0}, {"T12", 12.0}}};
      mapping.ids.push_back(ids);
    }
    if ((data[0] & 16U) != 0U) {
      mapping.restart_column = (data[0] & 32U) != 0U ? "time_s" : "path_mm";
      mapping.restart_per_file = (data[0] & 8U) != 0U;
    }
    if ((data[0] & 64U) != 0U) {
      mapping.header_rows = 2;
      mapping.names_row = 1 + (data[0] >> 7U);
    }
    constexpr char kSeparators[] = {',', ';', ';', '\t'};
    constexpr char kDecimals[] = {'.', '.', ',', ','};
    mapping.separator = kSeparators[size % 4];
    mapping.decimal = kDecimals[size % 4];
  }
  const int files = (data[0] & 128U) != 0U ? 2 : 1;
  try {
    for (int f = 0; f < files; ++f) {
      std::istringstream in(text);
      io::read_log(in, f == 0 ? "fuzz.csv" : "fuzz2.csv", mapping, d);
    }
    // Every column the reader filled has one value per row; sessions only grow; a time column
    // that restarts orders every run after the rows before it.
    for (const auto& c : d.columns) {
      if (!c.empty() && c.size() != d.rows()) __builtin_trap();
    }
    if (d.row_session.size() != d.rows() || d.order_s.size() != d.rows()) __builtin_trap();
    double last = -1e300;
    for (std::size_t r = 0; r < d.rows(); ++r) {
      if (r > 0 && d.row_session[r] < d.row_session[r - 1]) __builtin_trap();
      if (mapping.restart_column == "time_s" && std::isfinite(d.order_s[r])) {
        if (d.order_s[r] < last) __builtin_trap();
        last = d.order_s[r];
      }
    }
  } catch (const nccomp::formats::DiagnosticsError&) {
  }
  return 0;
}
