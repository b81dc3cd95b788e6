// Shared fixtures of the checkpoint tests.
#pragma once

#include <cmath>
#include <cstdint>
#include <vector>

#include "core/checkpoint/compensator.hpp"
#include "core/checkpoint/plan.hpp"
#include "core/checkpoint/probe.hpp"

namespace nccomp::core::checkpoint::test {

/// n checkpoints on a straight line along +X at y = 0, z = −5, 10 mm apart; path = x.
inline std::vector<Checkpoint> line_plan(std::size_t n) {
  std::vector<Checkpoint> plan;
  for (std::size_t i = 0; i < n; ++i) {
    Checkpoint c;
    c.id = static_cast<std::int32_t>(i);
    c.s_mm = 10.0 * static_cast<double>(i + 1);
    c.path_mm = c.s_mm;
    c.x_mm = c.tool_x_mm = c.s_mm;
    c.z_mm = -5.0;
    c.dir_y = 1.0;
    c.alpha_deg = 10.0;  // what probe() reports
    plan.push_back(c);
  }
  return plan;
}

inline LimiterConfig wide_limits() {
  LimiterConfig l;
  l.max_abs_um = 200.0;
  l.max_step_um = 1000.0;
  l.max_rate_um_per_s = 1e7;
  return l;
}

/// A probe reading whose corrected value is corrected_um (α = 10°, the α of line_plan(),
/// r = 1 mm).
inline ProbeMeasurement probe(std::int32_t part, std::int32_t cp, double corrected_um,
                              TimeNs t_ns = 0, double alpha_deg = 10.0) {
  ProbeMeasurement m;
  m.time_ns = t_ns;
  m.part = part;
  m.checkpoint = cp;
  m.wall_angle_deg = alpha_deg;
  m.ball_radius_mm = 1.0;
  m.raw_deviation_um = corrected_um + probe_delta0_um(1.0, alpha_deg);
  return m;
}

/// A probe reading at checkpoint c of a plan, with that checkpoint's α (as the probing program
/// passes it to the measuring macro).
inline ProbeMeasurement probe_at(const Checkpoint& c, std::int32_t part, double corrected_um,
                                 TimeNs t_ns = 0) {
  return probe(part, c.id, corrected_um, t_ns, c.alpha_deg);
}

inline ProgramEvent part_start(std::int32_t part) {
  return ProgramEvent{0, ProgramEventKind::kPartStart, part};
}

inline AxisSample sample(double x, double y, double z, double path, std::int32_t tool,
                         TimeNs t_ns) {
  AxisSample s;
  s.time_ns = t_ns;
  s.position_mm = {x, y, z, 0.0, 0.0, 0.0};
  s.program_path_mm = path;
  s.tool = tool;
  return s;
}

}  // namespace nccomp::core::checkpoint::test
