// Fuzz target: the toolpath file parser ([creep.edge] toolpath_file: normals and / or removal
// cross-sections), and the core stepping on whatever table it accepted. Any bytes must either be
// refused with std::invalid_argument or give a table on which every offset stays finite and
// within limits and the removed volume stays finite, non-negative and non-decreasing.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string_view>
#include <vector>

#include "core/common/output.hpp"
#include "core/creep/toolpath.hpp"
#include "core/creep/wear_compensator.hpp"

using namespace nccomp::core;
using namespace nccomp::core::creep;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  ToolpathTable table;
  try {
    table = parse_toolpath(text, "fuzz.csv");
  } catch (const std::invalid_argument&) {
    return 0;
  }
  const auto& rows = table.rows;
  if (rows.size() < 2 || !(table.has_normals || table.has_removal)) std::abort();
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const auto& n = rows[i].normal;
    if (!std::isfinite(rows[i].path_mm)) std::abort();
    if (table.has_normals &&
        std::fabs(std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) - 1.0) > 1e-9)
      std::abort();
    if (table.has_removal && !(rows[i].removal_mm2 >= 0.0 && rows[i].removal_mm2 <= kMaxRemovalMm2))
      std::abort();
    if (i > 0 && !(rows[i].path_mm > rows[i - 1].path_mm)) std::abort();
  }
  CreepConfig c;
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 4;
  c.edge.normal_source = table.has_normals ? NormalSource::kToolpath : NormalSource::kNone;
  c.toolpath = table;
  c.output.channel_register = {0, 1, 2, -1, -1};
  c.creep_length_mm = 1.0;
  c.interval.basis = IntervalBasis::kMaterial;
  c.interval.removal_source =
      table.has_removal ? RemovalSource::kToolpath : RemovalSource::kConstant;
  WearCompensator w;
  w.configure(c);  // a parsed table must always be a valid config
  StepOutput out;
  std::vector<Event> ev;
  ToolMeasurement m;
  m.tool = 1;
  m.point_count = 4;
  m.wear_um = {3.0, 5.0, 7.0, 9.0};
  ev.emplace_back(ToolChange{0, 1, false});
  ev.emplace_back(m);
  w.step(0, ev, out);
  const double lo = rows.front().path_mm;
  const double hi = rows.back().path_mm;
  double removed = 0.0;
  for (int k = 0; k <= 16; ++k) {
    ev.clear();
    AxisSample a;
    a.tool = 1;
    a.program_path_mm = lo - 1.0 + (hi - lo + 2.0) * k / 16.0;
    ev.emplace_back(a);
    out.clear();
    w.step((k + 1) * 1'000'000, ev, out);
    for (const auto& wr : out.writes) {
      if (!std::isfinite(wr.value_um) || std::fabs(wr.value_um) > c.limiter.max_abs_um)
        std::abort();
    }
    if (!std::isfinite(w.removed_mm3()) || w.removed_mm3() < removed - 1e-9) std::abort();
    removed = w.removed_mm3();
  }
  return 0;
}
