// Contour CSV bytes → parse_contour_csv → make_plan: either a plan or std::invalid_argument;
// every plan made is accepted by the compensator (a refused plan would be a planner bug).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string_view>

#include "core/checkpoint/compensator.hpp"
#include "core/checkpoint/plan.hpp"
#include "core/checkpoint/probe.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cp = nccomp::core::checkpoint;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    cp::PlanConfig c;
    c.contour = cp::parse_contour_csv(text, "fuzz.csv");
    c.z_start_mm = -1.0;
    c.z_end_mm = -11.0;
    c.depth_step_mm = 5.0;
    c.wall_angle_deg = 2.0;
    c.tool_radius_mm = 4.0;
    for (const bool closed : {true, false}) {
      c.closed = closed;
      c.material = closed ? cp::MaterialSide::kInside : cp::MaterialSide::kLeft;
      try {
        const cp::Plan p = cp::make_plan(c);
        for (std::size_t i = 1; i < p.checkpoints.size(); ++i) {
          if (!(p.checkpoints[i].path_mm > p.checkpoints[i - 1].path_mm)) {
            __builtin_trap();  // the plan's machining order must be strictly increasing
          }
        }
        for (const cp::Checkpoint& k : p.checkpoints) {
          if (!(std::fabs(k.alpha_deg) < cp::kMaxWallAngleDeg)) {
            __builtin_trap();  // every point's α (from the CSV's column) is a usable angle
          }
        }
        // Every plan the planner makes is one the compensator accepts (levels, passes, seams).
        cp::CheckpointCompensator comp;
        comp.configure(cp::CompensatorConfig{}, p.checkpoints, nccomp::core::LimiterConfig{});
      } catch (const std::invalid_argument&) {
      }
    }
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
