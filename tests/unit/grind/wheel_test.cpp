#include "core/grind/wheel.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

namespace nccomp::core::grind {
namespace {

TEST(Wheel, GivenWidthAndHeight_ThenRadiusIsTheSeedsFormula) {
  const auto w = Wheel::from_arc_height(150.0, 0.5);
  EXPECT_DOUBLE_EQ(w.radius_mm(), 0.25 + 150.0 * 150.0 / 4.0);  // h/2 + W²/(8h)
  // The arc's end lies exactly h above T.
  EXPECT_NEAR(w.rise_mm(75.0), 0.5, 1e-12);
  EXPECT_NEAR(w.rise_mm(-75.0), 0.5, 1e-12);
  EXPECT_DOUBLE_EQ(w.rise_mm(0.0), 0.0);
  // g(s) = R − sqrt(R² − s²) without cancellation: the series s²/(2R) + s⁴/(8R³) is exact to
  // 1e-30 here, while the textbook form loses ~1e-8 relative even in long double.
  const double r = w.radius_mm();
  const double s = 0.01;
  EXPECT_NEAR(w.rise_mm(s), s * s / (2 * r) + s * s * s * s / (8 * r * r * r), 1e-22);
  EXPECT_NEAR(w.end_slope(), 75.0 / std::sqrt(w.radius_mm() * w.radius_mm() - 75.0 * 75.0), 1e-15);
}

TEST(Wheel, GivenRadius_ThenHeightRoundTrips) {
  const auto a = Wheel::from_arc_height(120.0, 0.3);
  const auto b = Wheel::from_radius(120.0, a.radius_mm());
  EXPECT_NEAR(b.arc_height_mm(), 0.3, 1e-12);
  const auto flat = Wheel::from_radius(120.0, std::numeric_limits<double>::infinity());
  EXPECT_TRUE(flat.straight());
  EXPECT_EQ(flat.rise_mm(60.0), 0.0);
}

TEST(Wheel, GivenStraightLine_ThenRiseIsZero) {
  const auto w = Wheel::from_arc_height(100.0, 0.0);
  EXPECT_TRUE(w.straight());
  EXPECT_TRUE(std::isinf(w.radius_mm()));
  EXPECT_EQ(w.rise_mm(50.0), 0.0);
  EXPECT_EQ(w.end_slope(), 0.0);
}

TEST(Wheel, GivenBadGeometry_ThenClearErrors) {
  EXPECT_THROW(Wheel::from_arc_height(0.0, 0.1), std::invalid_argument);
  EXPECT_THROW(Wheel::from_arc_height(-5.0, 0.1), std::invalid_argument);
  EXPECT_THROW(Wheel::from_arc_height(std::nan(""), 0.1), std::invalid_argument);
  EXPECT_THROW(Wheel::from_arc_height(100.0, 50.0), std::invalid_argument);  // h = W/2
  EXPECT_THROW(Wheel::from_arc_height(100.0, 60.0), std::invalid_argument);
  EXPECT_THROW(Wheel::from_arc_height(100.0, -0.1), std::invalid_argument);
  EXPECT_THROW(Wheel::from_arc_height(100.0, std::nan("")), std::invalid_argument);
  EXPECT_THROW(Wheel::from_radius(100.0, 50.0), std::invalid_argument);
  try {
    Wheel::from_arc_height(100.0, 50.0);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("h < W/2"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace nccomp::core::grind
