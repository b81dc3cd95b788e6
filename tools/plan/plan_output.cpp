#include "tools/plan/plan_output.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "core/checkpoint/probe.hpp"

namespace nccomp::tools::checkpoints {

namespace cp = core::checkpoint;

namespace {

std::string fmt(int decimals, double v) {
  char buf[64];
  // -0.000 reads as a sign error on a machine print-out.
  const double clean = std::fabs(v) < 0.5 * std::pow(10.0, -decimals) ? 0.0 : v;
  std::snprintf(buf, sizeof buf, "%.*f", decimals, clean);
  return buf;
}

const char* source_name(cp::CheckpointSource s) {
  return s == cp::CheckpointSource::kCorner ? "corner" : "extra";
}

}  // namespace

void write_plan_summary(std::ostream& os, const cp::Plan& plan, const CheckpointsConfig& cfg) {
  const auto& c = cfg.compensator;
  const std::size_t n = plan.checkpoints.size();
  os << "# contour: " << cfg.plan.contour.size() << " points from " << cfg.contour_source << ", "
     << (cfg.plan.closed ? "closed" : "open") << ", length " << fmt(3, plan.contour_length_mm)
     << " mm, material " << cp::material_side_name(cfg.plan.material) << ", " << plan.corner_count
     << " corners";
  if (plan.marked_corner_count > 0) {
    os << " (" << plan.marked_corner_count << " marked as sub-curve boundaries)";
  }
  os << "\n";
  os << "# levels: " << plan.levels_z_mm.size() << " (z " << fmt(3, plan.levels_z_mm.front())
     << " .. " << fmt(3, plan.levels_z_mm.back()) << " mm, step " << fmt(3, cfg.plan.depth_step_mm)
     << " mm), " << n / plan.levels_z_mm.size() << " points per level, " << n << " checkpoints\n";
  os << "# registers: " << c.register_base << " .. " << c.register_base + n - 1;
  if (cfg.gcode.nc_variable_first > 0) {
    os << " (NC variables #" << cfg.gcode.nc_variable_first << " .. #"
       << cfg.gcode.nc_variable_first + static_cast<int>(n) - 1 << ")";
  }
  os << "; learning " << cp::learning_mode_name(c.learning_mode) << ", apply "
     << cp::apply_mode_name(c.apply) << ", trigger " << cp::trigger_mode_name(c.trigger) << "\n";
  const double r = cfg.plan.ball_radius_mm;
  os << "# probe: ball radius " << fmt(3, r) << " mm, ";
  if (!(plan.alpha_max_deg > plan.alpha_min_deg)) {
    os << "wall angle " << fmt(3, plan.alpha_min_deg)
       << " deg, delta0 = r/cos(a) - r = " << fmt(3, cp::probe_delta0_um(r, plan.alpha_min_deg))
       << " um\n";
  } else {
    // δ0 grows with |α|: its range over the plan's angles.
    const double a_lo =
        plan.alpha_min_deg <= 0.0 && plan.alpha_max_deg >= 0.0
            ? 0.0
            : std::min(std::fabs(plan.alpha_min_deg), std::fabs(plan.alpha_max_deg));
    const double a_hi = std::max(std::fabs(plan.alpha_min_deg), std::fabs(plan.alpha_max_deg));
    os << "wall angle " << fmt(3, plan.alpha_min_deg) << " .. " << fmt(3, plan.alpha_max_deg)
       << " deg (per point: column alpha_deg), delta0 = r/cos(a) - r = "
       << fmt(3, cp::probe_delta0_um(r, a_lo)) << " .. " << fmt(3, cp::probe_delta0_um(r, a_hi))
       << " um\n";
  }
}

void write_plan_csv(std::ostream& os, const cp::Plan& plan, const CheckpointsConfig& cfg) {
  os << "id,level,source,register,s_mm,path_mm,x_mm,y_mm,z_mm,dir_x,dir_y,alpha_deg,delta0_um,"
        "tool_x_mm,tool_y_mm,start_x_mm,start_y_mm\n";
  for (const cp::Checkpoint& k : plan.checkpoints) {
    os << k.id << ',' << k.level << ',' << source_name(k.source) << ','
       << cfg.compensator.register_base + k.id << ',' << fmt(3, k.s_mm) << ',' << fmt(3, k.path_mm)
       << ',' << fmt(4, k.x_mm) << ',' << fmt(4, k.y_mm) << ',' << fmt(4, k.z_mm) << ','
       << fmt(6, k.dir_x) << ',' << fmt(6, k.dir_y) << ',' << fmt(3, k.alpha_deg) << ','
       << fmt(3, cp::probe_delta0_um(cfg.plan.ball_radius_mm, k.alpha_deg)) << ','
       << fmt(4, k.tool_x_mm) << ',' << fmt(4, k.tool_y_mm) << ',' << fmt(4, k.start_x_mm) << ','
       << fmt(4, k.start_y_mm) << '\n';
  }
}

void write_probing_gcode(std::ostream& os, const cp::Plan& plan, const CheckpointsConfig& cfg) {
  const GcodeConfig& g = cfg.gcode;
  const std::size_t n = plan.checkpoints.size();
  os << "%\n";
  os << "O" << g.program_number << " (NCCOMP S1 CHECKPOINT PROBING, " << n << " POINTS, "
     << plan.levels_z_mm.size() << " LEVELS)\n";
  os << "(G65 P" << g.macro_program
     << ": I J = PROBING DIRECTION, D = NOMINAL TRAVEL TO THE WALL MM,)\n";
  os << "(A = WALL ANGLE DEG, R = BALL RADIUS MM, E = CHECKPOINT NUMBER)\n";
  os << "G90 G00 Z" << fmt(3, g.safe_z_mm) << "\n";
  for (const cp::Checkpoint& k : plan.checkpoints) {
    os << "N" << (k.id + 1) << " G00 X" << fmt(3, k.start_x_mm) << " Y" << fmt(3, k.start_y_mm)
       << "\n";
    os << "G01 Z" << fmt(3, k.z_mm) << " F" << fmt(0, g.feed_mm_per_min) << ".\n";
    os << "G65 P" << g.macro_program << " I" << fmt(4, k.dir_x) << " J" << fmt(4, k.dir_y) << " D"
       << fmt(3, cfg.plan.probe_approach_mm) << " A" << fmt(3, k.alpha_deg) << " R"
       << fmt(3, cfg.plan.ball_radius_mm) << " E" << k.id << ".";
    if (g.nc_variable_first > 0) {
      os << " (#" << g.nc_variable_first + k.id << ")";
    }
    os << "\n";
    os << "G00 Z" << fmt(3, g.safe_z_mm) << "\n";
  }
  os << "M30\n%\n";
}

}  // namespace nccomp::tools::checkpoints
