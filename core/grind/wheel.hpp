// The grinding wheel's profile in the U–Z feed plane (seeds.md S2): an arc of chord width W and
// height h, radius R = h/2 + W²/(8h). h = 0 is the straight grinding line (R = ∞).
//
// Convention used throughout core/grind: U is the height of the roll's profile (radial, mm);
// the wheel lies above the profile, convex toward it, and its surface at lateral offset s from
// the midpoint T of the grinding line rises by g(s) = R − sqrt(R² − s²), |s| ≤ W/2.
#pragma once

#include <cmath>
#include <limits>

namespace nccomp::core::grind {

class Wheel {
 public:
  /// From chord width W and arc height h (0 ≤ h < W/2). Throws std::invalid_argument.
  static Wheel from_arc_height(double width_mm, double arc_height_mm);
  /// From chord width W and arc radius R (R ≥ W/2, may be +inf for a straight line).
  static Wheel from_radius(double width_mm, double radius_mm);

  [[nodiscard]] double width_mm() const noexcept { return width_mm_; }
  [[nodiscard]] double half_width_mm() const noexcept { return 0.5 * width_mm_; }
  [[nodiscard]] double arc_height_mm() const noexcept { return arc_height_mm_; }
  /// +inf for the straight grinding line.
  [[nodiscard]] double radius_mm() const noexcept { return radius_mm_; }
  [[nodiscard]] bool straight() const noexcept { return !(arc_height_mm_ > 0.0); }

  /// g(s): rise of the wheel's surface at lateral offset s (|s| ≤ W/2 assumed). Written as
  /// s²/(R + sqrt(R² − s²)) because R − sqrt(R² − s²) cancels catastrophically for s ≪ R.
  /// Real-time safe.
  [[nodiscard]] double rise_mm(double s_mm) const noexcept {
    if (straight()) {
      return 0.0;
    }
    return s_mm * s_mm / (radius_mm_ + std::sqrt(radius_mm_ * radius_mm_ - s_mm * s_mm));
  }
  /// g'(W/2): slope of the arc at its ends (0 for the straight line).
  [[nodiscard]] double end_slope() const noexcept {
    if (straight()) {
      return 0.0;
    }
    const double s = half_width_mm();
    return s / std::sqrt(radius_mm_ * radius_mm_ - s * s);
  }

 private:
  Wheel(double w, double h, double r) : width_mm_(w), arc_height_mm_(h), radius_mm_(r) {}
  double width_mm_;
  double arc_height_mm_;
  double radius_mm_;
};

}  // namespace nccomp::core::grind
