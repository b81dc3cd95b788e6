#include "core/checkpoint/compensator.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "tests/support/alloc_counter.hpp"
#include "tests/unit/checkpoint/helpers.hpp"

namespace nccomp::core::checkpoint {
namespace {

using test::line_plan;
using test::part_start;
using test::probe;
using test::sample;
using test::wide_limits;

CompensatorConfig base_config() {
  CompensatorConfig c;
  c.finishing_tool = 12;
  c.semi_finishing_tool = 11;
  c.register_base = 20;
  c.ewma_weight = 1.0;
  c.dead_band_um = 0.0;
  c.feedback = 1.0;
  c.probe_repeatability_um = 0.0;
  c.write_threshold_um = 0.0;
  return c;
}

StepOutput run(CheckpointCompensator& comp, std::vector<Event> events, TimeNs t = 0) {
  StepOutput out;
  comp.step(t, events, out);
  return out;
}

bool has_alarm(const StepOutput& out, AlarmCode code) {
  return std::any_of(out.alarms.begin(), out.alarms.end(),
                     [&](const AlarmEvent& a) { return a.code == code; });
}

TEST(Registers, PartStartWritesEveryValueInMachiningOrderToConsecutiveRegisters) {
  CheckpointCompensator comp;
  comp.configure(base_config(), line_plan(8), wide_limits());
  for (std::int32_t i = 0; i < 8; ++i) {
    (void)run(comp, {probe(1, i, 2.0 * i + 3.0)});  // offsets −3, −5, …, −17
  }
  const StepOutput out = run(comp, {part_start(2)});
  ASSERT_EQ(out.writes.size(), 8U);
  for (std::size_t i = 0; i < 8; ++i) {
    EXPECT_EQ(out.writes[i].register_index, 20U + i);
    EXPECT_DOUBLE_EQ(out.writes[i].value_um, -(2.0 * static_cast<double>(i) + 3.0));
  }
}

TEST(Registers, LargeTablesAreSpreadOverCyclesAndEachRegisterIsWrittenOnce) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.register_base = 1001;
  comp.configure(cfg, line_plan(100), wide_limits());
  std::vector<int> seen(100, 0);
  StepOutput out = run(comp, {part_start(1)});
  std::size_t cycles = 1;
  EXPECT_EQ(out.writes.size(), kTableWritesPerStep);
  for (;;) {
    for (const OffsetWrite& w : out.writes) {
      ASSERT_GE(w.register_index, 1001U);
      ++seen[w.register_index - 1001U];
    }
    if (!comp.table_pending()) break;
    out = run(comp, {});
    ++cycles;
  }
  EXPECT_EQ(cycles, 4U);  // 32 + 32 + 32 + 4
  for (int n : seen) EXPECT_EQ(n, 1);
  EXPECT_EQ(comp.counters().table_writes, 100U);
}

TEST(Registers, ConfigRejectsTablesOutsideTheRegisterSpace) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.register_base = 65500;
  EXPECT_THROW(comp.configure(cfg, line_plan(100), wide_limits()), std::invalid_argument);
  cfg = base_config();
  cfg.active_register = 25;  // inside 20..27
  try {
    comp.configure(cfg, line_plan(8), wide_limits());
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("checkpoints.active_register"), std::string::npos);
  }
}

TEST(Config, EveryBadValueIsRefusedNamingItsKey) {
  const auto err = [](CompensatorConfig c, std::vector<Checkpoint> plan = line_plan(4)) {
    CheckpointCompensator comp;
    try {
      comp.configure(c, std::move(plan), wide_limits());
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  CompensatorConfig c = base_config();
  c.ewma_weight = 0.5;
  EXPECT_NE(err(c).find("checkpoints.ewma_weight"), std::string::npos);
  c = base_config();
  c.feedback = 0.0;
  EXPECT_NE(err(c).find("checkpoints.feedback"), std::string::npos);
  c = base_config();
  c.feedback = 1.5;
  EXPECT_NE(err(c).find("checkpoints.feedback"), std::string::npos);
  c = base_config();
  c.dead_band_um = -1.0;
  EXPECT_NE(err(c).find("checkpoints.dead_band_um"), std::string::npos);
  c = base_config();
  c.plausible_um = std::nan("");
  EXPECT_NE(err(c).find("checkpoints.plausible_um"), std::string::npos);
  c = base_config();
  c.outlier_min_history = 1;
  EXPECT_NE(err(c).find("checkpoints.outlier_min_history"), std::string::npos);
  c = base_config();
  c.xy_tolerance_mm = 0.0;
  EXPECT_NE(err(c).find("checkpoints.xy_tolerance_mm"), std::string::npos);
  c = base_config();
  c.creep_shape = ProfileShape::kTable;
  EXPECT_NE(err(c).find("checkpoints.creep_shape"), std::string::npos);
  EXPECT_NE(err(base_config(), {}).find("checkpoints.plan"), std::string::npos);
  auto plan = line_plan(4);
  plan[2].path_mm = plan[1].path_mm;
  EXPECT_NE(err(base_config(), plan).find("does not increase"), std::string::npos);
  plan = line_plan(4);
  plan[2].level = 2;  // levels skip 1
  EXPECT_NE(err(base_config(), plan).find("levels must be 0, 1, 2"), std::string::npos);
  plan = line_plan(4);
  plan[3].alpha_deg = 89.5;
  EXPECT_NE(err(base_config(), plan).find("wall angle"), std::string::npos);
  plan = line_plan(4);
  for (auto& p : plan) {
    p.pass_length_mm = 35.0;  // s = 10 .. 40: checkpoint 3 lies beyond the pass
  }
  EXPECT_NE(err(base_config(), plan).find("does not lie on its level's pass"), std::string::npos);
  EXPECT_EQ(err(base_config()), "");
}

TEST(Config, ALiveApplyModeWithoutALiveRegisterIsRefused) {
  // The trap: apply = creep (or step) and active_register = -1 would silently do nothing while
  // the NC switches offset numbers at each checkpoint.
  const auto err = [](ApplyMode apply, std::int32_t active) {
    CompensatorConfig c = base_config();
    c.apply = apply;
    c.active_register = active;
    CheckpointCompensator comp;
    try {
      comp.configure(c, line_plan(4), wide_limits());
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string creep = err(ApplyMode::kCreep, -1);
  EXPECT_EQ(creep.rfind("checkpoints.apply: \"creep\" drives the live radius wear register, but "
                        "active_register = -1",
                        0),
            0U)
      << creep;
  EXPECT_NE(err(ApplyMode::kStep, -1).find("checkpoints.apply: \"step\""), std::string::npos);
  EXPECT_EQ(err(ApplyMode::kTable, 5)
                .rfind("checkpoints.apply: \"table\" writes no live "
                       "register, but active_register = 5",
                       0),
            0U);
  EXPECT_EQ(err(ApplyMode::kTable, -1), "");
  EXPECT_EQ(err(ApplyMode::kCreep, 5), "");
  EXPECT_EQ(err(ApplyMode::kStep, 5), "");
  // The defaults are the table-only method: valid as they are.
  CheckpointCompensator comp;
  EXPECT_NO_THROW(comp.configure(CompensatorConfig{}, line_plan(2), wide_limits()));
  EXPECT_EQ(comp.config().apply, ApplyMode::kTable);
}

TEST(Learning, EwmaFeedbackAndSinumerikForm) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.ewma_weight = 2.0;
  comp.configure(cfg, line_plan(1), wide_limits());
  // Part 1 cut without offsets: δ' = e = 10 → M = 10, c = −10.
  StepOutput out = run(comp, {part_start(1), probe(1, 0, 10.0)});
  EXPECT_DOUBLE_EQ(comp.learned_um(0), 10.0);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -10.0);
  ASSERT_EQ(out.records.size(), 1U);
  EXPECT_EQ(out.records[0].kind, MeasurementKind::kContour);
  EXPECT_DOUBLE_EQ(out.records[0].measured_um, 10.0);
  EXPECT_DOUBLE_EQ(out.records[0].applied_um, 0.0);
  EXPECT_EQ(out.records[0].tool, 12);
  // Part 2 cut with c = −10 shows a residual of 2 µm: e = 2 − (−10) = 12,
  // M = 10 + (12 − 10)/2 = 11, c = −11.
  out = run(comp, {part_start(2), probe(2, 0, 2.0)});
  // Logged as the share of the error the offset removed: measured + applied = e = 12.
  EXPECT_DOUBLE_EQ(out.records[0].applied_um, 10.0);
  EXPECT_DOUBLE_EQ(out.records[0].measured_um + out.records[0].applied_um, 12.0);
  EXPECT_DOUBLE_EQ(comp.learned_um(0), 11.0);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -11.0);
  EXPECT_EQ(comp.learned_count(0), 2U);
}

TEST(Learning, FeedbackAppliesAFractionOfTheRemainingError) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.feedback = 0.5;
  comp.configure(cfg, line_plan(1), wide_limits());
  (void)run(comp, {part_start(1), probe(1, 0, 10.0)});
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -5.0);
  // Part 2 with c = −5 and the same push-off shows 5: e = 10, c → −5 + 0.5·(−10 + 5) = −7.5.
  (void)run(comp, {part_start(2), probe(2, 0, 5.0)});
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -7.5);
}

TEST(Learning, DeadBandAndRepeatability) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.dead_band_um = 1.0;
  cfg.probe_repeatability_um = 1.5;
  comp.configure(cfg, line_plan(2), wide_limits());
  // A change of 0.8 µm < dead band: M learns, the offset stays 0.
  (void)run(comp, {part_start(1), probe(1, 0, 0.8)});
  EXPECT_NEAR(comp.learned_um(0), 0.8, 1e-9);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), 0.0);
  EXPECT_EQ(comp.counters().dead_band_skips, 1U);
  // 3 µm passes the dead band …
  (void)run(comp, {probe(1, 1, 3.0)});
  EXPECT_NEAR(comp.register_value_um(1), -3.0, 1e-9);
  // … then part 2 (cut with −3) shows −1.6: e = 1.4, the offset moves by 1.6 to −1.4, which is
  // below the probe's repeatability and so written as 0.
  (void)run(comp, {part_start(2), probe(2, 1, -1.6)});
  EXPECT_NEAR(comp.learned_um(1), 1.4, 1e-9);
  EXPECT_DOUBLE_EQ(comp.register_value_um(1), 0.0);
  const StepOutput out = run(comp, {part_start(3)});
  ASSERT_EQ(out.writes.size(), 2U);
  EXPECT_EQ(out.writes[1].register_index, 21U);
  EXPECT_DOUBLE_EQ(out.writes[1].value_um, 0.0);
  // Part 3 (cut with 0) shows −0.5: the offset becomes +0.5, again below the repeatability.
  (void)run(comp, {probe(3, 1, -0.5)});
  EXPECT_NEAR(comp.learned_um(1), -0.5, 1e-9);
  EXPECT_DOUBLE_EQ(comp.register_value_um(1), 0.0);
}

TEST(Learning, ImplausibleReadingAlarmsAndChangesNothing) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.plausible_um = 100.0;
  comp.configure(cfg, line_plan(1), wide_limits());
  (void)run(comp, {part_start(1), probe(1, 0, 8.0)});
  const StepOutput out = run(comp, {probe(1, 0, 150.0)});
  EXPECT_TRUE(has_alarm(out, AlarmCode::kProbeImplausible));
  EXPECT_EQ(out.records.size(), 1U);  // logged
  EXPECT_DOUBLE_EQ(comp.learned_um(0), 8.0);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -8.0);
  EXPECT_EQ(comp.learned_count(0), 1U);
}

TEST(Learning, OutlierBeyondKSigmaIsLoggedNotLearned) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.ewma_weight = 4.0;
  cfg.outlier_sigma = 3.0;
  cfg.outlier_min_history = 4;
  cfg.probe_repeatability_um = 0.5;
  comp.configure(cfg, line_plan(1), wide_limits());
  // e history 10, 11, 9, 10 (the parts are cut without offsets here: feedback keeps c, so
  // report the residual accordingly: δ' = e + c).
  const double es[4] = {10.0, 11.0, 9.0, 10.0};
  for (int k = 0; k < 4; ++k) {
    const double c = comp.register_value_um(0);
    (void)run(comp, {part_start(k + 1), probe(k + 1, 0, es[k] + c)});
  }
  const double learned = comp.learned_um(0);
  const double offset = comp.register_value_um(0);
  // mean 10, σ = 0.8165: 3σ = 2.45. e = 13 deviates by 3 → outlier.
  StepOutput out = run(comp, {part_start(5), probe(5, 0, 13.0 + offset)});
  EXPECT_TRUE(has_alarm(out, AlarmCode::kProbeOutlier));
  EXPECT_EQ(out.records.size(), 1U);
  EXPECT_DOUBLE_EQ(comp.learned_um(0), learned);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), offset);
  EXPECT_EQ(comp.counters().outliers, 1U);
  // e = 12 deviates by 2 < 2.45 → learned.
  out = run(comp, {part_start(6), probe(6, 0, 12.0 + offset)});
  EXPECT_FALSE(has_alarm(out, AlarmCode::kProbeOutlier));
  EXPECT_DOUBLE_EQ(comp.learned_um(0), learned + (12.0 - learned) / 4.0);
}

// GIVEN a history that repeats exactly (σ = 0) THEN the outlier bound is k times the probe's
// repeatability, not 0: a reading within it is learned, one beyond it is an outlier.
TEST(Learning, APerfectlyRepeatingHistoryUsesTheProbesRepeatabilityAsSigma) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.ewma_weight = 4.0;
  cfg.outlier_sigma = 3.0;
  cfg.outlier_min_history = 4;
  cfg.probe_repeatability_um = 0.5;
  comp.configure(cfg, line_plan(1), wide_limits());
  for (int k = 0; k < 4; ++k) {
    const double c = comp.register_value_um(0);
    (void)run(comp, {part_start(k + 1), probe(k + 1, 0, 10.0 + c)});
  }
  const double learned = comp.learned_um(0);
  const double offset = comp.register_value_um(0);
  // mean 10, σ 0 → σ_eff 0.5: 3σ_eff = 1.5. e = 12 deviates by 2 → outlier.
  StepOutput out = run(comp, {part_start(5), probe(5, 0, 12.0 + offset)});
  EXPECT_TRUE(has_alarm(out, AlarmCode::kProbeOutlier));
  EXPECT_DOUBLE_EQ(comp.learned_um(0), learned);
  // e = 11 deviates by 1 < 1.5 → learned.
  out = run(comp, {part_start(6), probe(6, 0, 11.0 + offset)});
  EXPECT_FALSE(has_alarm(out, AlarmCode::kProbeOutlier));
  EXPECT_EQ(comp.counters().outliers, 1U);
  EXPECT_DOUBLE_EQ(comp.learned_um(0), learned + (11.0 - learned) / 4.0);
}

TEST(Learning, OffsetBeyondTheAbsoluteLimitIsRefused) {
  CheckpointCompensator comp;
  LimiterConfig lim = wide_limits();
  lim.max_abs_um = 50.0;
  comp.configure(base_config(), line_plan(1), lim);
  const StepOutput out = run(comp, {part_start(1), probe(1, 0, 80.0)});
  EXPECT_TRUE(has_alarm(out, AlarmCode::kOffsetBeyondAbsoluteLimit));
  EXPECT_EQ(comp.learned_count(0), 0U);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), 0.0);
}

TEST(Learning, InvalidProbeInputsAlarm) {
  CheckpointCompensator comp;
  comp.configure(base_config(), line_plan(2), wide_limits());
  ProbeMeasurement steep = probe(1, 0, 5.0);
  steep.wall_angle_deg = 89.0;
  ProbeMeasurement neg = probe(1, 0, 5.0);
  neg.ball_radius_mm = -1.0;
  ProbeMeasurement nan_raw = probe(1, 0, 5.0);
  nan_raw.raw_deviation_um = std::nan("");
  const StepOutput out = run(comp, {steep, neg, nan_raw, probe(1, 7, 5.0), probe(1, -1, 5.0)});
  EXPECT_EQ(out.alarms.size(), 5U);
  for (const AlarmEvent& a : out.alarms) EXPECT_EQ(a.code, AlarmCode::kProbeInvalidInput);
  EXPECT_EQ(comp.counters().invalid, 5U);
  EXPECT_EQ(comp.learned_count(0), 0U);
  EXPECT_TRUE(out.records.empty());
}

// Issue 17, finding 4. GIVEN a checkpoint whose wall is vertical (α 0°, so a reading of all zeros
// would pass every check), WHEN the probe's reading arrives faulted (the driver read NaN / inf / a
// value beyond the map's range: InputFault, its values 0 as the engine delivers them), THEN S1
// raises its invalid-reading alarm (32, severity alarm, subject the checkpoint, value NaN), learns
// nothing and writes nothing, as for any invalid reading; an intact reading next is learned.
TEST(Learning, AFaultedReadingAlarmsAndChangesNothing) {
  for (const auto fault : {InputFault::kInvalid, InputFault::kOutOfRange}) {
    CheckpointCompensator comp;
    auto plan = line_plan(1);
    plan[0].alpha_deg = 0.0;
    comp.configure(base_config(), plan, wide_limits());
    ProbeMeasurement m;
    m.part = 1;
    m.checkpoint = 0;
    m.fault = fault;
    const StepOutput out = run(comp, {part_start(1), m});
    ASSERT_EQ(out.alarms.size(), 1U);
    EXPECT_EQ(out.alarms[0].code, AlarmCode::kProbeInvalidInput);
    EXPECT_EQ(out.alarms[0].severity, Severity::kAlarm);
    EXPECT_EQ(out.alarms[0].subject, 0);
    EXPECT_TRUE(std::isnan(out.alarms[0].value));
    EXPECT_EQ(comp.counters().invalid, 1U);
    EXPECT_EQ(comp.learned_count(0), 0U);
    EXPECT_TRUE(out.records.empty());
    (void)run(comp, {test::probe(2, 0, 6.0, 0, 0.0)});
    EXPECT_EQ(comp.learned_count(0), 1U);
    EXPECT_DOUBLE_EQ(comp.register_value_um(0), -6.0);
  }
}

TEST(Learning, ModeBWritesTheSemiFinishingValueBeforeFinishing) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.learning_mode = LearningMode::kSemiFinishing;
  comp.configure(cfg, line_plan(3), wide_limits());
  (void)run(comp, {part_start(1)});
  // Semi-finishing of part 1 leaves the wall 7 µm proud at checkpoint 1: register 21 = −7 at
  // once (the finishing of this very part uses it).
  const StepOutput out = run(comp, {probe(1, 1, 7.0)});
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_EQ(out.writes[0].register_index, 21U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, -7.0);
  EXPECT_EQ(out.records[0].tool, 11);
  EXPECT_DOUBLE_EQ(out.records[0].applied_um, 0.0);
  // Part 2: the semi-finished wall (cut without per-checkpoint offsets) shows 5 → −5 with k = 1.
  (void)run(comp, {part_start(2)});
  const StepOutput out2 = run(comp, {probe(2, 1, 5.0)});
  EXPECT_DOUBLE_EQ(out2.records[0].applied_um, 0.0);
  EXPECT_DOUBLE_EQ(comp.register_value_um(1), -5.0);
}

TEST(Learning, ModeBAppliesThisBlanksReadingNotAnAverageOverBlanks) {
  // Default weights (k = 3): in mode A they average over parts; mode B must not blend the
  // previous blank's semi-finishing error into this blank's offset.
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.learning_mode = LearningMode::kSemiFinishing;
  cfg.ewma_weight = 3.0;
  comp.configure(cfg, line_plan(1), wide_limits());
  (void)run(comp, {part_start(1), probe(1, 0, 10.0)});
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -10.0);
  // Blank 2 is softer: 4 µm. Its offset is −4, not −10 + (4 − 10)/3 = −8.
  const StepOutput out = run(comp, {part_start(2), probe(2, 0, 4.0)});
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -4.0);
  EXPECT_DOUBLE_EQ(comp.learned_um(0), 4.0);
  // Part start marks the register for rewriting, the reading changes it before the cycle's
  // writes go out: one write, −4, before the finishing of this blank.
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, -4.0);
  // Feedback 0.5: half of this blank's error, whatever the previous offset was.
  CheckpointCompensator half;
  cfg.feedback = 0.5;
  half.configure(cfg, line_plan(1), wide_limits());
  (void)run(half, {part_start(1), probe(1, 0, 10.0)});
  EXPECT_DOUBLE_EQ(half.register_value_um(0), -5.0);
  (void)run(half, {part_start(2), probe(2, 0, 4.0)});
  EXPECT_DOUBLE_EQ(half.register_value_um(0), -2.0);  // mode A's form would give −3.5
  // Mode A with the same numbers averages (its purpose: the push-off repeats part to part).
  CheckpointCompensator a;
  cfg.learning_mode = LearningMode::kPreviousPart;
  cfg.feedback = 1.0;
  a.configure(cfg, line_plan(1), wide_limits());
  (void)run(a, {part_start(1), probe(1, 0, 10.0)});
  (void)run(a, {part_start(2), probe(2, 0, 4.0 - 10.0)});  // cut with −10: shows e + c
  EXPECT_DOUBLE_EQ(a.register_value_um(0), -8.0);
}

TEST(Learning, TheReadingIsCorrectedWithThePlansAlphaAndAnotherAlphaIsRefused) {
  // Two checkpoints on walls of different draft: 10° and 3° (per sub-curve α in the plan).
  auto plan = line_plan(2);
  plan[1].alpha_deg = 3.0;
  CheckpointCompensator comp;
  comp.configure(base_config(), plan, wide_limits());
  ProbeMeasurement m0;
  m0.part = 1;
  m0.checkpoint = 0;
  m0.wall_angle_deg = 10.0;
  m0.ball_radius_mm = 1.0;
  m0.raw_deviation_um = 20.0;  // δ' = 20 − 15.42661189 (r = 1 mm, α = 10°)
  ProbeMeasurement m1 = m0;
  m1.checkpoint = 1;
  m1.wall_angle_deg = 3.0;
  m1.ball_radius_mm = 2.0;  // δ0 = 2.745 µm at 3°
  StepOutput out = run(comp, {part_start(1), m0, m1});
  ASSERT_EQ(out.records.size(), 2U);
  EXPECT_NEAR(out.records[0].measured_um, 20.0 - 15.42661189, 1e-6);
  EXPECT_DOUBLE_EQ(out.records[0].angle_deg, 10.0);
  EXPECT_NEAR(probe_delta0_um(2.0, 3.0), 2.7447, 1e-4);
  EXPECT_DOUBLE_EQ(out.records[1].measured_um, 20.0 - probe_delta0_um(2.0, 3.0));
  EXPECT_DOUBLE_EQ(out.records[1].angle_deg, 3.0);
  // A reading with checkpoint 1's number but checkpoint 0's α (a stale probing program): alarm
  // 32, nothing learned or logged. Within the bus resolution (0.01°) it is accepted.
  ProbeMeasurement wrong = m1;
  wrong.wall_angle_deg = 10.0;
  ProbeMeasurement close = m1;
  close.wall_angle_deg = 3.01;
  out = run(comp, {wrong});
  EXPECT_TRUE(has_alarm(out, AlarmCode::kProbeInvalidInput));
  EXPECT_TRUE(out.records.empty());
  EXPECT_EQ(comp.learned_count(1), 1U);
  out = run(comp, {close});
  EXPECT_FALSE(has_alarm(out, AlarmCode::kProbeInvalidInput));
  EXPECT_EQ(comp.learned_count(1), 2U);
  // Corrected with the plan's 3°, not the reading's 3.01°.
  EXPECT_DOUBLE_EQ(out.records[0].measured_um, 20.0 - probe_delta0_um(2.0, 3.0));
}

// --- application while finishing ---

CompensatorConfig live_config(ApplyMode apply, TriggerMode trigger) {
  CompensatorConfig c = base_config();
  c.active_register = 5;
  c.apply = apply;
  c.trigger = trigger;
  return c;
}

void learn_values(CheckpointCompensator& comp, const std::vector<double>& offsets_um) {
  CheckpointState st;
  comp.export_state(st);
  for (std::size_t i = 0; i < offsets_um.size(); ++i) st.points[i].offset_um = offsets_um[i];
  comp.import_state(st);
}

TEST(Apply, StepHoldsEachCheckpointsValueUntilTheNext) {
  CheckpointCompensator comp;
  comp.configure(live_config(ApplyMode::kStep, TriggerMode::kPath), line_plan(3), wide_limits());
  learn_values(comp, {4.0, 10.0, -6.0});  // checkpoints at path 10, 20, 30
  (void)run(comp, {part_start(1)});
  const auto at = [&](double path) {
    (void)run(comp, {sample(path, 0, -5, path, 12, 0)});
    return comp.live_target_um();
  };
  EXPECT_DOUBLE_EQ(at(0.0), 4.0);   // before the first: the first value
  EXPECT_DOUBLE_EQ(at(10.0), 4.0);  // at checkpoint 0
  EXPECT_DOUBLE_EQ(at(19.9), 4.0);
  EXPECT_DOUBLE_EQ(at(20.0), 10.0);  // the step at checkpoint 1
  EXPECT_DOUBLE_EQ(at(29.0), 10.0);
  EXPECT_DOUBLE_EQ(at(35.0), -6.0);
  EXPECT_EQ(comp.passed(), 3U);
}

TEST(Apply, CreepReachesEachCheckpointsValueExactlyAtTheCheckpoint) {
  CheckpointCompensator comp;
  comp.configure(live_config(ApplyMode::kCreep, TriggerMode::kPath), line_plan(3), wide_limits());
  learn_values(comp, {4.0, 10.0, -6.0});
  (void)run(comp, {part_start(1)});
  const auto at = [&](double path) {
    (void)run(comp, {sample(path, 0, -5, path, 12, 0)});
    return comp.live_target_um();
  };
  EXPECT_DOUBLE_EQ(at(5.0), 4.0);
  EXPECT_DOUBLE_EQ(at(10.0), 4.0);
  EXPECT_DOUBLE_EQ(at(15.0), 7.0);   // linear halfway between 4 and 10
  EXPECT_DOUBLE_EQ(at(20.0), 10.0);  // exactly the checkpoint's value: no step left there
  EXPECT_DOUBLE_EQ(at(27.5), -2.0);
  EXPECT_DOUBLE_EQ(at(30.0), -6.0);
  EXPECT_DOUBLE_EQ(at(40.0), -6.0);
}

// A 100 × 60 mm rectangle, 2 levels 5 mm apart: per level 8 corner points at
// s = 5, 95, 105, 155, 165, 255, 265, 315 of a 320 mm closed pass; level 1 starts at path 325.
Plan two_level_rect(bool closed) {
  PlanConfig c;
  c.contour = {{0, 0}, {100, 0}, {100, 60}, {0, 60}};
  c.closed = closed;
  c.material = closed ? MaterialSide::kInside : MaterialSide::kLeft;
  c.z_start_mm = -2.0;
  c.z_end_mm = -7.0;
  c.depth_step_mm = 5.0;
  c.corner_offset_mm = 5.0;
  return make_plan(c);
}

// Level 0: 0, 1, 2, ..., 7 µm ×10 except the last = 10; level 1: 40 everywhere.
std::vector<double> rect_values() {
  return {0.0,  10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 10.0,
          40.0, 40.0, 40.0, 40.0, 40.0, 40.0, 40.0, 40.0};
}

TEST(Levels, CreepWrapsThroughTheSeamAndNeverBlendsAcrossLevels) {
  const Plan plan = two_level_rect(true);
  ASSERT_EQ(plan.checkpoints.size(), 16U);
  ASSERT_DOUBLE_EQ(plan.checkpoints[8].path_mm, 325.0 + 5.0);
  CheckpointCompensator comp;
  comp.configure(live_config(ApplyMode::kCreep, TriggerMode::kPath), plan.checkpoints,
                 wide_limits());
  learn_values(comp, rect_values());
  (void)run(comp, {part_start(1)});
  // Pre-positioned to where the first pass starts: halfway between checkpoint 7 (s = 315,
  // 10 µm) and checkpoint 0 (s = 5 + 320, 0 µm) through the seam.
  EXPECT_DOUBLE_EQ(comp.start_value_um(), 5.0);
  const auto at = [&](double path) {
    (void)run(comp, {sample(0, 0, -2, path, 12, 0)});
    return comp.live_target_um();
  };
  EXPECT_DOUBLE_EQ(at(0.0), 5.0);     // the pass's start: s = 0 on level 0
  EXPECT_DOUBLE_EQ(at(2.5), 2.5);     // toward checkpoint 0
  EXPECT_DOUBLE_EQ(at(5.0), 0.0);     // checkpoint 0
  EXPECT_DOUBLE_EQ(at(50.0), 5.0);    // halfway to checkpoint 1
  EXPECT_DOUBLE_EQ(at(315.0), 10.0);  // checkpoint 7
  EXPECT_DOUBLE_EQ(at(317.5), 7.5);   // through the seam toward checkpoint 0 of the SAME level
  EXPECT_DOUBLE_EQ(at(320.0), 5.0);   // the pass meets itself with the value it started with
  // The level link (path 320..325): from level 0's seam value 5 to level 1's 40.
  EXPECT_DOUBLE_EQ(at(322.5), 22.5);
  EXPECT_DOUBLE_EQ(at(325.0), 40.0);  // level 1's start: only level 1's values
  EXPECT_DOUBLE_EQ(at(327.0), 40.0);
  EXPECT_DOUBLE_EQ(at(645.0), 40.0);  // level 1's end = its start
  EXPECT_EQ(comp.passed(), 16U);
}

TEST(Levels, StepHoldsTheLevelsLastValueThroughTheSeam) {
  const Plan plan = two_level_rect(true);
  CheckpointCompensator comp;
  comp.configure(live_config(ApplyMode::kStep, TriggerMode::kPath), plan.checkpoints,
                 wide_limits());
  learn_values(comp, rect_values());
  (void)run(comp, {part_start(1)});
  const auto at = [&](double path) {
    (void)run(comp, {sample(0, 0, -2, path, 12, 0)});
    return comp.live_target_um();
  };
  EXPECT_DOUBLE_EQ(at(0.0), 10.0);  // before checkpoint 0: checkpoint 7's value (this level)
  EXPECT_DOUBLE_EQ(at(5.0), 0.0);
  EXPECT_DOUBLE_EQ(at(94.0), 0.0);
  EXPECT_DOUBLE_EQ(at(95.0), 10.0);
  EXPECT_DOUBLE_EQ(at(319.9), 10.0);  // = the start value: no step at the seam
  EXPECT_DOUBLE_EQ(at(321.0), 40.0);  // the link: level 1's start value at once
}

TEST(Levels, OpenPassesHoldTheirEndValuesAndTheLinkRamps) {
  const Plan plan = two_level_rect(false);
  // Open: corners at s = 100 and 160 only; points 95, 105, 155, 165 of a 260 mm pass; the link
  // is one depth step (5 mm): level 1 starts at path 265.
  ASSERT_EQ(plan.checkpoints.size(), 8U);
  ASSERT_DOUBLE_EQ(plan.checkpoints[4].path_mm, 265.0 + 95.0);
  CheckpointCompensator comp;
  comp.configure(live_config(ApplyMode::kCreep, TriggerMode::kPath), plan.checkpoints,
                 wide_limits());
  learn_values(comp, {2.0, 4.0, 6.0, 8.0, 20.0, 30.0, 30.0, 30.0});
  (void)run(comp, {part_start(1)});
  EXPECT_DOUBLE_EQ(comp.start_value_um(), 2.0);
  const auto at = [&](double path) {
    (void)run(comp, {sample(0, 0, -2, path, 12, 0)});
    return comp.live_target_um();
  };
  EXPECT_DOUBLE_EQ(at(0.0), 2.0);     // before the first: held at the first value
  EXPECT_DOUBLE_EQ(at(100.0), 3.0);   // halfway 95 → 105
  EXPECT_DOUBLE_EQ(at(200.0), 8.0);   // after the last: held
  EXPECT_DOUBLE_EQ(at(260.0), 8.0);   // the pass's end
  EXPECT_DOUBLE_EQ(at(262.5), 14.0);  // the link: 8 → 20
  EXPECT_DOUBLE_EQ(at(266.0), 20.0);  // level 1 before its first checkpoint: its first value
}

TEST(Apply, LiveRegisterWritesPassTheLimiterAndOnlyTheFinishingToolIsCompensated) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = live_config(ApplyMode::kStep, TriggerMode::kPath);
  cfg.write_threshold_um = 0.1;
  LimiterConfig lim = wide_limits();
  lim.max_step_um = 2.0;
  comp.configure(cfg, line_plan(2), lim);
  learn_values(comp, {0.0, 9.0});
  (void)run(comp, {part_start(1)});
  // Another tool: nothing happens.
  StepOutput out = run(comp, {sample(25, 0, -5, 25, 7, 1'000'000)});
  EXPECT_TRUE(out.writes.empty());
  // The finishing tool past checkpoint 1: the step of 9 µm is slewed at 2 µm per write.
  std::vector<double> written;
  for (int k = 0; k < 8; ++k) {
    out = run(comp, {sample(25, 0, -5, 25 + 0.1 * k, 12, 2'000'000 + k * 1'000'000)});
    for (const OffsetWrite& w : out.writes) {
      EXPECT_EQ(w.register_index, 5U);
      written.push_back(w.value_um);
    }
  }
  ASSERT_EQ(written.size(), 5U);
  EXPECT_DOUBLE_EQ(written[0], 2.0);
  EXPECT_DOUBLE_EQ(written[3], 8.0);
  EXPECT_DOUBLE_EQ(written[4], 9.0);  // then nothing: the target is reached
}

TEST(Apply, LiveRegisterIsPrepositionedToTheFirstValueBeforeFinishing) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = live_config(ApplyMode::kCreep, TriggerMode::kPath);
  LimiterConfig lim = wide_limits();
  lim.max_rate_um_per_s = 50.0;
  lim.max_step_um = 5.0;
  comp.configure(cfg, line_plan(2), lim);
  learn_values(comp, {-12.0, 3.0});
  // Part start at t = 0; the loop steps every 100 ms without the finishing tool.
  std::vector<double> live;
  for (int k = 0; k <= 4; ++k) {
    std::vector<Event> ev;
    if (k == 0) ev.emplace_back(part_start(1));
    const StepOutput out = run(comp, ev, static_cast<TimeNs>(k) * 100'000'000);
    for (const OffsetWrite& w : out.writes) {
      if (w.register_index == 5) live.push_back(w.value_um);
    }
  }
  // The register is first set to what the limiter holds (0: nothing read back), then moves by
  // 50 µm/s · 0.1 s = 5 µm per cycle until it holds checkpoint 0's −12.
  ASSERT_EQ(live.size(), 4U) << ::testing::PrintToString(live);
  EXPECT_DOUBLE_EQ(live[0], 0.0);
  EXPECT_DOUBLE_EQ(live[1], -5.0);
  EXPECT_DOUBLE_EQ(live[2], -10.0);
  EXPECT_DOUBLE_EQ(live[3], -12.0);
  // After a restart the value read back from the NC is where the limiter starts.
  CheckpointCompensator restarted;
  restarted.configure(cfg, line_plan(2), lim);
  learn_values(restarted, {-12.0, 3.0});
  restarted.reset_live(-11.0, 0);
  const StepOutput out = run(restarted, {part_start(2)}, 100'000'000);
  ASSERT_EQ(out.writes.size(), 3U);  // two table registers, then the live one
  EXPECT_EQ(out.writes[2].register_index, 5U);
  EXPECT_DOUBLE_EQ(out.writes[2].value_um, -12.0);
}

// --- no missed checkpoint at 10 m/min -------------------------------------------------------

struct Motion {
  std::vector<std::array<double, 4>> xyz_path;  // x, y, z, programmed path
};

// The finishing tool's centre path for plan `pc`: per level, the wall contour offset by the tool
// radius plus the draft (arcs around the convex corners of the CCW boss), programmed path = the
// contour's arc length (G41: the program is the contour), levels joined by a plunge.
std::vector<std::array<double, 4>> tool_path(const PlanConfig& pc, const Plan& plan,
                                             double step_mm) {
  std::vector<std::array<double, 4>> pts;
  const std::size_t nv = pc.contour.size();
  const double tan_a = std::tan(pc.wall_angle_deg * std::numbers::pi / 180.0);
  for (std::size_t l = 0; l < plan.levels_z_mm.size(); ++l) {
    const double z = plan.levels_z_mm[l];
    const double off = pc.tool_radius_mm + (pc.contour_z_mm - z) * tan_a;
    const double base = pc.program_path_start_mm +
                        static_cast<double>(l) * (plan.contour_length_mm + pc.depth_step_mm);
    double s0 = 0.0;
    for (std::size_t e = 0; e < nv; ++e) {
      const ContourPoint a = pc.contour[e];
      const ContourPoint b = pc.contour[(e + 1) % nv];
      const double len = std::hypot(b.x_mm - a.x_mm, b.y_mm - a.y_mm);
      const double tx = (b.x_mm - a.x_mm) / len;
      const double ty = (b.y_mm - a.y_mm) / len;
      const double nx = ty;  // CCW, material inside: air side on the right
      const double ny = -tx;
      const int n = static_cast<int>(std::ceil(len / step_mm));
      for (int k = 0; k < n; ++k) {
        const double u = len * k / n;
        pts.push_back({a.x_mm + tx * u + nx * off, a.y_mm + ty * u + ny * off, z, base + s0 + u});
      }
      // Arc around the corner b (programmed path does not advance: the contour has a vertex).
      const ContourPoint c = pc.contour[(e + 2) % nv];
      const double len2 = std::hypot(c.x_mm - b.x_mm, c.y_mm - b.y_mm);
      const double a0 = std::atan2(ny, nx);
      const double a1 = std::atan2(-(c.x_mm - b.x_mm) / len2, (c.y_mm - b.y_mm) / len2);
      // Counter-clockwise travel turns left: the air-side normal rotates by +turn angle.
      double da = a1 - a0;
      while (da <= -std::numbers::pi) da += 2 * std::numbers::pi;
      while (da > std::numbers::pi) da -= 2 * std::numbers::pi;
      const int na = std::max(1, static_cast<int>(std::ceil(std::fabs(da) * off / step_mm)));
      for (int k = 0; k < na; ++k) {
        const double ang = a0 + da * k / na;
        pts.push_back(
            {b.x_mm + off * std::cos(ang), b.y_mm + off * std::sin(ang), z, base + s0 + len});
      }
      s0 += len;
    }
  }
  return pts;
}

PlanConfig boss_plan_config() {
  PlanConfig c;
  c.contour = {{0, 0}, {100, 0}, {100, 60}, {0, 60}};
  c.z_start_mm = -2.0;
  c.z_end_mm = -22.0;
  c.depth_step_mm = 5.0;
  c.wall_angle_deg = 2.0;
  c.tool_radius_mm = 6.0;
  c.corner_offset_mm = 5.0;
  c.extra_points_mm = {50.0, 130.0};
  return c;
}

void expect_no_missed(TriggerMode trigger, double rate_hz) {
  const PlanConfig pc = boss_plan_config();
  const Plan plan = make_plan(pc);
  CheckpointCompensator comp;
  CompensatorConfig cfg = live_config(ApplyMode::kStep, trigger);
  cfg.xy_tolerance_mm = 0.2;
  cfg.z_band_mm = 1.0;
  comp.configure(cfg, plan.checkpoints, wide_limits());
  // 10 m/min = 166.7 mm/s: one sample every 0.167 mm at 1 kHz, 0.667 mm at 250 Hz.
  const double feed_mm_s = 10000.0 / 60.0;
  const double step_mm = feed_mm_s / rate_hz;
  const auto pts = tool_path(pc, plan, step_mm);
  StepOutput out;
  comp.step(0, std::vector<Event>{part_start(1)}, out);
  std::size_t passed = 0;
  double worst_late_mm = 0.0;
  for (std::size_t k = 0; k < pts.size(); ++k) {
    out.clear();
    const Event ev = sample(pts[k][0], pts[k][1], pts[k][2], pts[k][3], 12,
                            static_cast<TimeNs>(static_cast<double>(k) * 1e9 / rate_hz));
    comp.step(static_cast<TimeNs>(static_cast<double>(k) * 1e9 / rate_hz), {&ev, 1}, out);
    ASSERT_FALSE(has_alarm(out, AlarmCode::kCheckpointMissed)) << "sample " << k;
    while (passed < comp.passed()) {
      // The trigger comes at the first sample at or past the checkpoint: at most one sample late.
      const Checkpoint& cp = plan.checkpoints[passed];
      const double late_mm = std::hypot(pts[k][0] - cp.tool_x_mm, pts[k][1] - cp.tool_y_mm);
      worst_late_mm = std::max(worst_late_mm, late_mm);
      ++passed;
    }
  }
  EXPECT_EQ(passed, plan.checkpoints.size());
  EXPECT_EQ(comp.counters().triggers, plan.checkpoints.size());
  EXPECT_EQ(comp.counters().missed, 0U);
  EXPECT_LE(worst_late_mm, step_mm + 1e-9);
}

TEST(Trigger, NoMissedCheckpointAt10mPerMinAnd1kHzByPosition) {
  expect_no_missed(TriggerMode::kPosition, 1000.0);
}
TEST(Trigger, NoMissedCheckpointAt10mPerMinAnd250HzByPosition) {
  expect_no_missed(TriggerMode::kPosition, 250.0);
}
TEST(Trigger, NoMissedCheckpointAt10mPerMinAnd1kHzByPath) {
  expect_no_missed(TriggerMode::kPath, 1000.0);
}
TEST(Trigger, NoMissedCheckpointAt10mPerMinAnd250HzByPath) {
  expect_no_missed(TriggerMode::kPath, 250.0);
}

TEST(Levels, PositionTriggerAgreesWithThePathAndMeetsItselfAtTheSeam) {
  // The boss of the trigger tests, its tool centre path at 1 kHz and 10 m/min; creep values by
  // position (progress = tool travel) against those by program path.
  const PlanConfig pc = boss_plan_config();
  const Plan plan = make_plan(pc);
  const auto pts = tool_path(pc, plan, 10000.0 / 60.0 / 1000.0);
  std::vector<double> values(plan.checkpoints.size());
  for (std::size_t i = 0; i < values.size(); ++i) {
    values[i] = 20.0 * std::sin(0.7 * static_cast<double>(i)) - 3.0 * plan.checkpoints[i].level;
  }
  std::vector<double> by[2];
  for (int m = 0; m < 2; ++m) {
    CheckpointCompensator comp;
    CompensatorConfig cfg =
        live_config(ApplyMode::kCreep, m == 0 ? TriggerMode::kPath : TriggerMode::kPosition);
    cfg.xy_tolerance_mm = 0.2;
    comp.configure(cfg, plan.checkpoints, wide_limits());
    learn_values(comp, values);
    (void)run(comp, {part_start(1)});
    for (std::size_t k = 0; k < pts.size(); ++k) {
      (void)run(comp, {sample(pts[k][0], pts[k][1], pts[k][2], pts[k][3], 12,
                              static_cast<TimeNs>(k) * 1'000'000)});
      by[m].push_back(comp.live_target_um());
    }
    EXPECT_EQ(comp.passed(), plan.checkpoints.size());
  }
  // Per level: the first and the last sample of the pass are the same wall point; their values
  // differ by at most the ramp's slope over one sample (0.167 mm).
  double worst_seam[2] = {0.0, 0.0};
  double worst_diff = 0.0;
  std::size_t k0 = 0;
  for (std::size_t l = 0; l < plan.levels_z_mm.size(); ++l) {
    std::size_t k1 = k0;
    while (k1 + 1 < pts.size() && std::fabs(pts[k1 + 1][2] - pts[k0][2]) < 1e-9) ++k1;
    for (int m = 0; m < 2; ++m) {
      worst_seam[m] = std::max(worst_seam[m], std::fabs(by[m][k1] - by[m][k0]));
    }
    for (std::size_t k = k0; k <= k1; ++k) {
      worst_diff = std::max(worst_diff, std::fabs(by[0][k] - by[1][k]));
    }
    k0 = k1 + 1;
  }
  std::printf("seam step: path %.4f um, position %.4f um; position vs path max %.3f um\n",
              worst_seam[0], worst_seam[1], worst_diff);
  // The steepest ramp here is ~40 µm over 10 mm of seam span: 0.67 µm per sample at most.
  EXPECT_LT(worst_seam[0], 0.7);
  EXPECT_LT(worst_seam[1], 0.7);
  // Position progress runs ahead around convex corners (tool radius × turn), so the two differ
  // between checkpoints, never by a whole checkpoint-to-checkpoint difference (~40 µm).
  EXPECT_LT(worst_diff, 10.0);
}

TEST(Trigger, PositionTriggerNeedsTheRightLevelAndReportsAMissedPoint) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = live_config(ApplyMode::kStep, TriggerMode::kPosition);
  cfg.xy_tolerance_mm = 0.3;
  cfg.z_band_mm = 0.5;
  auto plan = line_plan(3);
  plan[0].tool_y_mm = 2.0;  // the tool passes 2 mm away from checkpoint 0: missed
  comp.configure(cfg, plan, wide_limits());
  (void)run(comp, {part_start(1)});
  // At the wrong height nothing triggers.
  (void)run(comp, {sample(0, 0, -7, kNaN, 12, 0)});
  (void)run(comp, {sample(25, 0, -7, kNaN, 12, 1)});
  EXPECT_EQ(comp.passed(), 0U);
  (void)run(comp, {sample(0, 0, -5, kNaN, 12, 2)});
  const StepOutput out = run(comp, {sample(25, 0, -5.2, kNaN, 12, 3)});
  EXPECT_TRUE(has_alarm(out, AlarmCode::kCheckpointMissed));
  EXPECT_EQ(comp.passed(), 2U);
  EXPECT_EQ(comp.counters().missed, 1U);
}

// --- persistence and restart ------------------------------------------------------------------

TEST(State, ExportImportRoundTrip) {
  CheckpointCompensator a;
  a.configure(base_config(), line_plan(3), wide_limits());
  (void)run(a, {part_start(1), probe(1, 0, 4.0), probe(1, 2, -3.0)});
  (void)run(a, {part_start(2), probe(2, 0, 1.0)});
  CheckpointState st;
  a.export_state(st);
  EXPECT_EQ(st.part_counter, 2);
  EXPECT_EQ(st.points[0].history_n, 2U);

  CheckpointCompensator b;
  b.configure(base_config(), line_plan(3), wide_limits());
  b.import_state(st);
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_DOUBLE_EQ(b.register_value_um(i), a.register_value_um(i));
    EXPECT_DOUBLE_EQ(b.learned_um(i), a.learned_um(i));
  }
  EXPECT_EQ(b.part_counter(), 2);
  // The restarted daemon rewrites its table.
  const StepOutput out = run(b, {});
  EXPECT_EQ(out.writes.size(), 3U);
  // The same next measurement gives the same result on both.
  (void)run(a, {probe(2, 0, 0.5)});
  (void)run(b, {probe(2, 0, 0.5)});
  EXPECT_DOUBLE_EQ(a.register_value_um(0), b.register_value_um(0));
}

TEST(State, ImportRefusesAStateThatDoesNotFitAndChangesNothing) {
  CheckpointCompensator comp;
  comp.configure(base_config(), line_plan(3), wide_limits());
  (void)run(comp, {probe(1, 0, 4.0)});
  CheckpointState st;
  comp.export_state(st);
  st.points.pop_back();
  EXPECT_THROW(comp.import_state(st), std::invalid_argument);
  comp.export_state(st);
  st.points[1].offset_um = std::nan("");
  EXPECT_THROW(comp.import_state(st), std::invalid_argument);
  comp.export_state(st);
  st.points[1].offset_um = 500.0;  // beyond max_abs_um 200
  EXPECT_THROW(comp.import_state(st), std::invalid_argument);
  comp.export_state(st);
  st.points[1].history_n = 99;
  EXPECT_THROW(comp.import_state(st), std::invalid_argument);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -4.0);
}

TEST(State, ReconcilePreferDaemonRewritesDifferingRegisters) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.reconcile_tolerance_um = 0.5;
  comp.configure(cfg, line_plan(3), wide_limits());
  (void)run(comp, {probe(1, 0, 4.0), probe(1, 1, 6.0), probe(1, 2, 8.0)});
  (void)run(comp, {});                               // nothing pending in mode A until part start
  const std::vector<double> nc = {-4.2, 0.0, -8.0};  // register 21 lost its value
  const ReconcileReport rep = comp.reconcile(nc);
  EXPECT_EQ(rep.compared, 3U);
  EXPECT_EQ(rep.mismatched, 1U);
  EXPECT_DOUBLE_EQ(rep.max_difference_um, 6.0);
  ASSERT_EQ(rep.mismatched_ids.size(), 1U);
  EXPECT_EQ(rep.mismatched_ids[0], 1);
  const StepOutput out = run(comp, {});
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_EQ(out.writes[0].register_index, 21U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, -6.0);
  EXPECT_TRUE(has_alarm(out, AlarmCode::kCheckpointRegisterMismatch));
  EXPECT_THROW((void)comp.reconcile(std::vector<double>{1.0}), std::invalid_argument);
}

TEST(State, ReconcilePreferNcAdoptsTheOperatorsValues) {
  CheckpointCompensator comp;
  CompensatorConfig cfg = base_config();
  cfg.reconcile_prefer = ReconcilePrefer::kNc;
  comp.configure(cfg, line_plan(2), wide_limits());
  (void)run(comp, {probe(1, 0, 4.0)});
  // Every difference adoptable: nothing is written (the NC holds exactly these values), and the
  // daemon's start-up hook is told not to resend the table (rewritten = 0).
  ReconcileReport rep = comp.reconcile(std::vector<double>{-2.0, 0.0});
  EXPECT_EQ(rep.mismatched, 1U);
  EXPECT_EQ(rep.rewritten, 0U);
  EXPECT_TRUE(rep.adopted_nc);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -2.0);
  StepOutput out = run(comp, {});
  EXPECT_TRUE(out.writes.empty());
  EXPECT_TRUE(has_alarm(out, AlarmCode::kCheckpointRegisterMismatch));
  // A non-finite read-back is never adopted: the daemon's 0 is rewritten, and since the whole
  // table is then sent again, the adopted value goes with it as the target.
  rep = comp.reconcile(std::vector<double>{-3.5, std::nan("")});
  EXPECT_EQ(rep.mismatched, 2U);
  EXPECT_EQ(rep.rewritten, 1U);
  EXPECT_DOUBLE_EQ(comp.register_value_um(0), -3.5);
  out = run(comp, {});
  ASSERT_EQ(out.writes.size(), 2U);
  EXPECT_EQ(out.writes[0].register_index, 20U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, -3.5);
  EXPECT_EQ(out.writes[1].register_index, 21U);
  EXPECT_DOUBLE_EQ(out.writes[1].value_um, 0.0);
}

TEST(RealTime, StepAllocatesNothing) {
  const Plan plan = make_plan(boss_plan_config());
  CheckpointCompensator comp;
  CompensatorConfig cfg = live_config(ApplyMode::kCreep, TriggerMode::kPosition);
  cfg.outlier_min_history = 2;
  comp.configure(cfg, plan.checkpoints, wide_limits());
  const auto pts = tool_path(boss_plan_config(), plan, 0.5);
  std::vector<Event> part_events;
  std::vector<Event> probes;
  for (std::size_t i = 0; i < plan.checkpoints.size(); ++i) {
    probes.emplace_back(test::probe_at(plan.checkpoints[i], 1, 3.0 + static_cast<double>(i % 5)));
  }
  probes.emplace_back(test::probe_at(plan.checkpoints[0], 1, 250.0));  // implausible
  probes.emplace_back(probe(1, 999, 1.0));                             // unknown checkpoint
  probes.emplace_back(probe(1, 1, 1.0, 0, 7.0));                       // α not the plan's
  ProbeMeasurement faulted = probe(1, 2, 0.0);
  faulted.fault = InputFault::kInvalid;
  probes.emplace_back(faulted);  // its value did not arrive intact
  const Event start = part_start(1);
  StepOutput out;
  nccomp::test::AllocationScope scope;
  for (int part = 0; part < 4; ++part) {
    out.clear();
    comp.step(0, {&start, 1}, out);
    for (std::size_t k = 0; k < pts.size(); ++k) {
      out.clear();
      const Event ev = sample(pts[k][0], pts[k][1], pts[k][2], pts[k][3], 12,
                              static_cast<TimeNs>(k) * 1'000'000);
      comp.step(static_cast<TimeNs>(k) * 1'000'000, {&ev, 1}, out);
    }
    out.clear();
    comp.step(0, probes, out);
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(comp.counters().missed, 0U);
  EXPECT_EQ(comp.counters().triggers, 4 * plan.checkpoints.size());
  EXPECT_EQ(comp.counters().invalid, 4U * 3U);
  EXPECT_EQ(comp.counters().implausible, 4U);
  EXPECT_GT(comp.counters().updates, 0U);
}

}  // namespace
}  // namespace nccomp::core::checkpoint

namespace nccomp::core::checkpoint {
namespace {

// GIVEN mode A with an average over 3 parts following a wear trend (true error 2, 4, 6 µm at
// parts 1-3: the average lags at 3.78 µm) WHEN a trim of −5 µm takes over the register
// (rebase by +5) THEN the residual is part 3's error less the trim's share, 6 − 5 = 1 µm, and
// the offset cancels it (−1 µm), not the lagging average less 5 (1.22 µm); part 3's applied
// value moves with the trim (−2.67 + 5); the history restarts, the next reading counts in full.
TEST(Compensator, ARebaseTakesTheLastPartsErrorLessTheTrimAsTheResidual) {
  CheckpointCompensator comp;
  CompensatorConfig cfg;
  cfg.ewma_weight = 3.0;
  cfg.dead_band_um = 0.0;
  cfg.probe_repeatability_um = 0.0;
  comp.configure(cfg, test::line_plan(1), test::wide_limits());
  StepOutput out;
  double applied = 0.0;
  for (int part = 1; part <= 3; ++part) {
    std::vector<Event> ev = {test::part_start(part)};
    comp.step(0, ev, out);
    applied = comp.register_value_um(0);
    ev = {test::probe(part, 0, 2.0 * part + applied)};
    comp.step(0, ev, out);
  }
  const double lagging = 2.0 + (4.0 - 2.0) / 3.0;
  ASSERT_NEAR(comp.learned_um(0), lagging + (6.0 - lagging) / 3.0, 1e-9);
  ASSERT_TRUE(comp.rebase(0, 0, 5.0, 0));
  EXPECT_NEAR(comp.learned_um(0), 1.0, 1e-9);
  EXPECT_NEAR(comp.register_value_um(0), -1.0, 1e-9);
  EXPECT_NEAR(comp.point(0).applied_um, applied + 5.0, 1e-9);
  EXPECT_EQ(comp.point(0).history_n, 0U);
  EXPECT_EQ(comp.learned_count(0), 0U);
  // An offset the limit refuses changes nothing.
  EXPECT_FALSE(comp.rebase(0, 0, 500.0, 0));
  EXPECT_NEAR(comp.register_value_um(0), -1.0, 1e-9);
  // Part 4 (true error 8, the trim took 5 + 2 more along the path): its residual 1.5 µm is
  // taken in full, not as a third of it.
  std::vector<Event> ev = {test::part_start(4)};
  comp.step(0, ev, out);
  ev = {test::probe(4, 0, 1.5 + comp.register_value_um(0))};
  comp.step(0, ev, out);
  EXPECT_NEAR(comp.register_value_um(0), -1.5, 1e-9);
}

}  // namespace
}  // namespace nccomp::core::checkpoint
