// Fuzz target: the [creep] section parser and the CreepModule it configures. Any bytes must end
// in a module that attaches and steps, or in diagnostics (or a refused attach), never in a crash.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string_view>
#include <vector>

#include <toml++/toml.h>

#include "core/creep/creep_module.hpp"
#include "core/engine/engine.hpp"
#include "daemon/sections/creep/creep_section.hpp"
#include "formats/toml/guard.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cfg = nccomp::daemon::config;
  namespace core = nccomp::core;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  toml::table root;
  try {
    root = nccomp::formats::parse_toml(text, std::string_view("fuzz.toml"));
  } catch (const toml::parse_error&) {
    return 0;
  }
  const toml::node* node = root.get("creep");
  if (node == nullptr) {
    return 0;
  }
  nccomp::formats::Diagnostics diag;
  auto section = nccomp::daemon::sections::parse_creep_section(*node, diag);
  for (const auto& d : diag.items()) {
    (void)nccomp::formats::format(d);
  }
  if (!diag.ok()) {
    return 0;
  }
  const core::LimiterConfig lim{100.0, 10.0, 1000.0};
  std::vector<core::engine::RegisterSpec> regs{
      {"X_wear_offset", core::engine::RegisterKind::kAxisOffset, lim},
      {"Y_wear_offset", core::engine::RegisterKind::kAxisOffset, lim},
      {"Z_wear_offset", core::engine::RegisterKind::kAxisOffset, lim},
      {"T1_radius_wear", core::engine::RegisterKind::kToolRadiusWear, lim},
      {"T1_length_wear", core::engine::RegisterKind::kToolLengthWear, lim}};
  std::vector<std::unique_ptr<core::engine::Module>> modules;
  modules.push_back(std::make_unique<core::creep::CreepModule>(section->module));
  core::engine::Engine engine;
  try {
    engine.configure(regs, std::move(modules));
  } catch (const std::invalid_argument&) {
    return 0;  // a register name or kind the fixed table does not have
  }
  // A short stream: the configured module must step without tripping a sanitizer.
  core::StepOutput out;
  core::AxisSample a;
  a.tool = 1;
  core::ToolMeasurement m;
  m.tool = 1;
  m.wear_um[0] = 5.0;
  for (int i = 0; i < 20; ++i) {
    a.time_ns = i * 1'000'000;
    a.program_path_mm = 0.5 * i;
    std::vector<core::Event> ev{a};
    if (i == 3) ev.emplace_back(m);
    engine.step(a.time_ns, ev, out);
  }
  return 0;
}
