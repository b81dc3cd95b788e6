// Items 3 and 6 of issue 3: edge-wear profile at the current engagement angle along the surface
// normal (axes or tool registers, or the mean on one axis), per-support-point creep, and the
// wear-dependent deflection table.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using testing::base_config;
using testing::Rig;

const double kS45 = std::sqrt(0.5);

CreepConfig ball_config() {
  auto c = base_config();
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 4;  // 0°, 30°, 60°, 90°
  c.edge.normal_source = NormalSource::kAxisSample;
  c.creep_length_mm = 10.0;
  return c;
}

TEST(CreepEdge, WearAtTheEngagementAngleAlongTheNormalSplitIntoAxes) {
  Rig r(ball_config());
  r.has_normal = true;
  r.normal = {kS45, 0.0, kS45};  // 45° wall in XZ
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  EXPECT_NEAR(r.comp.engagement_angle_deg(), 45.0, 1e-9);
  EXPECT_NEAR(r.comp.correction_um(), 10.0, 1e-9);  // halfway between 8 (30°) and 12 (60°)
  EXPECT_NEAR(r.x(), -10.0 * kS45, 1e-9);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kY), 0.0, 1e-12);
  EXPECT_NEAR(r.z(), -10.0 * kS45, 1e-9);
  // Flat floor: the tip's wear, on Z only.
  r.normal = {0.0, 0.0, 1.0};
  r.advance(0.5);
  EXPECT_NEAR(r.z(), -4.0, 1e-9);
  EXPECT_NEAR(r.x(), 0.0, 1e-12);
  // Vertical wall facing −Y: the side wear, on +Y toward the wall.
  r.normal = {0.0, -1.0, 0.0};
  r.advance(0.5);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kY), 16.0, 1e-9);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
}

TEST(CreepEdge, ToolRegistersTakeRadiusAndLengthComponents) {
  auto c = ball_config();
  c.output.mode = OutputMode::kToolRegisters;
  c.output.channel_register = {-1, -1, -1, 3, 4};
  c.edge.fallback_channel = Channel::kLength;
  Rig r(c);
  r.has_normal = true;
  r.normal = {0.5, 0.0, std::sqrt(0.75)};  // 30°
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  EXPECT_NEAR(r.comp.correction_um(), 8.0, 1e-9);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kRadius), -8.0 * 0.5, 1e-9);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kLength), -8.0 * std::sqrt(0.75), 1e-9);
  EXPECT_NEAR(r.last_write(3), -4.0, 1e-9);
}

TEST(CreepEdge, WithoutANormalTheMeanWearGoesOnTheFallbackAxis) {
  Rig r(ball_config());
  r.has_normal = false;
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  EXPECT_TRUE(std::isnan(r.comp.engagement_angle_deg()));
  EXPECT_NEAR(r.z(), -10.0, 1e-9);
  EXPECT_NEAR(r.x(), 0.0, 1e-12);
}

TEST(CreepEdge, NormalFromAToolpathTableByProgramPosition) {
  auto c = ball_config();
  c.edge.normal_source = NormalSource::kToolpath;
  c.toolpath = {true, false, {{0.0, {0.0, 0.0, 1.0}}, {100.0, {1.0, 0.0, 0.0}}}};
  Rig r(c);
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(50.0);  // interpolated normal (0.5, 0, 0.5) → 45°
  EXPECT_NEAR(r.comp.engagement_angle_deg(), 45.0, 1e-9);
  EXPECT_NEAR(r.x(), -10.0 * kS45, 1e-9);
  r.run_to(150.0);  // beyond the table: its last normal, 90°
  EXPECT_NEAR(r.x(), -16.0, 1e-9);
}

TEST(CreepEdge, ANewProfileCreepsInPerSupportPoint) {
  Rig r(ball_config());
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  r.measure({6.0, 8.0, 12.0, 26.0});
  r.run_to(25.0);  // half of the 10 mm creep
  EXPECT_NEAR(r.comp.applied_wear_um(0), 5.0, 1e-9);
  EXPECT_NEAR(r.comp.applied_wear_um(1), 8.0, 1e-9);
  EXPECT_NEAR(r.comp.applied_wear_um(2), 12.0, 1e-9);
  EXPECT_NEAR(r.comp.applied_wear_um(3), 21.0, 1e-9);
}

TEST(CreepEdge, AtARateEachSupportPointCreepsOverItsOwnLength) {
  auto c = ball_config();
  c.creep_basis = CreepBasis::kRatePath;
  c.creep_rate_um_per_mm = 1.0;
  Rig r(c);
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(6.0);
  EXPECT_NEAR(r.comp.applied_wear_um(0), 4.0, 1e-9);  // done after 4 mm
  EXPECT_NEAR(r.comp.applied_wear_um(1), 6.0, 1e-9);  // same slope 1 µm/mm everywhere
  EXPECT_NEAR(r.comp.applied_wear_um(3), 6.0, 1e-9);
  r.run_to(16.0);
  EXPECT_NEAR(r.comp.applied_wear_um(3), 16.0, 1e-9);
  EXPECT_EQ(r.comp.creeps_in_progress(), 0U);
}

TEST(CreepEdge, ASinglePointMeasurementAppliesAlongTheWholeEdge) {
  Rig r(ball_config());
  r.measure({7.0});
  r.run_to(20.0);
  for (std::size_t i = 0; i < 4; ++i) EXPECT_NEAR(r.comp.applied_wear_um(i), 7.0, 1e-9);
}

TEST(CreepEdge, AMeasurementWithTheWrongPointCountIsRefused) {
  Rig r(ball_config());
  r.measure({1.0, 2.0});
  EXPECT_EQ(r.count(AlarmCode::kEventInvalid), 1U);
  EXPECT_EQ(r.comp.counters().measurements_accepted, 0U);
}

// ---- item 6 ------------------------------------------------------------------------------

TEST(CreepDeflection, OverCompensationGrowsWithWearInNormalAndLateralDirections) {
  auto c = ball_config();
  c.deflection = {{0, {0.0, 20.0}, {0.0, 4.0}, {0.0, 10.0}}};
  Rig r(c);
  r.has_normal = true;
  r.normal = {kS45, 0.0, kS45};
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  // Wear 10 at 45°: normal 10 + 2, lateral 5 across the tool axis (+X here).
  EXPECT_NEAR(r.comp.correction_um(), 12.0, 1e-9);
  EXPECT_NEAR(r.comp.lateral_um(), 5.0, 1e-9);
  EXPECT_NEAR(r.x(), -12.0 * kS45 - 5.0, 1e-9);
  EXPECT_NEAR(r.z(), -12.0 * kS45, 1e-9);
  // Beyond the table's last row: held at its end value.
  r.measure({30.0, 30.0, 30.0, 30.0});
  r.run_to(40.0);
  EXPECT_NEAR(r.comp.correction_um(), 34.0, 1e-9);
  EXPECT_NEAR(r.comp.lateral_um(), 10.0, 1e-9);
}

TEST(CreepDeflection, WithoutANormalTheLateralPartGoesAcrossTheFeedTowardTheMaterial) {
  auto c = base_config();  // tip, no normal: mean wear on Z
  c.deflection = {{0, {0.0, 20.0}, {0.0, 4.0}, {0.0, 10.0}}};
  c.edge.material_side = MaterialSide::kRight;
  Rig r(c);
  r.measure({10.0});
  r.run_to(60.0);  // feed along +X, tool axis +Z: the material on the right is at −Y
  EXPECT_NEAR(r.z(), -(10.0 + 2.0), 1e-9);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kY), -5.0, 1e-9);
  EXPECT_NEAR(r.x(), 0.0, 1e-12);
  EXPECT_NEAR(r.comp.lateral_um(), 5.0, 1e-9);
  // The return pass of a raster (feed −X): the material on the right is now at +Y.
  for (int i = 0; i < 4; ++i) {
    r.pos_mm[0] -= 0.5;
    r.program_path_mm += 0.5;
    r.now_ns += 10'000'000;
    r.sample();
  }
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kY), 5.0, 1e-9);
  // A plunge along the tool axis keeps the last feed direction.
  r.pos_mm[2] -= 1.0;
  r.program_path_mm += 1.0;
  r.sample();
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kY), 5.0, 1e-9);

  c.edge.material_side = MaterialSide::kLeft;
  Rig left(c);
  left.measure({10.0});
  left.run_to(60.0);
  EXPECT_NEAR(left.comp.channel_output_um(Channel::kY), 5.0, 1e-9);

  // No side configured: no direction, so no lateral compensation (and lateral_um() says so).
  c.edge.material_side = MaterialSide::kNone;
  Rig none(c);
  none.measure({10.0});
  none.run_to(60.0);
  EXPECT_NEAR(none.comp.channel_output_um(Channel::kY), 0.0, 1e-12);
  EXPECT_NEAR(none.comp.lateral_um(), 0.0, 0.0);
  EXPECT_NEAR(none.z(), -12.0, 1e-9);
}

TEST(CreepDeflection, WithoutANormalTheToolRegistersTakeTheLateralPartOnTheRadius) {
  auto c = base_config();
  c.output.mode = OutputMode::kToolRegisters;
  c.output.channel_register = {-1, -1, -1, 3, 4};
  c.edge.fallback_channel = Channel::kLength;
  c.deflection = {{0, {0.0, 20.0}, {0.0, 4.0}, {0.0, 10.0}}};
  Rig r(c);
  r.measure({10.0});
  r.run_to(60.0);
  // Length: −(10 + 2); radius: −5 (the NC's radius compensation knows the side).
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kLength), -12.0, 1e-9);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kRadius), -5.0, 1e-9);
  EXPECT_NEAR(r.last_write(3), -5.0, 1e-9);
}

TEST(CreepEdge, BullNoseOffsetsRestoreTheContactOfTheWornTorus) {
  // A bull-nose mill: radius R = 5 mm, corner radius r = 1 mm, a flat of radius R − r; the laser
  // gives the corner's wear at 0/30/60/90°. For a surface with outward normal n at angle θ from
  // the tool axis the tool touches where its own outward normal is −n: on the corner at θ (on the
  // flat for θ = 0). The offsets move the tool along −n by the wear at θ; checked against the
  // worn torus itself, sampled finely: R − r and the flat drop out, and the exact recession is
  // smaller only by the second-order shift of the contact toward less worn points,
  // w'² / (2 r) with w' the wear gradient along the corner (4 µm per 30°: 0.029 µm).
  auto c = ball_config();
  c.edge.tool_shape = ToolShape::kBullNose;
  const std::array<double, 4> wear_um{4.0, 8.0, 12.0, 16.0};
  const double big_r = 5.0;
  const double r_c = 1.0;
  const double w_prime_um_per_rad = 4.0 / (30.0 * std::numbers::pi / 180.0);
  const double second_order_um = w_prime_um_per_rad * w_prime_um_per_rad / (2.0 * r_c * 1e3);
  const auto wear_at = [&](double psi_deg) {  // the core's interpolation of the support points
    const double x = std::clamp(psi_deg, 0.0, 90.0) / 30.0;
    const auto i = std::min<std::size_t>(static_cast<std::size_t>(x), 2);
    return wear_um[i] + (x - static_cast<double>(i)) * (wear_um[i + 1] - wear_um[i]);
  };
  // Support of the tool (tip at the origin, axis +Z) in direction d = −n [mm]: the corner points
  // at azimuth 0 (toward +X: the wall faces −X, the tool touches it with its +X side) and
  // engagement angle ψ; ψ = 0 is also the flat's level.
  const auto support_mm = [&](const std::array<double, 3>& n, bool worn) {
    double h = -1e9;
    for (int k = 0; k <= 90000; ++k) {
      const double psi = 0.001 * k;
      const double p = psi * std::numbers::pi / 180.0;
      const double rr = r_c - (worn ? wear_at(psi) * 1e-3 : 0.0);
      const double x = (big_r - r_c) + rr * std::sin(p);
      const double z = r_c - rr * std::cos(p);
      h = std::max(h, -(n[0] * x + n[2] * z));
    }
    return h;
  };
  for (const double theta : {0.0, 20.0, 45.0, 75.0, 90.0}) {
    SCOPED_TRACE(theta);
    const double t = theta * std::numbers::pi / 180.0;
    const std::array<double, 3> n{-std::sin(t), 0.0, std::cos(t)};  // a wall facing −X
    Rig r(c);
    r.has_normal = true;
    r.normal = n;
    r.measure({wear_um[0], wear_um[1], wear_um[2], wear_um[3]});
    r.run_to(20.0);
    const double recede_um = (support_mm(n, false) - support_mm(n, true)) * 1e3;
    EXPECT_LE(recede_um, wear_at(theta) + 1e-6);
    if (theta < 1e-9) {
      EXPECT_NEAR(recede_um, wear_at(0.0), 1e-6);  // the flat: exact
    } else {
      EXPECT_NEAR(wear_at(theta) - recede_um, second_order_um, 0.02 * second_order_um);
    }
    // The offset: −w(θ)·n, along the normal.
    EXPECT_NEAR(r.x(), -wear_at(theta) * n[0], 1e-9);
    EXPECT_NEAR(r.z(), -wear_at(theta) * n[2], 1e-9);
    EXPECT_NEAR(r.comp.channel_output_um(Channel::kY), 0.0, 1e-12);
    // The same as a ball-end mill with the same edge profile.
    auto b = c;
    b.edge.tool_shape = ToolShape::kBall;
    Rig ball(b);
    ball.has_normal = true;
    ball.normal = n;
    ball.measure({wear_um[0], wear_um[1], wear_um[2], wear_um[3]});
    ball.run_to(20.0);
    EXPECT_NEAR(ball.x(), r.x(), 1e-12);
    EXPECT_NEAR(ball.z(), r.z(), 1e-12);
  }
}

TEST(CreepDeflection, APerToolTableWinsOverTheDefault) {
  auto c = base_config();
  c.deflection = {{0, {0.0, 10.0}, {0.0, 1.0}, {0.0, 0.0}},
                  {5, {0.0, 10.0}, {0.0, 3.0}, {0.0, 0.0}}};
  Rig r(c);
  r.measure({10.0});
  r.run_to(60.0);
  EXPECT_NEAR(r.z(), -11.0, 1e-9);
  r.tool_change(5, false);
  r.measure({10.0});
  r.run_to(120.0);
  EXPECT_NEAR(r.z(), -13.0, 1e-9);
}

}  // namespace
}  // namespace nccomp::core::creep
