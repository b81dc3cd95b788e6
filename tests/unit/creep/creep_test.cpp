// Items 1 and 2 of issue 3: creeping after a measurement (path / time / rate, every profile),
// and a measurement that arrives before the creep has finished.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using testing::base_config;
using testing::Rig;

TEST(Creep, LinearOverPathStartsUncorrectedAndRampsToTheWear) {
  Rig r(base_config());
  r.run_to(100.0);
  r.measure({20.0});
  // Machining resumes uncorrected: nothing is applied at the measurement itself.
  EXPECT_NEAR(r.z(), 0.0, 1e-12);
  r.run_to(110.0);
  EXPECT_NEAR(r.z(), -20.0 * 10.0 / 50.0, 1e-9);
  r.run_to(125.0);
  EXPECT_NEAR(r.z(), -10.0, 1e-9);
  r.run_to(150.0);
  EXPECT_NEAR(r.z(), -20.0, 1e-9);
  r.run_to(170.0);
  EXPECT_NEAR(r.z(), -20.0, 1e-9);
  EXPECT_EQ(r.comp.creeps_in_progress(), 0U);
  EXPECT_NEAR(r.comp.state().committed_um[0], 20.0, 1e-12);
}

TEST(Creep, PathFromAxisPositionsWhenTheNcPublishesNoProgramPath) {
  Rig r(base_config());
  r.publish_program_path = false;
  r.run_to(30.0);
  r.measure({10.0});
  r.run_to(55.0);  // X moved 25 mm
  EXPECT_NEAR(r.z(), -5.0, 1e-9);
  EXPECT_NEAR(r.comp.cut_path_mm(), 55.0, 1e-9);
}

TEST(Creep, NoProgressWhileNotCuttingOrInterrupted) {
  Rig r(base_config());
  r.run_to(10.0);
  r.measure({10.0});
  r.run_to(20.0);
  EXPECT_NEAR(r.z(), -2.0, 1e-9);
  // Moving away to the laser and back: not cutting.
  r.cutting = false;
  r.run_to(60.0);
  EXPECT_NEAR(r.z(), -2.0, 1e-9);
  r.cutting = true;
  r.advance(0.0);  // re-anchor: the first cutting sample after the move adds nothing
  r.events.emplace_back(ProgramEvent{r.now_ns, ProgramEventKind::kInterruption, 0});
  r.step();
  r.run_to(80.0);
  EXPECT_NEAR(r.z(), -2.0, 1e-9);
  r.events.emplace_back(ProgramEvent{r.now_ns, ProgramEventKind::kResume, 0});
  r.step();
  r.advance(0.0);
  r.run_to(85.0);
  EXPECT_NEAR(r.z(), -3.0, 1e-9);
}

double ramp_at(ProfileShape shape, double u, std::vector<double> table = {}) {
  auto c = base_config();
  c.profile = shape;
  c.profile_table = std::move(table);
  c.creep_length_mm = 40.0;
  Rig r(c);
  r.measure({8.0});
  r.run_to(40.0 * u, 0.25);
  return -r.z() / 8.0;
}

TEST(Creep, EveryProfileShapeFollowsItsFormula) {
  const double pi = std::numbers::pi;
  EXPECT_NEAR(ramp_at(ProfileShape::kLinear, 0.25), 0.25, 1e-9);
  EXPECT_NEAR(ramp_at(ProfileShape::kCosine, 0.25), 0.5 * (1.0 - std::cos(pi * 0.25)), 1e-9);
  EXPECT_NEAR(ramp_at(ProfileShape::kSmoothstep, 0.25), 3 * 0.0625 - 2 * 0.015625, 1e-9);
  EXPECT_NEAR(ramp_at(ProfileShape::kTable, 0.25, {0.0, 0.8, 1.0}), 0.4, 1e-9);
  EXPECT_NEAR(ramp_at(ProfileShape::kTable, 0.75, {0.0, 0.8, 1.0}), 0.9, 1e-9);
  EXPECT_NEAR(ramp_at(ProfileShape::kStep, 0.25), 1.0, 1e-9);
}

TEST(Creep, OverTimeOfCutting) {
  auto c = base_config();
  c.creep_basis = CreepBasis::kTime;
  c.creep_time_s = 10.0;
  Rig r(c);
  r.measure({12.0});
  for (int i = 0; i < 250; ++i) r.advance(0.1, 0.01);  // 2.5 s
  EXPECT_NEAR(r.z(), -3.0, 1e-6);
  for (int i = 0; i < 1000; ++i) r.advance(0.1, 0.01);
  EXPECT_NEAR(r.z(), -12.0, 1e-9);
}

TEST(Creep, AtARatePerMinuteAndPerMillimetre) {
  auto c = base_config();
  c.creep_basis = CreepBasis::kRateTime;
  c.creep_rate_um_per_min = 2.0;  // 20 µm → 600 s
  Rig r(c);
  r.measure({20.0});
  for (int i = 0; i < 1500; ++i) r.advance(0.0, 0.1);  // 150 s
  EXPECT_NEAR(r.z(), -5.0, 1e-6);

  c.creep_basis = CreepBasis::kRatePath;
  c.creep_rate_um_per_mm = 0.5;  // 20 µm → 40 mm
  Rig p(c);
  p.measure({20.0});
  p.run_to(10.0);
  EXPECT_NEAR(p.z(), -5.0, 1e-9);
  p.run_to(40.0);
  EXPECT_NEAR(p.z(), -20.0, 1e-9);
}

// ---- item 2 ------------------------------------------------------------------------------

TEST(CreepUnfinished, SuperposeContinuesOnTheSumWithoutAKink) {
  auto c = base_config();
  c.profile = ProfileShape::kCosine;
  c.on_unfinished = UnfinishedPolicy::kSuperpose;
  Rig r(c);
  r.measure({10.0});
  const double ds = 0.05;
  r.run_to(24.95, ds);
  const double z_before = r.z();
  r.run_to(25.0, ds);
  const double z_at = r.z();
  const double slope_before = (z_at - z_before) / ds;
  r.measure({30.0});  // 10 already measured: +20, while 5 µm of the first creep remain
  EXPECT_NEAR(r.z(), z_at, 1e-12);  // no step
  r.run_to(25.05, ds);
  const double slope_after = (r.z() - z_at) / ds;
  // The first creep's slope at mid-way is −10·π/(2·50); the new cosine creep starts flat.
  EXPECT_NEAR(slope_before, -10.0 * std::numbers::pi / 100.0, 1e-3);
  EXPECT_NEAR(slope_after, slope_before, 2e-3);
  ASSERT_EQ(r.count(AlarmCode::kCreepUnfinished), 1U);
  EXPECT_EQ(r.alarms.back().severity, Severity::kInfo);
  EXPECT_NEAR(r.alarms.back().value, 5.0, 1e-9);  // the remaining part, logged
  r.run_to(75.0);
  EXPECT_NEAR(r.z(), -30.0, 1e-9);
  EXPECT_NEAR(r.last_write(10), 0.0, 0.0);  // no warning raised
}

TEST(CreepUnfinished, LinearSuperposeAddsTheSlopes) {
  Rig r(base_config());
  r.measure({10.0});
  r.run_to(20.0);
  r.measure({30.0});
  r.run_to(30.0);
  // 10 µm over 50 mm plus 20 µm over 50 mm from s = 20.
  EXPECT_NEAR(r.z(), -(10.0 * 30.0 / 50.0 + 20.0 * 10.0 / 50.0), 1e-9);
  r.run_to(70.0);
  EXPECT_NEAR(r.z(), -30.0, 1e-9);
}

TEST(CreepUnfinished, WarnRaisesTheWarningRegister) {
  auto c = base_config();
  c.on_unfinished = UnfinishedPolicy::kWarn;
  Rig r(c);
  r.measure({10.0});
  r.run_to(20.0);
  EXPECT_NEAR(r.last_write(10), 0.0, 0.0);
  r.measure({15.0});
  EXPECT_NEAR(r.last_write(10), 1.0, 0.0);
  ASSERT_EQ(r.count(AlarmCode::kCreepUnfinished), 1U);
  EXPECT_EQ(r.alarms.back().severity, Severity::kWarning);
  r.run_to(100.0);
  EXPECT_NEAR(r.z(), -15.0, 1e-9);  // still applied
}

TEST(CreepUnfinished, AlarmStopsApplyingAndFreezesTheOffset) {
  auto c = base_config();
  c.on_unfinished = UnfinishedPolicy::kAlarm;
  Rig r(c);
  r.measure({10.0});
  r.run_to(20.0);
  r.measure({15.0});
  EXPECT_TRUE(r.comp.halted());
  EXPECT_NEAR(r.last_write(11), 1.0, 0.0);
  r.run_to(80.0);
  EXPECT_NEAR(r.z(), -4.0, 1e-9);                         // frozen where it was
  EXPECT_NEAR(r.comp.state().measured_um[0], 10.0, 0.0);  // the new one was not applied
  ASSERT_FALSE(r.records.empty());
  EXPECT_NEAR(r.records.back().measured_um, 15.0, 0.0);  // but logged
  r.comp.clear_alarm();
  r.run_to(110.0);  // the creep resumes where it was frozen: 30 mm more
  EXPECT_NEAR(r.z(), -10.0, 1e-9);
  EXPECT_NEAR(r.last_write(11), 0.0, 0.0);
}

TEST(CreepUnfinished, BeyondTheSlotsTheOldestIsFoldedWithoutAStep) {
  auto c = base_config();
  c.max_creeps = 2;
  Rig r(c);
  r.measure({10.0});
  r.run_to(10.0);
  r.measure({20.0});
  r.run_to(20.0);
  const double z = r.z();
  r.measure({30.0});
  EXPECT_NEAR(r.z(), z, 1e-12);
  EXPECT_EQ(r.comp.counters().creeps_folded, 1U);
  EXPECT_EQ(r.comp.creeps_in_progress(), 2U);
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), -30.0, 1e-9);
}

// ---- predictive creeping (beyond the seed) ------------------------------------------------

TEST(CreepPredict, FeedsTheFittedWearRateBetweenMeasurementsAndEachMeasurementCorrectsIt) {
  auto c = base_config();
  c.predict.enabled = true;
  c.predict.window = 2;
  Rig r(c);
  r.run_to(100.0);
  r.measure({2.0});  // true wear 0.02 µm/mm of path
  r.run_to(180.0);
  EXPECT_NEAR(r.z(), -2.0, 1e-9);  // one measurement: no prediction yet (break-in)
  r.run_to(200.0);
  r.measure({4.0});
  r.run_to(250.0);
  EXPECT_NEAR(r.z(), -(4.0 + 0.02 * 50.0), 1e-9);  // the creep is done, the prediction grows
  r.run_to(300.0);
  const double z = r.z();
  EXPECT_NEAR(z, -6.0, 1e-9);
  r.measure({6.0});  // exactly as predicted: nothing left to creep
  EXPECT_NEAR(r.z(), z, 1e-12);
  EXPECT_EQ(r.comp.creeps_in_progress(), 0U);
  r.run_to(325.0);
  EXPECT_NEAR(r.z(), -6.5, 1e-9);
  r.run_to(400.0);
  r.measure({7.0});  // slower than predicted (8): the difference creeps out
  EXPECT_NEAR(r.z(), -8.0, 1e-9);
  r.run_to(425.0);
  // Half of the −1 µm correction, and the new rate (6 → 7 over 100 mm) predicts 0.25 µm.
  EXPECT_NEAR(r.z(), -(8.0 - 0.5 + 0.25), 1e-9);
}

TEST(CreepPredict, ThePredictionIsCapped) {
  auto c = base_config();
  c.predict.enabled = true;
  c.predict.window = 2;
  c.predict.max_um = 1.5;
  Rig r(c);
  r.run_to(100.0);
  r.measure({2.0});
  r.run_to(200.0);
  r.measure({4.0});
  r.run_to(500.0);
  EXPECT_NEAR(r.z(), -5.5, 1e-9);
}

TEST(CreepRecords, OneToolWearRowPerSupportPoint) {
  auto c = base_config();
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 4;
  Rig r(c);
  r.run_to(12.0);
  r.measure({1.0, 2.0, 3.0, 4.0});
  ASSERT_EQ(r.records.size(), 4U);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(r.records[i].kind, MeasurementKind::kToolWear);
    EXPECT_EQ(r.records[i].point, static_cast<int>(i));
    EXPECT_NEAR(r.records[i].angle_deg, 30.0 * static_cast<double>(i), 1e-12);
    EXPECT_NEAR(r.records[i].measured_um, static_cast<double>(i + 1), 0.0);
    EXPECT_NEAR(r.records[i].path_mm, 12.0, 1e-9);
    EXPECT_EQ(r.records[i].tool, 1);
  }
}

}  // namespace
}  // namespace nccomp::core::creep
