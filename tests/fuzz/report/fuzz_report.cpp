// Fuzz target: the result-directory readers of `nccomp report`. Any bytes must parse or raise
// ReportInputError; nothing may crash or trip a sanitizer. The first byte picks the reader.
#include <cstddef>
#include <cstdint>
#include <string>

#include "tools/report/report.hpp"

namespace rp = nccomp::tools::report;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::string text(reinterpret_cast<const char*>(data) + 1, size - 1);
  try {
    switch (data[0] % 6U) {
      case 0: {
        const auto t = rp::parse_csv(text, "surface.csv", rp::surface_schema());
        if (t.values.size() != t.rows() * t.columns.size()) __builtin_trap();
        if (t.rows() > 0) (void)rp::analyze_surface(t);
        break;
      }
      case 1: {
        const auto t = rp::parse_csv(text, "walls.csv", rp::walls_schema());
        if (t.rows() > 0) (void)rp::analyze_walls(t);
        break;
      }
      case 2:
        (void)rp::analyze_checkpoints(
            rp::parse_csv(text, "checkpoints.csv", rp::checkpoints_schema()));
        break;
      case 3:
        (void)rp::analyze_touches(rp::parse_csv(text, "touches.csv", rp::touches_schema()));
        break;
      case 4:
        (void)rp::analyze_writes(rp::parse_csv(text, "writes.csv", rp::writes_schema()));
        break;
      default:
        (void)rp::result_info_from_json(rp::parse_json(text, "result.json"), "result.json");
        break;
    }
  } catch (const rp::ReportInputError&) {
  }
  return 0;
}
