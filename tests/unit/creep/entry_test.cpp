// Items 7 and 8 of issue 3: sister-tool creep-in, retract / re-feed, smaller-tool creep-in / out;
// every offset absolute and through the limiter. Plus state export / import and config checks.
#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <string>

#include "core/common/config_issue.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using testing::base_config;
using testing::Rig;

TEST(CreepEntry, SisterRestartsBeforeTheLastMeasurementWithAPositiveOffsetCreepingToZero) {
  auto c = base_config();
  c.entry.sister_offset_um = 10.0;
  c.entry.sister_length_mm = 20.0;
  c.entry.sister_restart_back_mm = 30.0;
  c.output.restart_path_register = 14;
  Rig r(c);
  r.run_to(300.0);
  r.measure({20.0});
  r.run_to(400.0);
  EXPECT_NEAR(r.z(), -20.0, 1e-9);
  r.cutting = false;
  r.advance(0.0);
  r.tool_change(2, true);
  EXPECT_NEAR(r.comp.restart_program_path_mm(), 270.0, 1e-9);
  EXPECT_NEAR(r.last_write(14), 270000.0, 1e-6);  // [µm of program path]
  // The NC restarts the sister at 270 mm: a new, unworn tool held 10 µm off the surface.
  r.program_path_mm = 270.0;
  r.cutting = true;
  r.advance(0.0);
  EXPECT_NEAR(r.z(), 10.0, 1e-9);
  EXPECT_NEAR(r.comp.applied_wear_um(0), 0.0, 0.0);
  r.run_to(275.0);
  EXPECT_NEAR(r.z(), 10.0 * (1.0 - 5.0 / 20.0), 1e-9);
  r.run_to(290.0);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
}

TEST(CreepEntry, SmoothProfileEntersTangentially) {
  auto c = base_config();
  c.profile = ProfileShape::kCosine;
  c.entry.sister_offset_um = 10.0;
  c.entry.sister_length_mm = 20.0;
  Rig r(c);
  r.tool_change(2, true);
  r.run_to(0.1, 0.1);
  const double slope_start = (r.z() - 10.0) / 0.1;
  r.run_to(19.9);
  const double z_end = r.z();
  r.run_to(20.0, 0.1);
  EXPECT_NEAR(slope_start, 0.0, 0.01);
  EXPECT_NEAR((r.z() - z_end) / 0.1, 0.0, 0.01);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
}

TEST(CreepEntry, RetractAfterAMeasurementAndReFeed) {
  auto c = base_config();
  c.entry.retract_um = 5.0;
  c.entry.refeed_length_mm = 10.0;
  Rig r(c);
  r.run_to(100.0);
  r.measure({20.0});
  EXPECT_NEAR(r.z(), 5.0, 1e-9);  // held 5 µm away, the wear not yet in force
  r.run_to(105.0);
  EXPECT_NEAR(r.z(), 2.5 - 20.0 * 5.0 / 50.0, 1e-9);
  r.run_to(150.0);
  EXPECT_NEAR(r.z(), -20.0, 1e-9);
}

TEST(CreepEntry, SmallerToolCreepsInAndOutAtTheLargerToolsSurface) {
  auto c = base_config();
  c.transitions = {{7, 100.0, 200.0, 8.0, 10.0, 6.0, 20.0}};
  Rig r(c);
  r.tool_change(7, false);
  r.run_to(99.5);
  EXPECT_NEAR(r.z(), 0.0, 1e-12);
  r.run_to(100.0);
  EXPECT_NEAR(r.z(), 8.0, 1e-9);
  r.run_to(105.0);
  EXPECT_NEAR(r.z(), 4.0, 1e-9);
  r.run_to(150.0);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
  r.run_to(190.0);
  EXPECT_NEAR(r.z(), 3.0, 1e-9);
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), 6.0, 1e-9);
  r.run_to(201.0);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
  // Another tool on the same path: no transition.
  r.tool_change(8, false);
  r.program_path_mm = 104.0;
  r.advance(1.0);
  EXPECT_NEAR(r.z(), 0.0, 1e-12);
}

// ---- tools out of the spindle ------------------------------------------------------------

TEST(CreepToolMemory, AToolThatComesBackResumesWithItsWearAndItsCreep) {
  Rig r(base_config());
  r.measure({20.0});
  r.run_to(25.0);
  EXPECT_NEAR(r.z(), -10.0, 1e-9);
  r.tool_change(2, false);
  r.advance(0.0);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);  // tool 2 is new: no wear
  r.measure({4.0});
  r.run_to(200.0);
  EXPECT_NEAR(r.z(), -4.0, 1e-9);
  r.tool_change(1, false);
  r.advance(0.0);
  EXPECT_NEAR(r.z(), -10.0, 1e-9);                // tool 1 where it left off, mid-creep
  EXPECT_NEAR(r.comp.cut_path_mm(), 25.0, 1e-9);  // its own cut path
  r.run_to(225.0);
  EXPECT_NEAR(r.z(), -20.0, 1e-9);
  r.tool_change(2, false);
  r.advance(0.0);
  EXPECT_NEAR(r.z(), -4.0, 1e-9);
}

TEST(CreepToolMemory, AnAxisSampleWithAnotherToolIsATacitToolChange) {
  Rig r(base_config());
  r.measure({20.0});
  r.run_to(100.0);
  r.tool = 5;  // the NC says tool 5 is cutting; no ToolChange event arrived
  r.advance(0.5);
  EXPECT_EQ(r.comp.state().tool, 5);
  EXPECT_EQ(r.comp.counters().implicit_tool_changes, 1U);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
  r.tool = 1;
  r.advance(0.5);
  EXPECT_NEAR(r.z(), -20.0, 1e-9);
}

TEST(CreepToolMemory, ASisterReplacesTheWornToolForGood) {
  Rig r(base_config());
  r.measure({20.0});
  r.run_to(100.0);
  r.tool_change(3, true);
  r.advance(0.0);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
  r.tool_change(1, false);  // tool number 1 again: a fresh tool, the worn one is gone
  r.advance(0.0);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
}

TEST(CreepToolMemory, TheLeastRecentlyUsedToolIsForgottenBeyondTheSlots) {
  Rig r(base_config());
  for (std::int32_t t = 1; t <= static_cast<std::int32_t>(kMaxToolMemory) + 2; ++t) {
    if (t > 1) r.tool_change(t, false);
    r.measure({static_cast<double>(t)});
    r.run_to(r.program_path_mm + 100.0);
  }
  // Tools 1 and 2 were pushed out by 3..9 (8 slots, tool 10 in the spindle).
  r.tool_change(2, false);
  r.advance(0.0);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
  r.tool_change(9, false);
  r.advance(0.0);
  EXPECT_NEAR(r.z(), -9.0, 1e-9);
}

// ---- item 8 ------------------------------------------------------------------------------

TEST(CreepLimiter, AStepCorrectionIsSlewedAndEveryWriteIsAbsolute) {
  auto c = base_config();
  c.profile = ProfileShape::kStep;
  c.limiter = {100.0, 5.0, 1e6};
  Rig r(c);
  r.measure({20.0});
  r.writes.clear();
  for (int i = 0; i < 6; ++i) r.advance(0.5);
  std::vector<double> z;
  for (const auto& w : r.writes) {
    if (w.register_index == 2) z.push_back(w.value_um);
  }
  ASSERT_EQ(z.size(), 4U);
  EXPECT_NEAR(z[0], -5.0, 1e-9);
  EXPECT_NEAR(z[1], -10.0, 1e-9);
  EXPECT_NEAR(z[2], -15.0, 1e-9);
  EXPECT_NEAR(z[3], -20.0, 1e-9);
  EXPECT_EQ(r.count(AlarmCode::kOffsetSlewLimited), 1U);  // edge-triggered, not every cycle
}

TEST(CreepLimiter, RateLimitPerSecond) {
  auto c = base_config();
  c.profile = ProfileShape::kStep;
  c.limiter = {100.0, 100.0, 10.0};  // 10 µm/s
  Rig r(c);
  r.measure({20.0});
  for (int i = 0; i < 100; ++i) r.advance(0.01, 0.01);  // 1 s
  EXPECT_NEAR(r.z(), -10.0, 1e-6);
}

TEST(CreepLimiter, UnchangedValuesAreNotRewrittenButRefreshedPeriodically) {
  auto c = base_config();
  c.output.refresh_interval_s = 1.0;
  Rig r(c);
  r.writes.clear();
  for (int i = 0; i < 250; ++i) r.advance(0.0, 0.01);  // 2.5 s idle
  std::size_t z_writes = 0;
  for (const auto& w : r.writes) z_writes += w.register_index == 2 ? 1U : 0U;
  EXPECT_EQ(z_writes, 2U);
}

// ---- state -------------------------------------------------------------------------------

TEST(CreepStateIo, AResumedCompensatorContinuesExactlyWhereItWas) {
  auto c = base_config();
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 4;
  c.predict.enabled = true;
  c.profile = ProfileShape::kSmoothstep;
  Rig a(c);
  Rig b(c);
  for (Rig* r : {&a, &b}) {
    r->run_to(100.0);
    r->measure({4.0, 6.0, 8.0, 10.0});
    r->run_to(150.0);
    r->measure({6.0, 8.0, 9.0, 12.0});
    r->run_to(170.0);
  }
  // b "restarts": a fresh compensator gets b's state.
  const CreepState saved = b.comp.export_state();
  b.comp.configure(c);
  b.comp.import_state(saved);
  b.writes.clear();
  b.advance(0.0);  // re-anchor; every offset re-sent
  EXPECT_NEAR(b.last_write(2), a.z(), 1e-9);
  a.advance(0.0);
  for (double p = 175.0; p <= 260.0; p += 5.0) {
    a.run_to(p);
    b.run_to(p);
    EXPECT_NEAR(a.z(), b.z(), 1e-12) << p;
  }
  EXPECT_GT(a.comp.creeps_in_progress() + 1, 0U);
}

TEST(CreepStateIo, ImportRefusesAMismatchedOrCorruptState) {
  auto c = base_config();
  WearCompensator w;
  w.configure(c);
  CreepState s = w.export_state();
  s.edge_points = 3;
  EXPECT_THROW(w.import_state(s), std::invalid_argument);
  s = w.export_state();
  s.committed_um[0] = std::nan("");
  try {
    w.import_state(s);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("committed_um[0]"), std::string::npos);
  }
  s = w.export_state();
  s.creeps[0].active = true;
  s.creeps[0].span[0] = -1.0;
  EXPECT_THROW(w.import_state(s), std::invalid_argument);
}

// ---- config ------------------------------------------------------------------------------

std::string error_of(const CreepConfig& c) {
  try {
    validate(c);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(CreepConfigCheck, ErrorsNameTheTomlKey) {
  EXPECT_EQ(error_of(base_config()), "");
  auto c = base_config();
  c.creep_length_mm = 0.0;
  EXPECT_NE(error_of(c).find("creep.creep_length_mm"), std::string::npos);
  c = base_config();
  c.edge.edge_points = 40;
  EXPECT_NE(error_of(c).find("creep.edge.edge_points"), std::string::npos);
  c = base_config();
  c.profile = ProfileShape::kTable;
  c.profile_table = {0.0, 0.7, 0.5, 1.0};
  EXPECT_NE(error_of(c).find("creep.profile_table[2]"), std::string::npos);
  c = base_config();
  c.output.channel_register = {-1, -1, -1, -1, -1};
  EXPECT_NE(error_of(c).find("creep.output"), std::string::npos);
  c = base_config();
  c.output.channel_register = {0, 1, 2, 3, -1};
  EXPECT_NE(error_of(c).find("creep.output.mode"), std::string::npos);
  c = base_config();
  c.deflection = {{0, {0.0, 10.0, 5.0}, {0.0, 1.0, 2.0}, {0.0, 0.0, 0.0}}};
  EXPECT_NE(error_of(c).find("creep.deflection[0].wear_um[2]"), std::string::npos);
  c = base_config();
  c.transitions = {{7, 100.0, 110.0, 8.0, 10.0, 6.0, 20.0}};
  EXPECT_NE(error_of(c).find("creep.transition[0]"), std::string::npos);
  c = base_config();
  c.edge.normal_source = NormalSource::kToolpath;
  c.toolpath = {true, false, {{0.0, {0.0, 0.0, 1.0}}, {0.0, {0.0, 0.0, 1.0}}}};
  EXPECT_NE(
      error_of(c).find("creep.edge.toolpath_file: row 2: path_mm must be strictly increasing"),
      std::string::npos);
  c.toolpath = {false, true, {{0.0, {0.0, 0.0, 1.0}, 1.0}, {5.0, {0.0, 0.0, 1.0}, 1.0}}};
  EXPECT_NE(error_of(c).find("creep.edge.toolpath_file: needs at least 2 rows with normals"),
            std::string::npos);  // a removal-only file gives no normals
  c = base_config();
  c.interval.basis = IntervalBasis::kMaterial;
  c.interval.removal_source = RemovalSource::kToolpath;
  c.toolpath = {true, false, {{0.0, {0.0, 0.0, 1.0}}, {5.0, {0.0, 0.0, 1.0}}}};
  EXPECT_NE(error_of(c).find("creep.interval.removal_source"), std::string::npos);
  c.toolpath = {true, true, {{0.0, {0.0, 0.0, 1.0}, -1.0}, {5.0, {0.0, 0.0, 1.0}, 1.0}}};
  EXPECT_NE(
      error_of(c).find("creep.edge.toolpath_file: row 1: removal_mm2 must be a finite number >= 0"),
      std::string::npos)
      << error_of(c);
  c = base_config();
  c.limiter.max_step_um = -1.0;
  EXPECT_NE(error_of(c).find("creep.limiter.max_step_um"), std::string::npos);
}

TEST(CreepConfigCheck, EveryIssueIsReportedWithItsKeyAndReason) {
  auto c = base_config();
  c.creep_length_mm = -2.0;
  c.edge.edge_points = 40;
  c.limiter.max_step_um = -1.0;
  try {
    validate(c);
    FAIL() << "validate() accepted three bad values";
  } catch (const core::ConfigInvalid& e) {
    ASSERT_EQ(e.issues().size(), 3U) << e.what();
    EXPECT_EQ(e.issues()[0].key, "creep.creep_length_mm");
    EXPECT_EQ(e.issues()[0].reason.rfind("must be a positive finite number, got -2", 0), 0U)
        << e.issues()[0].reason;
    EXPECT_EQ(e.issues()[1].key, "creep.edge.edge_points");
    EXPECT_EQ(e.issues()[1].reason, "must be 1..32, got 40");
    EXPECT_EQ(e.issues()[2].key, "creep.limiter.max_step_um");
  }
  WearCompensator w;
  EXPECT_THROW(w.configure(c), std::invalid_argument);
}

// ---- real time ---------------------------------------------------------------------------

TEST(CreepRealTime, StepAllocatesNothingWith16PointsAnd4Creeps) {
  auto c = base_config();
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 16;
  c.edge.normal_source = NormalSource::kAxisSample;
  c.profile = ProfileShape::kCosine;
  c.predict.enabled = true;
  c.interval.basis = IntervalBasis::kAdaptive;
  c.deflection = {{0, {0.0, 50.0}, {0.0, 5.0}, {0.0, 3.0}}};
  c.entry.retract_um = 3.0;
  c.creep_length_mm = 1000.0;
  Rig r(c);
  r.has_normal = true;
  r.normal = {0.6, 0.0, 0.8};
  std::vector<double> wear(16);
  std::vector<Event> events;
  for (int m = 0; m < 4; ++m) {
    for (std::size_t i = 0; i < 16; ++i)
      wear[i] = 2.0 * (m + 1) * (m + 1) +
                0.1 * static_cast<double>(i);  // not linear: no perfect prediction
    r.run_to(r.program_path_mm + 10.0);
    r.measure(wear);
  }
  ASSERT_EQ(r.comp.creeps_in_progress(), 4U);
  // Events built before the counted scope; a measurement inside it as well.
  ToolMeasurement tm;
  tm.tool = 1;
  tm.point_count = 16;
  for (std::size_t i = 0; i < 16; ++i) tm.wear_um[i] = 40.0 + 0.1 * static_cast<double>(i);
  AxisSample a;
  a.normal = {0.6, 0.0, 0.8};
  a.has_normal = true;
  a.tool = 1;
  events.reserve(4);
  StepOutput out;
  TimeNs now = r.now_ns;
  double path = r.program_path_mm;
  std::uint64_t allocations = 0;
  for (int k = 0; k < 2000; ++k) {
    events.clear();
    now += 1'000'000;
    path += 0.05;
    a.time_ns = now;
    a.program_path_mm = path;
    a.position_mm[0] = path;
    events.emplace_back(a);
    if (k == 1000) events.emplace_back(tm);
    // Another tool and back: the states are swapped through the tool memory, no allocation.
    if (k == 1500) {
      events.clear();
      events.emplace_back(ToolChange{now, 2, false});
      a.tool = 2;
      events.emplace_back(a);
    }
    if (k == 1600) {
      events.clear();
      events.emplace_back(ToolChange{now, 1, false});
      a.tool = 1;
      events.emplace_back(a);
    }
    out.clear();
    nccomp::test::AllocationScope scope;
    r.comp.step(now, events, out);
    allocations += scope.count();
  }
  EXPECT_EQ(allocations, 0U);
  EXPECT_EQ(r.comp.counters().measurements_accepted, 5U);
  EXPECT_EQ(r.comp.counters().creeps_folded, 1U);  // the fifth creep folded into the slots
  EXPECT_FALSE(r.comp.halted());
  EXPECT_EQ(r.comp.counters().implicit_tool_changes, 0U);
}

}  // namespace
}  // namespace nccomp::core::creep
