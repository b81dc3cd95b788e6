// Items 4 and 5 of issue 3: measurement interval (path, time, adaptive, material) and tool life
// (limit → sister requested, excessive increment, broken or mis-measured → nothing applied).
#include <gtest/gtest.h>

#include <cmath>

#include "tests/support/alloc_counter.hpp"
#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using testing::base_config;
using testing::Rig;

TEST(CreepInterval, ByPathRaisesMeasurementDueAndAMeasurementClearsIt) {
  auto c = base_config();
  c.interval.basis = IntervalBasis::kPath;
  c.interval.interval_mm = 100.0;
  Rig r(c);
  r.run_to(99.5);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 0U);
  EXPECT_NEAR(r.last_write(12), 0.0, 0.0);
  r.run_to(100.0);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 1U);
  EXPECT_NEAR(r.last_write(12), 1.0, 0.0);
  r.run_to(150.0);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 1U);  // raised once
  r.measure({5.0});
  EXPECT_NEAR(r.last_write(12), 0.0, 0.0);
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), 250.0, 1e-9);
  r.run_to(250.0);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 2U);
}

TEST(CreepInterval, ByCuttingTime) {
  auto c = base_config();
  c.interval.basis = IntervalBasis::kTime;
  c.interval.interval_s = 60.0;
  Rig r(c);
  for (int i = 0; i < 5990; ++i) r.advance(0.1, 0.01);  // 59.9 s
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 0U);
  for (int i = 0; i < 20; ++i) r.advance(0.1, 0.01);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 1U);
}

TEST(CreepInterval, AdaptiveShortensWhenWearGrowsFaster) {
  auto c = base_config();
  c.interval.basis = IntervalBasis::kAdaptive;
  c.interval.target_increment_um = 5.0;
  c.interval.min_interval_mm = 20.0;
  c.interval.max_interval_mm = 500.0;
  Rig r(c);
  // New tool, no rate yet: the minimum interval.
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), 20.0, 1e-9);
  r.run_to(100.0);
  r.measure({10.0});  // 0.1 µm/mm from the new tool's zero
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), 100.0 + 5.0 / 0.1, 1e-9);
  r.run_to(150.0);
  r.measure({20.0});  // last rate 0.2 µm/mm
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), 150.0 + 25.0, 1e-9);
  r.run_to(175.0);
  r.measure({20.5});  // slow: 0.02 µm/mm → 250 mm
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), 175.0 + 250.0, 1e-9);
  r.run_to(425.0);
  r.measure({20.5});  // no growth: the maximum
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), 425.0 + 500.0, 1e-9);
}

TEST(CreepInterval, ByMaterialRemoved) {
  auto c = base_config();
  c.interval.basis = IntervalBasis::kMaterial;
  c.interval.removal_mm3_per_mm = 0.5;
  c.interval.interval_mm3 = 25.0;
  Rig r(c);
  r.run_to(49.5);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 0U);
  r.run_to(50.0);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 1U);
}

TEST(CreepInterval, ByMaterialRemovedFromTheToolpathCrossSections) {
  // a_e·a_p per segment from the toolpath file: 0.5 mm² up to 100 mm, 2 mm² up to 200 mm,
  // 0.25 mm² up to 300 mm (the last row ends the table); 0.1 mm² outside it.
  auto c = base_config();
  c.interval.basis = IntervalBasis::kMaterial;
  c.interval.removal_source = RemovalSource::kToolpath;
  c.interval.removal_mm3_per_mm = 0.1;
  c.interval.interval_mm3 = 100.0;
  c.toolpath = {false,
                true,
                {{0.0, {0.0, 0.0, 1.0}, 0.5},
                 {100.0, {0.0, 0.0, 1.0}, 2.0},
                 {200.0, {0.0, 0.0, 1.0}, 0.25},
                 {300.0, {0.0, 0.0, 1.0}, 0.0}}};
  Rig r(c);
  r.run_to(100.0);
  EXPECT_NEAR(r.comp.removed_mm3(), 50.0, 1e-9);
  // 100 mm³ after 100 + 50 / 2 = 125 mm (a constant 0.5 mm² would say 200 mm).
  r.run_to(124.5);
  EXPECT_NEAR(r.comp.removed_mm3(), 99.0, 1e-9);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 0U);
  r.run_to(125.0);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 1U);
  EXPECT_NEAR(r.last_write(12), 1.0, 0.0);
  r.run_to(130.0);
  r.measure({3.0});  // at 110 mm³: the next at 210 mm³ = 50 + 2·(p − 100) → p = 180 mm
  EXPECT_NEAR(r.last_write(12), 0.0, 0.0);
  EXPECT_NEAR(r.comp.next_measurement_removed_mm3(), 210.0, 1e-9);
  EXPECT_TRUE(std::isinf(r.comp.next_measurement_path_mm()));
  r.run_to(179.5);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 1U);
  r.run_to(180.0);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 2U);
  // A sample step across a segment boundary counts each segment's own cross-section:
  // 180 → 260 mm = 20·2 + 60·0.25.
  const double v0 = r.comp.removed_mm3();
  r.advance(80.0);
  EXPECT_NEAR(r.comp.removed_mm3() - v0, 40.0 + 15.0, 1e-9);
  // Beyond the table: the constant 0.1 mm² (260 → 300 at 0.25, then 300 → 350 at 0.1).
  r.run_to(350.0, 10.0);
  EXPECT_NEAR(r.comp.removed_mm3() - v0, 55.0 + 10.0 + 5.0, 1e-9);
  // Without a program path (axis positions only) the constant is all there is.
  r.publish_program_path = false;
  r.advance(0.0);  // re-anchor
  r.advance(10.0);
  EXPECT_NEAR(r.comp.removed_mm3() - v0, 70.0 + 1.0, 1e-9);
  // Going back along the program (a restart further back) removes nothing.
  r.publish_program_path = true;
  r.advance(0.0);  // re-anchor on the program path (360 mm)
  r.program_path_mm = 100.0;
  r.advance(0.0);
  EXPECT_NEAR(r.comp.removed_mm3() - v0, 71.0, 1e-9);
  r.advance(4.0);  // and then from 100 mm on at 2 mm² again
  EXPECT_NEAR(r.comp.removed_mm3() - v0, 79.0, 1e-9);
  // The volume belongs to the tool: a new tool starts from zero.
  r.tool_change(2, false);
  EXPECT_NEAR(r.comp.removed_mm3(), 0.0, 0.0);
}

// ---- item 5 ------------------------------------------------------------------------------

TEST(CreepToolLife, BeyondTheLimitTheSisterIsRequested) {
  auto c = base_config();
  c.tool_life.wear_limit_um = 30.0;
  Rig r(c);
  r.measure({20.0});
  EXPECT_NEAR(r.last_write(13), 0.0, 0.0);
  r.run_to(100.0);
  r.measure({31.0});
  EXPECT_NEAR(r.last_write(13), 1.0, 0.0);
  EXPECT_EQ(r.count(AlarmCode::kToolLifeReached), 1U);
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), -31.0, 1e-9);  // still compensated until the change
  r.tool_change(2, true);
  EXPECT_NEAR(r.last_write(13), 0.0, 0.0);
}

TEST(CreepToolLife, ExcessiveIncrementStopsAndAppliesNothing) {
  auto c = base_config();
  c.tool_life.excessive_increment_um = 15.0;
  c.tool_life.on_excessive = ExcessivePolicy::kStop;
  Rig r(c);
  r.measure({10.0});
  r.run_to(100.0);
  r.measure({26.0});
  EXPECT_TRUE(r.comp.halted());
  EXPECT_EQ(r.count(AlarmCode::kToolExcessivelyWorn), 1U);
  EXPECT_EQ(r.alarms.back().severity, Severity::kAlarm);
  EXPECT_NEAR(r.last_write(11), 1.0, 0.0);
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), -10.0, 1e-9);
}

TEST(CreepToolLife, ExcessiveIncrementCanContinueWithTheSister) {
  auto c = base_config();
  c.tool_life.excessive_increment_um = 15.0;
  c.tool_life.on_excessive = ExcessivePolicy::kSister;
  Rig r(c);
  r.measure({10.0});
  r.run_to(100.0);
  r.measure({26.0});
  EXPECT_FALSE(r.comp.halted());
  EXPECT_EQ(r.alarms.back().severity, Severity::kWarning);
  EXPECT_NEAR(r.last_write(13), 1.0, 0.0);
  EXPECT_NEAR(r.last_write(10), 1.0, 0.0);
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), -10.0, 1e-9);  // the excessive value is not applied
}

TEST(CreepToolLife, BrokenNanShrinkingOrAJumpIsAlarmedAndNothingApplied) {
  struct Case {
    std::vector<double> wear;
    bool broken;
  };
  const Case cases[] = {{{12.0}, true},           // the laser says broken
                        {{std::nan("")}, false},  // NaN
                        {{6.0}, false},           // shrank by 4 > noise 2
                        {{400.0}, false}};        // 390 ≫ 5 × expected
  for (const auto& k : cases) {
    auto c = base_config();
    c.tool_life.noise_um = 2.0;
    c.tool_life.implausible_factor = 5.0;
    c.tool_life.min_expected_increment_um = 10.0;
    Rig r(c);
    r.measure({10.0});
    r.run_to(100.0);
    r.measure(k.wear, k.broken);
    EXPECT_TRUE(r.comp.halted());
    ASSERT_EQ(r.count(AlarmCode::kToolBrokenOrMismeasured), 1U);
    EXPECT_EQ(r.alarms.back().severity, Severity::kAlarm);
    r.run_to(200.0);
    EXPECT_NEAR(r.z(), -10.0, 1e-9);
    EXPECT_NEAR(r.comp.state().measured_um[0], 10.0, 0.0);
  }
}

TEST(CreepToolLife, ShrinkingWithinTheNoiseIsAccepted) {
  auto c = base_config();
  c.tool_life.noise_um = 2.0;
  Rig r(c);
  r.measure({10.0});
  r.run_to(100.0);
  r.measure({8.5});
  EXPECT_FALSE(r.comp.halted());
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), -8.5, 1e-9);
}

TEST(CreepToolLife, TheExpectedIncrementFollowsTheFittedRate) {
  auto c = base_config();
  c.tool_life.min_expected_increment_um = 1.0;
  c.tool_life.implausible_factor = 3.0;
  Rig r(c);
  r.run_to(100.0);
  r.measure({2.0});  // 0.02 µm/mm
  r.run_to(600.0);
  r.measure({12.0});  // expected 10, 3× = 30: fine
  EXPECT_FALSE(r.comp.halted());
  r.run_to(700.0);
  r.measure({20.0});  // rate 0.02 → expected 2 → limit 6 < 8
  EXPECT_TRUE(r.comp.halted());
}

TEST(CreepToolLife, AWearBeyondTheAbsoluteLimitIsRefusedAndChangesNothing) {
  auto c = base_config();
  c.limiter.max_abs_um = 50.0;
  c.tool_life.min_expected_increment_um = 100.0;
  Rig r(c);
  r.measure({20.0});
  r.run_to(100.0);
  r.measure({60.0});
  EXPECT_EQ(r.count(AlarmCode::kOffsetBeyondAbsoluteLimit), 1U);
  EXPECT_NEAR(r.last_write(11), 1.0, 0.0);
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), -20.0, 1e-9);
}

// Pins: the admissibility check counts the deflection the module adds on top of the wear. A
// reading of 48 µm is inside the 50 µm limit, but the offset it asks for is 48 + 4 µm of normal
// deflection (+ 10 µm lateral): it must be refused before it changes the module's state, not
// accepted and then held back by the limiter with the state already moved.
TEST(CreepToolLife, AWearWithinTheLimitThatTheDeflectionPushesBeyondItIsRefused) {
  auto c = base_config();
  c.limiter.max_abs_um = 50.0;
  c.tool_life.min_expected_increment_um = 100.0;
  c.deflection = {{0, {0.0, 20.0}, {0.0, 4.0}, {0.0, 10.0}}};
  Rig r(c);
  r.measure({20.0});  // 20 + 4 + 10 = 34 µm: accepted
  r.run_to(100.0);
  ASSERT_NEAR(r.z(), -24.0, 1e-9);
  const CreepState before = r.comp.export_state();
  r.measure({48.0});
  EXPECT_EQ(r.count(AlarmCode::kOffsetBeyondAbsoluteLimit), 1U);
  EXPECT_EQ(r.comp.counters().measurements_accepted, 1U);
  EXPECT_EQ(r.comp.counters().measurements_refused, 1U);
  EXPECT_NEAR(r.last_write(11), 1.0, 0.0);
  const CreepState& after = r.comp.state();
  EXPECT_EQ(after.measured_um[0], before.measured_um[0]);
  EXPECT_EQ(after.committed_um[0], before.committed_um[0]);
  EXPECT_EQ(after.measurements, before.measurements);
  EXPECT_EQ(after.history_count, before.history_count);
  EXPECT_EQ(after.next_seq, before.next_seq);
  EXPECT_EQ(after.last_measurement_cut_path_mm, before.last_measurement_cut_path_mm);
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), -24.0, 1e-9);
}

TEST(CreepToolLife, AMeasurementOfAnotherToolIsLoggedNotApplied) {
  Rig r(base_config());
  ToolMeasurement m;
  m.tool = 9;
  m.wear_um[0] = 5.0;
  r.events.emplace_back(m);
  r.step();
  EXPECT_EQ(r.records.size(), 1U);
  EXPECT_EQ(r.count(AlarmCode::kEventInvalid), 1U);
  r.run_to(100.0);
  EXPECT_NEAR(r.z(), 0.0, 0.0);
}

// Issue 17, finding 4. GIVEN a fresh tool (nothing measured yet, so a wear of 0 would be
// plausible), WHEN the laser's result arrives faulted (the driver read NaN / inf / a value beyond
// the map's range: InputFault, its values 0 as the engine delivers them), whatever tool number
// came with it (the active tool 1, or 0 when the tool number itself was unreadable), THEN the
// creep module raises its broken-or-mismeasured alarm (23, severity alarm, value NaN) and halts
// as for an impossible measurement, logs the measurement with no value, and applies nothing; a
// second faulted one while halted is a warning (51), as any measurement while halted.
TEST(CreepToolLife, AFaultedMeasurementIsAMismeasurementAndChangesNothing) {
  for (const auto fault : {InputFault::kInvalid, InputFault::kOutOfRange}) {
    for (const std::int32_t tool : {1, 0}) {
      Rig r(base_config());
      r.run_to(100.0);
      ToolMeasurement m;
      m.time_ns = r.now_ns;
      m.tool = tool;
      m.fault = fault;
      const Event e = m;
      r.out.clear();
      {
        const nccomp::test::AllocationScope scope;  // the loop's path: allocation-free
        r.comp.step(r.now_ns, {&e, 1}, r.out);
        EXPECT_EQ(scope.count(), 0U);
      }
      for (const auto& a : r.out.alarms) r.alarms.push_back(a);
      for (const auto& rec : r.out.records) r.records.push_back(rec);
      EXPECT_TRUE(r.comp.halted()) << tool;
      ASSERT_EQ(r.count(AlarmCode::kToolBrokenOrMismeasured), 1U) << tool;
      EXPECT_EQ(r.alarms.back().severity, Severity::kAlarm);
      EXPECT_EQ(r.alarms.back().subject, 1);
      EXPECT_TRUE(std::isnan(r.alarms.back().value));
      ASSERT_EQ(r.records.size(), 1U);
      EXPECT_TRUE(std::isnan(r.records[0].measured_um));
      EXPECT_EQ(r.comp.state().measured_um[0], 0.0);
      r.events.emplace_back(m);
      r.step();
      EXPECT_EQ(r.count(AlarmCode::kToolBrokenOrMismeasured), 1U);
      EXPECT_EQ(r.count(AlarmCode::kEventInvalid), 1U);
      r.run_to(200.0);
      EXPECT_EQ(r.z(), 0.0);
    }
  }
}

}  // namespace
}  // namespace nccomp::core::creep
