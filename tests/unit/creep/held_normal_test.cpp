// Item 3 of issue 3 across interruptions: while no surface normal is known (not cutting, an
// interruption, the trip to the laser, a restart) the last known normal stays in force, so the
// split of the correction between the radius / length (or X/Y/Z) registers does not change and
// the offset in force at the surface does not jump when the tool cuts again. Before, the whole
// correction moved onto the fallback register during the trip and was split back only after the
// tool resumed (one NC latency too late: the 0.3 µm steps of the e2e demo).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using testing::base_config;
using testing::Rig;

constexpr std::uint16_t kRadiusReg = 3;
constexpr std::uint16_t kLengthReg = 4;
const double kCos30 = std::sqrt(0.75);

/// Ball-end mill, 0/30/60/90°, the NC's normal with each sample, radius / length wear
/// registers (sign −1, the mean on length without a normal), linear creep over 50 mm.
CreepConfig registers_config() {
  auto c = base_config();
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 4;
  c.edge.normal_source = NormalSource::kAxisSample;
  c.edge.fallback_channel = Channel::kLength;
  c.output.mode = OutputMode::kToolRegisters;
  c.output.channel_register = {-1, -1, -1, kRadiusReg, kLengthReg};
  c.output.tool_register_sign = -1.0;
  c.creep_length_mm = 50.0;
  return c;
}

double radius(const Rig& r) { return r.comp.channel_output_um(Channel::kRadius); }
double length(const Rig& r) { return r.comp.channel_output_um(Channel::kLength); }

std::size_t offset_writes(const Rig& r) {
  std::size_t n = 0;
  for (const auto& w : r.writes) {
    n += w.register_index == kRadiusReg || w.register_index == kLengthReg ? 1U : 0U;
  }
  return n;
}

/// The NC's trip to the laser: an interruption, `cycles` samples without a normal and not
/// cutting while the tool moves away and back (program path unchanged), a laser measurement
/// half-way, the resume.
void laser_trip(Rig& r, int cycles, std::vector<double> wear_um, double expect_radius,
                double expect_length) {
  r.events.emplace_back(ProgramEvent{r.now_ns, ProgramEventKind::kInterruption, 0});
  r.cutting = false;
  r.has_normal = false;
  const auto home = r.pos_mm;
  for (int k = 0; k < cycles; ++k) {
    r.now_ns += from_seconds(0.004);
    r.pos_mm[2] = home[2] + (k < cycles / 2 ? 2.0 * (k + 1) : 2.0 * (cycles - k - 1));
    r.sample();
    if (k == cycles / 2) r.measure(wear_um);
    EXPECT_EQ(radius(r), expect_radius) << "cycle " << k << " of the trip";
    EXPECT_EQ(length(r), expect_length) << "cycle " << k << " of the trip";
  }
  r.pos_mm = home;
  r.events.emplace_back(ProgramEvent{r.now_ns, ProgramEventKind::kResume, 0});
  r.cutting = true;
  r.has_normal = true;
}

TEST(CreepHeldNormal, TheRegistersStayConstantAcrossALaserTripWithoutNormals) {
  Rig r(registers_config());
  r.has_normal = true;
  r.normal = {0.5, 0.0, kCos30};  // 30°: the support point of 8 µm
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);  // 8 µm over 50 mm, 20 mm done: c = 3.2 µm
  EXPECT_NEAR(r.comp.correction_um(), 3.2, 1e-12);
  const double r0 = radius(r);
  const double l0 = length(r);
  EXPECT_NEAR(r0, -3.2 * 0.5, 1e-12);
  EXPECT_NEAR(l0, -3.2 * kCos30, 1e-12);
  const std::size_t writes_before = offset_writes(r);
  // The trip: 50 cycles, the laser measures 2 µm more at 30° half-way (superposed).
  laser_trip(r, 50, {6.0, 10.0, 14.0, 18.0}, r0, l0);
  EXPECT_EQ(offset_writes(r), writes_before);  // nothing sent: the NC holds what it held
  EXPECT_NEAR(r.comp.engagement_angle_deg(), 30.0, 1e-9);  // the held normal's angle
  EXPECT_EQ(r.comp.creeps_in_progress(), 2U);
  // Cutting again at the same point with its normal: no jump, then at most the creep's slope.
  // Bound per 0.5 mm sample along the normal: the first creep h1·Δs/L = 8 · 0.5 / 50 plus the
  // superposed, eased one 1.11 · h2·Δs/L = 1.11 · 2 · 0.5 / 50.
  const double bound_um = 8.0 * 0.5 / 50.0 + 1.0 / 0.9 * 2.0 * 0.5 / 50.0;
  double prev_r = r0;
  double prev_l = l0;
  double largest = 0.0;
  for (int k = 0; k < 120; ++k) {
    r.advance(0.5);
    const double d = std::hypot(radius(r) - prev_r, length(r) - prev_l);
    if (k == 0) {
      EXPECT_EQ(d, 0.0);  // the sample that re-anchors the path: nothing moved
    }
    largest = std::max(largest, d);
    prev_r = radius(r);
    prev_l = length(r);
  }
  EXPECT_LE(largest, bound_um + 1e-12);
  EXPECT_GT(largest, 0.8 * 8.0 * 0.5 / 50.0);  // it does creep
  // 60 mm after the resume both creeps are done: 10 µm at 30°.
  EXPECT_NEAR(radius(r), -10.0 * 0.5, 1e-9);
  EXPECT_NEAR(length(r), -10.0 * kCos30, 1e-9);
}

TEST(CreepHeldNormal, BeforeTheFirstNormalTheFallbackAfterItTheLastNormal) {
  Rig r(registers_config());
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(60.0);
  // No normal yet: the mean (10 µm) on length.
  EXPECT_TRUE(std::isnan(r.comp.engagement_angle_deg()));
  EXPECT_NEAR(length(r), -10.0, 1e-9);
  EXPECT_NEAR(radius(r), 0.0, 1e-12);
  EXPECT_FALSE(r.comp.state().normal_held);
  r.has_normal = true;
  r.normal = {std::sqrt(0.75), 0.0, 0.5};  // 60°: 12 µm
  r.advance(0.5);
  EXPECT_NEAR(radius(r), -12.0 * kCos30, 1e-9);
  EXPECT_NEAR(length(r), -12.0 * 0.5, 1e-9);
  // The normal is gone (a non-cutting move, say): the 60° split stays.
  r.has_normal = false;
  r.cutting = false;
  for (int k = 0; k < 10; ++k) r.advance(0.5);
  EXPECT_NEAR(r.comp.engagement_angle_deg(), 60.0, 1e-9);
  EXPECT_NEAR(radius(r), -12.0 * kCos30, 1e-9);
  EXPECT_NEAR(length(r), -12.0 * 0.5, 1e-9);
  // A new normal is taken at once.
  r.has_normal = true;
  r.cutting = true;
  r.normal = {0.0, 0.0, 1.0};  // the floor: 4 µm at the tip, on length
  r.advance(0.5);
  EXPECT_NEAR(radius(r), 0.0, 1e-12);
  EXPECT_NEAR(length(r), -4.0, 1e-9);
}

TEST(CreepHeldNormal, ANormalFromTheToolpathIsHeldWhereTheProgramPositionIsUnknown) {
  auto c = registers_config();
  c.edge.normal_source = NormalSource::kToolpath;
  c.toolpath = {true, false, {{0.0, {0.5, 0.0, kCos30}}, {100.0, {0.5, 0.0, kCos30}}}};
  Rig r(c);
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(60.0);
  EXPECT_NEAR(radius(r), -4.0, 1e-9);
  r.publish_program_path = false;  // the NC stops publishing it
  for (int k = 0; k < 10; ++k) r.advance(0.5);
  EXPECT_NEAR(radius(r), -4.0, 1e-9);
  EXPECT_NEAR(length(r), -8.0 * kCos30, 1e-9);
}

TEST(CreepHeldNormal, ARestartKeepsTheSplitTheNcHolds) {
  const auto c = registers_config();
  Rig a(c);
  a.has_normal = true;
  a.normal = {0.5, 0.0, kCos30};
  a.measure({4.0, 8.0, 12.0, 16.0});
  a.run_to(30.0);
  const CreepState saved = a.comp.export_state();
  ASSERT_TRUE(saved.normal_held);
  EXPECT_NEAR(saved.held_normal[0], 0.5, 1e-12);
  // The daemon restarts while the NC stands still (no normal): the first values it sends are
  // the ones the NC holds, not the whole correction on the length register.
  Rig b(c);
  b.comp.import_state(saved);
  b.cutting = false;
  b.sample();
  EXPECT_EQ(radius(b), saved.channel_output_um[static_cast<std::size_t>(Channel::kRadius)]);
  EXPECT_EQ(length(b), saved.channel_output_um[static_cast<std::size_t>(Channel::kLength)]);
  EXPECT_NEAR(b.last_write(kRadiusReg), -4.8 * 0.5, 1e-12);
  EXPECT_NEAR(b.last_write(kLengthReg), -4.8 * kCos30, 1e-12);
  // A state whose held normal is not a unit vector is refused.
  CreepState bad = saved;
  bad.held_normal = {0.5, 0.0, 0.5};
  Rig d(c);
  EXPECT_THROW(d.comp.import_state(bad), std::invalid_argument);
}

TEST(CreepHeldNormal, ASisterStartsWithTheLastNormal) {
  auto c = registers_config();
  c.entry.sister_offset_um = 5.0;
  c.entry.sister_length_mm = 10.0;
  Rig r(c);
  r.has_normal = true;
  r.normal = {0.5, 0.0, kCos30};
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(60.0);
  r.has_normal = false;
  r.cutting = false;
  r.advance(0.0);
  r.tool_change(2, true);
  r.advance(0.0);  // 10 ms later (the limiter's rate needs time to move)
  // The sister starts 5 µm off the surface along the held normal (30°): −(−5)·(sin, cos).
  EXPECT_TRUE(r.comp.state().normal_held);
  EXPECT_NEAR(radius(r), 5.0 * 0.5, 1e-9);
  EXPECT_NEAR(length(r), 5.0 * kCos30, 1e-9);
}

TEST(CreepHeldNormal, WithNormalSourceNoneNothingIsHeld) {
  auto c = registers_config();
  c.edge.normal_source = NormalSource::kNone;
  Rig r(c);
  r.has_normal = true;  // published, but not to be used
  r.normal = {0.5, 0.0, kCos30};
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(60.0);
  EXPECT_FALSE(r.comp.state().normal_held);
  EXPECT_NEAR(length(r), -10.0, 1e-9);
  EXPECT_NEAR(radius(r), 0.0, 1e-12);
}

}  // namespace
}  // namespace nccomp::core::creep
