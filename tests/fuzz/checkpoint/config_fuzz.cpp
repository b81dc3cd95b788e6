// TOML bytes → the [checkpoints] loader → (if valid) the plan outputs.
#include <toml++/toml.h>

#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string_view>
#include <vector>

#include "formats/checkpoints/checkpoints_toml.hpp"
#include "formats/toml/guard.hpp"
#include "tools/plan/plan_output.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace ck = nccomp::tools::checkpoints;
  namespace fc = nccomp::formats::checkpoints;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  toml::table root;
  try {
    root = nccomp::formats::parse_toml(text, std::string_view("fuzz.toml"));
  } catch (const toml::parse_error&) {
    return 0;
  }
  const toml::table* t = root["checkpoints"].as_table();
  if (t == nullptr) return 0;
  nccomp::formats::Diagnostics diag;
  // A base directory without files: contour_csv can only fail cleanly.
  const fc::CheckpointsConfig c = fc::parse_checkpoints(*t, "fuzz.toml", "/nonexistent", diag);
  if (!diag.ok()) {
    (void)diag.to_string();
    return 0;
  }
  const auto plan = nccomp::core::checkpoint::make_plan(c.plan);  // validated: must not throw
  std::ostringstream os;
  ck::write_plan_summary(os, plan, c);
  ck::write_plan_csv(os, plan, c);
  ck::write_probing_gcode(os, plan, c);
  return 0;
}
