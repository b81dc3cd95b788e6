// Fuzz target: config text after a fixed register table (so [measurement_context], [model] and
// their keys are reached), then the engine built from it steps a few cycles of axis samples,
// temperatures, tool changes and part starts. Any bytes must end in diagnostics or in an engine
// that steps, never in a crash.
#include <cstddef>
#include <cstdint>
#include <exception>
#include <string>
#include <vector>

#include "core/common/output.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cfg = nccomp::daemon::config;
  namespace core = nccomp::core;
  const std::string text =
      "[loopback]\n[[registers]]\nname = \"r0\"\nkind = \"checkpoint\"\nbus = \"loopback\"\n"
      "max_abs_um = 100\nmax_step_um = 10\nmax_rate_um_per_s = 1000\n" +
      std::string(reinterpret_cast<const char*>(data), size);
  auto r = cfg::load_string(text, "fuzz.toml", "/nonexistent-nccomp-fuzz");
  if (!r.config) {
    for (const auto& d : r.diagnostics.items()) (void)nccomp::formats::format(d);
    return 0;
  }
  std::unique_ptr<core::engine::Engine> e;
  try {
    e = cfg::build_engine(*r.config);
  } catch (const std::exception&) {
    return 0;
  }
  core::StepOutput out;
  for (std::int32_t k = 1; k <= 6; ++k) {
    core::AxisSample a;
    a.position_mm[0] = 3.0 * k;
    a.tool = k / 3 + 1;
    a.cutting = k % 4 != 0;
    const std::vector<core::Event> ev = {
        a, core::TemperatureSample{0, static_cast<std::uint8_t>(k % 3), 20.0 + k},
        core::ProgramEvent{0, core::ProgramEventKind::kPartStart, k / 2},
        core::ToolChange{0, k, k == 5}};
    e->step(k * 1'000'000'000LL, ev, out);
  }
  return 0;
}
