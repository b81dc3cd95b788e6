#include "core/checkpoint/probe.hpp"

#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

#include "core/common/types.hpp"

namespace nccomp::core::checkpoint {

const char* probe_status_text(ProbeStatus status) noexcept {
  switch (status) {
    case ProbeStatus::kOk:
      return "ok";
    case ProbeStatus::kNonFinite:
      return "deviation, wall angle or ball radius is not a finite number";
    case ProbeStatus::kNegativeRadius:
      return "probe ball radius is negative";
    case ProbeStatus::kAngleTooSteep:
      return "wall angle must be below 89 degrees";
  }
  return "unknown";
}

double probe_delta0_um(double ball_radius_mm, double wall_angle_deg) noexcept {
  const double alpha_rad = wall_angle_deg * std::numbers::pi / 180.0;
  return (ball_radius_mm / std::cos(alpha_rad) - ball_radius_mm) * kUmPerMm;
}

ProbeCorrection correct_probe(double raw_deviation_um, double wall_angle_deg,
                              double ball_radius_mm) noexcept {
  ProbeCorrection out;
  if (!std::isfinite(raw_deviation_um) || !std::isfinite(wall_angle_deg) ||
      !std::isfinite(ball_radius_mm)) {
    out.status = ProbeStatus::kNonFinite;
    return out;
  }
  if (ball_radius_mm < 0.0) {
    out.status = ProbeStatus::kNegativeRadius;
    return out;
  }
  // The sign of α only says to which side the wall leans; δ0 depends on |α|.
  if (std::fabs(wall_angle_deg) >= kMaxWallAngleDeg) {
    out.status = ProbeStatus::kAngleTooSteep;
    return out;
  }
  out.delta0_um = probe_delta0_um(ball_radius_mm, wall_angle_deg);
  out.corrected_um = raw_deviation_um - out.delta0_um;
  return out;
}

double corrected_deviation_um(double raw_deviation_um, double wall_angle_deg,
                              double ball_radius_mm) {
  const ProbeCorrection c = correct_probe(raw_deviation_um, wall_angle_deg, ball_radius_mm);
  if (c.status != ProbeStatus::kOk) {
    throw std::invalid_argument(std::string("probe correction: ") + probe_status_text(c.status) +
                                " (deviation " + std::to_string(raw_deviation_um) +
                                " um, wall angle " + std::to_string(wall_angle_deg) +
                                " deg, ball radius " + std::to_string(ball_radius_mm) + " mm)");
  }
  return c.corrected_um;
}

}  // namespace nccomp::core::checkpoint
