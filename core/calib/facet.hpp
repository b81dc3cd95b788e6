// Test-grinding geometry (S3, "exact facet geometry"): a flat ground to depth d into a cylinder
// of radius ρ leaves a facet whose chord is c = 2·sqrt(2ρd − d²), so d = ρ − sqrt(ρ² − c²/4).
// Grinding from +X and from −X to the same nominal depth d0 with a position error e gives depths
// d0 + e and d0 − e, so e = (d₊ − d₋)/2 — independent of d0, exact for any e, one grind suffices.
// All functions are real-time safe.
#pragma once

#include <algorithm>
#include <cmath>

namespace nccomp::core::calib {

/// Chord length [mm] of a flat of depth depth_mm in a cylinder of radius radius_mm; NaN outside
/// 0 ≤ d ≤ 2ρ.
inline double chord_from_depth_mm(double radius_mm, double depth_mm) noexcept {
  if (!(depth_mm >= 0.0) || !(depth_mm <= 2.0 * radius_mm)) {
    return std::nan("");
  }
  return 2.0 * std::sqrt(std::max(0.0, 2.0 * radius_mm * depth_mm - depth_mm * depth_mm));
}

/// Depth [mm] of the flat whose chord is chord_mm (the shallower of the two solutions); NaN
/// outside 0 ≤ c ≤ 2ρ.
inline double depth_from_chord_mm(double radius_mm, double chord_mm) noexcept {
  if (!(chord_mm >= 0.0) || !(chord_mm <= 2.0 * radius_mm)) {
    return std::nan("");
  }
  const double half = 0.5 * chord_mm;
  return radius_mm - std::sqrt(radius_mm * radius_mm - half * half);
}

/// Position error [µm] from the two facet chords by the exact geometry: e = (d₊ − d₋)/2, where
/// the +X facet is the deeper one when e > 0.
inline double facet_error_exact_um(double radius_mm, double chord_plus_mm,
                                   double chord_minus_mm) noexcept {
  return 0.5 *
         (depth_from_chord_mm(radius_mm, chord_plus_mm) -
          depth_from_chord_mm(radius_mm, chord_minus_mm)) *
         1000.0;
}

/// Position error [µm] by the proportional model: e = gain · (c₊ − c₋).
inline double facet_error_proportional_um(double gain_um_per_um, double chord_plus_mm,
                                          double chord_minus_mm) noexcept {
  return gain_um_per_um * (chord_plus_mm - chord_minus_mm) * 1000.0;
}

/// The gain that makes the proportional model exact to first order at nominal depth d0:
/// e = (dd/dc)/2 · Δc with dd/dc = c/(4·sqrt(ρ² − c²/4)) = c / (4(ρ − d0)).
inline double matched_proportional_gain(double radius_mm, double nominal_depth_mm) noexcept {
  const double c = chord_from_depth_mm(radius_mm, nominal_depth_mm);
  return 0.5 * c / (4.0 * (radius_mm - nominal_depth_mm));
}

}  // namespace nccomp::core::calib
