// Fuzz target: the measurement-log CSV reader (v1 and mapped). Any bytes must either parse or
// raise formats::DiagnosticsError; nothing may crash or trip a sanitizer. The first byte picks the
// mode.
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
  }
  std::istringstream in(text);
  try {
    io::read_log(in, "fuzz.csv", mapping, d);
    // Every column the reader filled has one value per row.
    for (const auto& c : d.columns) {
      if (!c.empty() && c.size() != d.rows()) __builtin_trap();
    }
  } catch (const nccomp::formats::DiagnosticsError&) {
  }
  return 0;
}
