// Items 1 and 2 of issue 3: creeping after a measurement (path / time / rate, every profile),
// and a measurement that arrives before the creep has finished.
#include <gtest/gtest.h>

#include <algorithm>
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

// What the offset does around a second measurement that arrives while the first creep is half
// done: its slope just before and just after (numerically, over one fine step of the creep clock),
// its value at the measurement, whether it then rises monotonically, and where it ends.
struct AroundASecondMeasurement {
  double slope_before{0.0};  // µm per mm of path or per s of cutting time
  double slope_after{0.0};
  double mean_slope_new{0.0};  // Δ / span of the new increment: the size of a kink
  double step_at_measurement{0.0};
  double final_um{0.0};
  bool monotonic{true};
  double max_um{0.0};
};

AroundASecondMeasurement superpose_at_half(ProfileShape shape, CreepBasis basis) {
  auto c = base_config();
  c.profile = shape;
  if (shape == ProfileShape::kTable) c.profile_table = {0.0, 0.5, 0.9, 1.0};
  c.creep_basis = basis;
  c.creep_length_mm = 50.0;
  c.creep_time_s = 10.0;
  c.creep_rate_um_per_mm = 0.5;    // 10 µm → 20 mm, 20 µm → 40 mm
  c.creep_rate_um_per_min = 60.0;  // 10 µm → 10 s, 20 µm → 20 s
  c.on_unfinished = UnfinishedPolicy::kSuperpose;
  const bool timed = basis == CreepBasis::kTime || basis == CreepBasis::kRateTime;
  const double half = basis == CreepBasis::kRatePath ? 10.0 : timed ? 5.0 : 25.0;
  const double new_span = basis == CreepBasis::kPath       ? 50.0
                          : basis == CreepBasis::kTime     ? 10.0
                          : basis == CreepBasis::kRatePath ? 40.0
                                                           : 20.0;
  Rig r(c);
  const auto clock = [&] {
    return timed ? r.comp.state().creep_time_s : r.comp.state().creep_path_mm;
  };
  const auto offset = [&] { return -r.z(); };
  // One fine step: 0.01 mm of path (path bases) or 1 ms of cutting (time bases).
  const auto fine = [&] { r.advance(0.01, timed ? 0.001 : 0.01); };
  r.measure({10.0});
  while (clock() < half - 1e-9) fine();
  const double c0 = clock();
  const double z0 = offset();
  fine();
  const double c1 = clock();
  const double z1 = offset();
  r.measure({30.0});  // 20 µm more while about half of the first 10 µm still creeps
  const double cm = clock();
  const double zm = offset();
  fine();
  const double c2 = clock();
  const double z2 = offset();
  AroundASecondMeasurement a;
  a.slope_before = (z1 - z0) / (c1 - c0);
  // The measurement step itself may advance the clock (the rig's 1 ms): the slope after is taken
  // from there.
  a.slope_after = (z2 - zm) / (c2 - cm);
  a.step_at_measurement = zm - (z1 + a.slope_before * (cm - c1));
  a.mean_slope_new = 20.0 / new_span;
  double prev = z2;
  a.max_um = z2;
  const double end = half + new_span + 5.0;
  while (clock() < end) {
    r.advance(0.1, timed ? 0.01 : 0.1);
    const double z = offset();
    if (z < prev - 1e-12) a.monotonic = false;
    a.max_um = std::max(a.max_um, z);
    prev = z;
  }
  a.final_um = offset();
  EXPECT_EQ(r.count(AlarmCode::kCreepUnfinished), 1U);
  EXPECT_EQ(r.comp.creeps_in_progress(), 0U);
  return a;
}

void expect_no_kink(ProfileShape shape, CreepBasis basis, const char* what) {
  SCOPED_TRACE(what);
  const auto a = superpose_at_half(shape, basis);
  // The first creep is half done: it moves.
  EXPECT_GT(a.slope_before, 0.25 * a.mean_slope_new);
  // No step, and the slope after the measurement equals the slope before it: within 1 % of the
  // new increment's mean slope (a kink of the plain linear profile would be 100 %).
  EXPECT_NEAR(a.step_at_measurement, 0.0, 1e-6);
  EXPECT_NEAR(a.slope_after, a.slope_before, 0.01 * a.mean_slope_new);
  // It ends exactly on the remainder plus the new wear (= the new measurement), rising
  // monotonically and never beyond it.
  EXPECT_NEAR(a.final_um, 30.0, 1e-9);
  EXPECT_TRUE(a.monotonic);
  EXPECT_LE(a.max_um, 30.0 + 1e-9);
}

TEST(CreepUnfinished, SuperposeKeepsTheSlopeForEveryProfileOverPath) {
  expect_no_kink(ProfileShape::kLinear, CreepBasis::kPath, "linear");
  expect_no_kink(ProfileShape::kCosine, CreepBasis::kPath, "cosine");
  expect_no_kink(ProfileShape::kSmoothstep, CreepBasis::kPath, "smoothstep");
  expect_no_kink(ProfileShape::kTable, CreepBasis::kPath, "table");
}

TEST(CreepUnfinished, SuperposeKeepsTheSlopeForEveryProfileOverTime) {
  expect_no_kink(ProfileShape::kLinear, CreepBasis::kTime, "linear");
  expect_no_kink(ProfileShape::kCosine, CreepBasis::kTime, "cosine");
  expect_no_kink(ProfileShape::kSmoothstep, CreepBasis::kTime, "smoothstep");
  expect_no_kink(ProfileShape::kTable, CreepBasis::kTime, "table");
}

TEST(CreepUnfinished, SuperposeKeepsTheSlopeForEveryProfileAtARate) {
  for (const auto basis : {CreepBasis::kRatePath, CreepBasis::kRateTime}) {
    SCOPED_TRACE(basis == CreepBasis::kRatePath ? "per mm" : "per minute");
    expect_no_kink(ProfileShape::kLinear, basis, "linear");
    expect_no_kink(ProfileShape::kCosine, basis, "cosine");
    expect_no_kink(ProfileShape::kSmoothstep, basis, "smoothstep");
    expect_no_kink(ProfileShape::kTable, basis, "table");
  }
}

TEST(CreepUnfinished, LinearSuperposeEasesTheNewIncrementIn) {
  // Linear, 10 µm over 50 mm from s = 0, then +20 µm at s = 25: the first creep keeps its slope
  // 0.2 µm/mm, the new 20 µm enter with zero slope (eased over 0.2 · 50 = 10 mm) and then rise
  // at 20 / (50 · (1 − 0.1)) = 0.444 µm/mm, so the sum still ends at 30 µm at s = 75.
  Rig r(base_config());
  r.measure({10.0});
  r.run_to(25.0);
  r.measure({30.0});
  r.run_to(30.0);  // u = 0.1 of the new creep: φ = (1/0.9)·0.1²/0.4 = 0.02778
  EXPECT_NEAR(r.z(), -(10.0 * 30.0 / 50.0 + 20.0 * 0.1 * 0.1 / (0.9 * 0.4)), 1e-9);
  r.run_to(50.0);  // u = 0.5: φ = (0.5 − 0.1) / 0.9; the first creep has finished
  EXPECT_NEAR(r.z(), -(10.0 + 20.0 * 0.4 / 0.9), 1e-9);
  r.run_to(75.0);
  EXPECT_NEAR(r.z(), -30.0, 1e-9);
  EXPECT_EQ(r.comp.creeps_in_progress(), 0U);
  // A creep that starts while nothing moves keeps the plain profile (tested above: −4 µm at
  // 10 of 50 mm for 20 µm, Creep.LinearOverPathStartsUncorrectedAndRampsToTheWear).
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

TEST(CreepUnfinished, BeyondTheSlotsTheOldestIsFoldedWithoutAStepOrAKink) {
  auto c = base_config();
  c.max_creeps = 2;
  Rig r(c);
  r.measure({10.0});
  r.run_to(10.0);
  r.measure({20.0});
  r.run_to(19.99, 0.01);
  const double z0 = r.z();
  r.run_to(20.0, 0.01);
  const double z1 = r.z();
  r.measure({30.0});  // both slots busy: the oldest (10 µm, 40 % fed) is folded into the new one
  EXPECT_NEAR(r.z(), z1, 1e-12);
  EXPECT_EQ(r.comp.counters().creeps_folded, 1U);
  EXPECT_EQ(r.comp.creeps_in_progress(), 2U);
  r.run_to(20.01, 0.01);
  const double slope_before = (z1 - z0) / 0.01;
  const double slope_after = (r.z() - z1) / 0.01;
  // Before: 10/50 (first, linear) + the second's eased slope at u = 0.2 (20·(1/0.9)/50).
  EXPECT_NEAR(-slope_before, 0.2 + 10.0 / (0.9 * 50.0), 2e-3);
  // The folded creep's 0.2 µm/mm is carried into the new one and fades out: no kink.
  EXPECT_NEAR(slope_after, slope_before, 0.01 * 16.0 / 50.0);
  double prev = -r.z();
  bool monotonic = true;
  while (r.program_path_mm < 200.0) {
    r.advance(0.5);
    monotonic = monotonic && -r.z() >= prev - 1e-12;
    prev = -r.z();
    EXPECT_LE(prev, 30.0 + 1e-9);
  }
  EXPECT_TRUE(monotonic);
  EXPECT_NEAR(r.z(), -30.0, 1e-9);
}

TEST(CreepUnfinished, AFoldAgainstTheMotionStaysWithinWhatTheOldCreepWouldHaveFed) {
  // The only slot is busy and the new measurement finds less wear than is already fed in (noise
  // within noise_um): the offset must turn around. The carried slope fades out over 0.2·50 mm
  // (no kink): the offset moves on by at most s·l/2 = 0.2·10/2 = 1 µm, never beyond the folded
  // creep's own target, then settles exactly on the measurement.
  auto c = base_config();
  c.max_creeps = 1;
  c.tool_life.noise_um = 5.0;
  Rig r(c);
  r.measure({10.0});
  r.run_to(39.99, 0.01);
  const double z0 = -r.z();
  r.run_to(40.0, 0.01);  // 8 µm fed, 2 µm left at 0.2 µm/mm
  const double z_fold = -r.z();
  r.measure({7.0});
  EXPECT_NEAR(-r.z(), z_fold, 1e-12);
  r.run_to(40.01, 0.01);
  EXPECT_NEAR((-r.z() - z_fold) / 0.01, (z_fold - z0) / 0.01, 2e-3);  // 0.2 µm/mm on both sides
  double peak = z_fold;
  while (r.program_path_mm < 120.0) {
    r.advance(0.01);
    peak = std::max(peak, -r.z());
  }
  EXPECT_GT(peak, z_fold + 0.5);         // it kept moving up for a while (its slope fades out) ...
  EXPECT_LE(peak, z_fold + 1.0 + 1e-9);  // ... by at most s·l/2
  EXPECT_NEAR(-r.z(), 7.0, 1e-9);
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
  // The prediction starts; its rate blends from 0 to the fitted 0.02 µm/mm over 0.2 of the last
  // interval (100 mm): grown = 0.02·p − 0.02·20/2 after p = 20 mm.
  r.run_to(210.0);
  EXPECT_NEAR(r.z(), -(2.0 + 2.0 * 10.0 / 50.0 + 0.02 * 10.0 * 10.0 / 40.0), 1e-9);
  r.run_to(250.0);
  EXPECT_NEAR(r.z(), -(4.0 + 0.02 * 50.0 - 0.2), 1e-9);  // the creep is done, the prediction grows
  r.run_to(300.0);
  const double z = r.z();
  EXPECT_NEAR(z, -5.8, 1e-9);
  r.measure({6.0});  // 0.2 µm more than predicted: it creeps in, entered with zero slope
  EXPECT_NEAR(r.z(), z, 1e-12);
  EXPECT_EQ(r.comp.creeps_in_progress(), 1U);
  r.run_to(325.0);
  // Rate unchanged (0.02): 0.5 predicted; the 0.2 µm creep at u = 0.5: φ = 0.4 / 0.9.
  EXPECT_NEAR(r.z(), -(5.8 + 0.2 * 0.4 / 0.9 + 0.5), 1e-9);
  r.run_to(400.0);
  EXPECT_NEAR(r.z(), -8.0, 1e-9);
  r.measure({7.0});  // slower than predicted (8): the difference creeps out
  EXPECT_NEAR(r.z(), -8.0, 1e-9);
  r.run_to(425.0);
  // Half of the −1 µm correction (eased: φ = 0.4/0.9); the new rate (6 → 7 over 100 mm,
  // 0.01 µm/mm) is blended in from 0.02 over 20 mm: 0.01·25 + 0.01·20/2 = 0.35 µm.
  EXPECT_NEAR(r.z(), -(8.0 - 0.4 / 0.9 + 0.35), 1e-9);
}

TEST(CreepPredict, TheSlopeOfTheOffsetIsContinuousAtAMeasurementWhilePredicting) {
  auto c = base_config();
  c.predict.enabled = true;
  c.predict.window = 2;
  Rig r(c);
  r.run_to(100.0);
  r.measure({2.0});
  r.run_to(200.0);
  r.measure({4.0});
  r.run_to(290.0);
  r.measure({6.5});  // the creep of this one is still running at the next
  r.run_to(319.99, 0.01);
  const double z0 = r.z();
  r.run_to(320.0, 0.01);
  const double z1 = r.z();
  // The rate refit drops from 2.5/90 = 0.0278 to 0.5/30 = 0.0167 µm/mm.
  r.measure({7.0});
  EXPECT_NEAR(r.z(), z1, 1e-12);
  r.run_to(320.01, 0.01);
  const double before = (z1 - z0) / 0.01;
  const double after = (r.z() - z1) / 0.01;
  EXPECT_GT(-before, 0.02);  // the creep and the prediction both move
  EXPECT_NEAR(after, before, 1e-3);
  // Without the blend the prediction's slope alone would jump by the rate change (0.011).
  EXPECT_NEAR(r.comp.state().rate_prev_um_per_mm[0], 2.5 / 90.0, 1e-12);
  EXPECT_NEAR(r.comp.state().rate_um_per_mm[0], 0.5 / 30.0, 1e-12);
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
