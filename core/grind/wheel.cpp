#include "core/grind/wheel.hpp"

#include <limits>
#include <stdexcept>
#include <string>

namespace nccomp::core::grind {

Wheel Wheel::from_arc_height(double width_mm, double arc_height_mm) {
  if (!std::isfinite(width_mm) || !(width_mm > 0.0)) {
    throw std::invalid_argument("wheel width W must be a finite number > 0 mm, got " +
                                std::to_string(width_mm));
  }
  if (!std::isfinite(arc_height_mm) || arc_height_mm < 0.0 || !(arc_height_mm < 0.5 * width_mm)) {
    throw std::invalid_argument(
        "wheel arc height h must satisfy 0 <= h < W/2 = " + std::to_string(0.5 * width_mm) +
        " mm, got " + std::to_string(arc_height_mm));
  }
  if (!(arc_height_mm > 0.0)) {
    return Wheel(width_mm, 0.0, std::numeric_limits<double>::infinity());
  }
  const double r = 0.5 * arc_height_mm + width_mm * width_mm / (8.0 * arc_height_mm);
  return Wheel(width_mm, arc_height_mm, r);
}

Wheel Wheel::from_radius(double width_mm, double radius_mm) {
  if (!std::isfinite(width_mm) || !(width_mm > 0.0)) {
    throw std::invalid_argument("wheel width W must be a finite number > 0 mm, got " +
                                std::to_string(width_mm));
  }
  if (std::isnan(radius_mm) || !(radius_mm > 0.5 * width_mm)) {
    throw std::invalid_argument(
        "wheel arc radius R must be > W/2 = " + std::to_string(0.5 * width_mm) + " mm, got " +
        std::to_string(radius_mm));
  }
  if (std::isinf(radius_mm)) {
    return Wheel(width_mm, 0.0, radius_mm);
  }
  const double s = 0.5 * width_mm;
  const double h = s * s / (radius_mm + std::sqrt(radius_mm * radius_mm - s * s));
  return Wheel(width_mm, h, radius_mm);
}

}  // namespace nccomp::core::grind
