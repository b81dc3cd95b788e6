// GIVEN an engine with registers and test modules, WHEN it is stepped, THEN every target passes
// the register's limiter, invalid input is counted and alarmed, and nothing allocates.
#include "core/engine/engine.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "core/engine/ramp_module.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

constexpr TimeNs kMs = 1'000'000;

RegisterSpec reg(const char* name, double max_abs = 100.0, double max_step = 5.0,
                 double max_rate = 1000.0) {
  return RegisterSpec{name, RegisterKind::kToolLengthWear,
                      LimiterConfig{max_abs, max_step, max_rate}};
}

// Writes a fixed value to one register every cycle; counts the events it sees.
class ConstantModule final : public Module {
 public:
  ConstantModule(const char* name, std::uint16_t reg_index, double value)
      : value_(value), name_(name), reg_(reg_index) {}
  std::string_view name() const noexcept override { return name_; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept override {
    events_seen += events.size();
    out.writes.push(OffsetWrite{now_ns, reg_, value_});
  }
  std::size_t events_seen{0};
  double value_;

 private:
  const char* name_;
  std::uint16_t reg_;
};

struct Fixture {
  Engine engine;
  StepOutput out;
  std::vector<ConstantModule*> mods;

  void configure(std::vector<RegisterSpec> regs, std::vector<std::pair<std::uint16_t, double>> c) {
    std::vector<std::unique_ptr<Module>> m;
    int k = 0;
    static const char* names[] = {"m0", "m1", "m2", "m3"};
    for (auto [r, v] : c) {
      auto p = std::make_unique<ConstantModule>(names[k++], r, v);
      mods.push_back(p.get());
      m.push_back(std::move(p));
    }
    engine.configure(std::move(regs), std::move(m));
  }
  void step(TimeNs t, std::span<const Event> ev = {}) { engine.step(t, ev, out); }
};

TEST(Engine, PassesAnAdmissibleTargetOnceAndThenStaysQuiet) {
  Fixture f;
  f.configure({reg("a")}, {{0, 2.5}});
  f.step(1 * kMs);
  ASSERT_EQ(f.out.writes.size(), 1U);
  EXPECT_EQ(f.out.writes[0].register_index, 0);
  EXPECT_DOUBLE_EQ(f.out.writes[0].value_um, 2.5);
  // Same target again: the NC already holds it, nothing is written.
  f.step(2 * kMs);
  EXPECT_EQ(f.out.writes.size(), 0U);
  EXPECT_EQ(f.engine.counters().writes_forwarded, 1U);
  EXPECT_DOUBLE_EQ(f.engine.register_state(0).output_um, 2.5);
}

TEST(Engine, RejectsNonFiniteTargetWithAlarmAndHoldsTheRegister) {
  Fixture f;
  f.configure({reg("a")}, {{0, 1.0}});
  f.step(1 * kMs);
  f.mods[0]->value_ = std::numeric_limits<double>::quiet_NaN();
  f.step(2 * kMs);
  EXPECT_EQ(f.out.writes.size(), 0U);
  ASSERT_EQ(f.out.alarms.size(), 1U);
  EXPECT_EQ(f.out.alarms[0].code, AlarmCode::kOffsetNonFinite);
  EXPECT_EQ(f.out.alarms[0].severity, Severity::kAlarm);
  EXPECT_EQ(f.out.alarms[0].subject, 0);
  EXPECT_DOUBLE_EQ(f.engine.register_state(0).output_um, 1.0);
  EXPECT_DOUBLE_EQ(f.engine.register_state(0).target_um, 1.0);
  EXPECT_EQ(f.engine.counters().writes_rejected, 1U);
}

TEST(Engine, RejectsTargetBeyondAbsoluteLimit) {
  Fixture f;
  f.configure({reg("a", 10.0)}, {{0, 10.5}});
  f.step(1 * kMs);
  EXPECT_EQ(f.out.writes.size(), 0U);
  ASSERT_EQ(f.out.alarms.size(), 1U);
  EXPECT_EQ(f.out.alarms[0].code, AlarmCode::kOffsetBeyondAbsoluteLimit);
  EXPECT_DOUBLE_EQ(f.out.alarms[0].value, 10.5);
  EXPECT_FALSE(f.engine.register_state(0).has_target);
}

TEST(Engine, SlewedTargetKeepsConvergingWithOneWarning) {
  Fixture f;
  // 5 µm per write, 1000 µm/s → 1 µm per 1 ms cycle.
  f.configure({reg("a", 100.0, 5.0, 1000.0)}, {{0, 4.0}});
  f.step(0);
  ASSERT_EQ(f.out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(f.out.writes[0].value_um, 4.0);  // first write: only the step cap applies
  f.mods[0]->value_ = 10.0;
  int warnings = 0;
  std::vector<double> values;
  for (int k = 1; k <= 10; ++k) {
    f.step(k * kMs);
    for (const auto& a : f.out.alarms) {
      warnings += a.code == AlarmCode::kOffsetSlewLimited ? 1 : 0;
    }
    for (const auto& w : f.out.writes) {
      values.push_back(w.value_um);
    }
  }
  EXPECT_EQ(warnings, 1);
  ASSERT_EQ(values.size(), 6U);  // 5, 6, 7, 8, 9, 10
  for (std::size_t i = 0; i < values.size(); ++i) {
    EXPECT_NEAR(values[i], 5.0 + static_cast<double>(i), 1e-9);
  }
  EXPECT_FALSE(f.engine.register_state(0).slewing);
}

TEST(Engine, InvalidEventsAreCountedAlarmedAndNotForwarded) {
  Fixture f;
  f.configure({reg("a")}, {{0, 0.0}});
  AxisSample good;
  good.position_mm = {1.0, 2.0, 3.0};
  AxisSample bad = good;
  bad.position_mm[1] = std::numeric_limits<double>::infinity();
  ToolMeasurement bad_wear;
  bad_wear.wear_um[0] = std::numeric_limits<double>::quiet_NaN();
  ToolMeasurement broken = bad_wear;
  broken.broken = true;  // wear values of a broken report are not looked at
  TemperatureSample bad_temp;
  bad_temp.temperature_c = std::numeric_limits<double>::quiet_NaN();
  CalibrationTouch bad_dir;
  bad_dir.direction = 0;
  const std::vector<Event> ev{good, bad, bad_wear, broken, bad_temp, bad_dir};
  f.step(kMs, ev);
  EXPECT_EQ(f.mods[0]->events_seen, 2U);
  EXPECT_EQ(f.engine.counters().events_invalid, 4U);
  EXPECT_EQ(f.engine.counters().events_accepted, 2U);
  int invalid_alarms = 0;
  for (const auto& a : f.out.alarms) {
    invalid_alarms += a.code == AlarmCode::kEventInvalid ? 1 : 0;
  }
  EXPECT_EQ(invalid_alarms, 4);
}

// Keeps a copy of every event it is stepped with.
class RecordingModule final : public Module {
 public:
  std::string_view name() const noexcept override { return "rec"; }
  void attach(const RegisterTable& /*registers*/) override { seen.reserve(16); }
  void step(TimeNs /*now_ns*/, std::span<const Event> events,
            StepOutput& /*out*/) noexcept override {
    for (const Event& e : events) {
      if (seen.size() < seen.capacity()) seen.push_back(e);
    }
  }
  std::vector<Event> seen;
};

// Issue 17, finding 4. GIVEN faulted measurements (the NC reported them, the driver could not use
// their values) whose value fields still hold NaN / inf / an absurd value, WHEN the engine steps
// them, THEN they reach the modules (so that each method can raise its alarm) with the fault and
// every value field 0, are not counted invalid; a fault code outside the enum is invalid.
TEST(Engine, FaultedMeasurementsReachTheModulesWithEveryValueZero) {
  Engine e;
  std::vector<std::unique_ptr<Module>> m;
  auto rec = std::make_unique<RecordingModule>();
  RecordingModule* r = rec.get();
  m.push_back(std::move(rec));
  e.configure({reg("a")}, std::move(m));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  ToolMeasurement tm;
  tm.tool = 5;
  tm.point_count = 2;
  tm.wear_um[0] = nan;
  tm.wear_um[1] = 3000.0;
  tm.fault = InputFault::kInvalid;
  ProbeMeasurement pm;
  pm.checkpoint = 4;
  pm.raw_deviation_um = inf;
  pm.wall_angle_deg = -inf;
  pm.ball_radius_mm = nan;
  pm.position_mm = {nan, 1.0, 2.0};
  pm.fault = InputFault::kOutOfRange;
  CalibrationTouch ct;
  ct.axis = 2;
  ct.trigger_position_mm = nan;
  ct.fault = InputFault::kInvalid;
  ToolMeasurement bad_code;
  bad_code.fault = static_cast<InputFault>(7);
  const std::vector<Event> ev{tm, pm, ct, bad_code};
  StepOutput out;
  e.step(kMs, ev, out);
  EXPECT_EQ(e.counters().events_accepted, 3U);
  EXPECT_EQ(e.counters().events_invalid, 1U);
  ASSERT_EQ(r->seen.size(), 3U);
  const auto& t = std::get<ToolMeasurement>(r->seen[0]);
  EXPECT_EQ(t.fault, InputFault::kInvalid);
  EXPECT_EQ(t.tool, 5);
  for (double w : t.wear_um) EXPECT_EQ(w, 0.0);
  const auto& p = std::get<ProbeMeasurement>(r->seen[1]);
  EXPECT_EQ(p.fault, InputFault::kOutOfRange);
  EXPECT_EQ(p.checkpoint, 4);
  EXPECT_EQ(p.raw_deviation_um, 0.0);
  EXPECT_EQ(p.wall_angle_deg, 0.0);
  EXPECT_EQ(p.ball_radius_mm, 0.0);
  for (double x : p.position_mm) EXPECT_EQ(x, 0.0);
  const auto& c = std::get<CalibrationTouch>(r->seen[2]);
  EXPECT_EQ(c.fault, InputFault::kInvalid);
  EXPECT_EQ(c.axis, 2);
  EXPECT_EQ(c.trigger_position_mm, 0.0);
}

TEST(Engine, EventsBeyondCapacityAreCountedNotForwarded) {
  Engine e;
  std::vector<std::unique_ptr<Module>> m;
  auto c = std::make_unique<ConstantModule>("c", 0, 0.0);
  auto* cp = c.get();
  m.push_back(std::move(c));
  e.configure({reg("a")}, std::move(m), EngineOptions{3});
  const std::vector<Event> ev(5, Event{AxisSample{}});
  StepOutput out;
  e.step(0, ev, out);
  EXPECT_EQ(cp->events_seen, 3U);
  EXPECT_EQ(e.counters().events_overflow, 2U);
}

TEST(Engine, UnknownRegisterRaisesAlarm) {
  Fixture f;
  f.configure({reg("a")}, {{7, 1.0}});
  f.step(kMs);
  EXPECT_EQ(f.out.writes.size(), 0U);
  ASSERT_EQ(f.out.alarms.size(), 1U);
  EXPECT_EQ(f.out.alarms[0].code, AlarmCode::kRegisterUnknown);
  EXPECT_EQ(f.out.alarms[0].subject, 7);
}

TEST(Engine, HoldModeWritesNothingButKeepsTargets) {
  Fixture f;
  f.configure({reg("a")}, {{0, 3.0}});
  f.engine.set_hold(true);
  f.step(kMs);
  EXPECT_EQ(f.out.writes.size(), 0U);
  EXPECT_EQ(f.engine.counters().writes_held, 1U);
  f.engine.set_hold(false);
  f.step(2 * kMs);
  ASSERT_EQ(f.out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(f.out.writes[0].value_um, 3.0);
}

TEST(Engine, ResendAllWritesKnownValuesAgain) {
  Fixture f;
  f.configure({reg("a"), reg("b")}, {{0, 3.0}});
  f.step(kMs);
  f.engine.resend_all();
  f.step(2 * kMs);
  ASSERT_EQ(f.out.writes.size(), 1U);  // b was never written: nothing to resend
  EXPECT_EQ(f.out.writes[0].register_index, 0);
  EXPECT_DOUBLE_EQ(f.out.writes[0].value_um, 3.0);
}

TEST(Engine, ConfigureRejectsBadTables) {
  Engine e;
  EXPECT_THROW(e.configure({reg("a"), reg("a")}, {}), std::invalid_argument);
  EXPECT_THROW(e.configure({reg("")}, {}), std::invalid_argument);
  EXPECT_THROW(e.configure({reg("a", -1.0)}, {}), std::invalid_argument);
  std::vector<std::unique_ptr<Module>> m;
  m.push_back(std::make_unique<ConstantModule>("x", 0, 0.0));
  m.push_back(std::make_unique<ConstantModule>("x", 0, 0.0));
  EXPECT_THROW(e.configure({reg("a")}, std::move(m)), std::invalid_argument);
  std::vector<std::unique_ptr<Module>> r;
  r.push_back(std::make_unique<RampModule>(RampConfig{"ramp", "missing", 0.0, 1.0, 1.0}));
  try {
    e.configure({reg("a")}, std::move(r));
    FAIL() << "expected a throw";
  } catch (const std::invalid_argument& ex) {
    EXPECT_NE(std::string(ex.what()).find("missing"), std::string::npos);
  }
}

std::unique_ptr<Engine> ramp_engine(double target_um, double rate_um_per_s) {
  auto e = std::make_unique<Engine>();
  std::vector<std::unique_ptr<Module>> m;
  m.push_back(std::make_unique<RampModule>(RampConfig{"ramp", "a", 0.0, target_um, rate_um_per_s}));
  e->configure({reg("b"), reg("a")}, std::move(m));
  return e;
}

TEST(EngineState, ExportImportResumesRampWithoutDoubling) {
  auto e1 = ramp_engine(10.0, 100.0);  // 0.1 µm per ms
  StepOutput out;
  for (int k = 0; k <= 40; ++k) {
    e1->step(k * kMs, {}, out);
  }
  EXPECT_NEAR(e1->register_state(1).output_um, 4.0, 1e-9);
  std::vector<std::byte> buf(e1->state_capacity());
  const std::size_t n = e1->export_state(buf);
  ASSERT_GT(n, 0U);

  // A restart: a fresh engine, a clock far away (the time the daemon was down is not made up).
  auto e2 = ramp_engine(10.0, 100.0);
  std::size_t skipped = 99;
  ASSERT_TRUE(e2->import_state(std::span<const std::byte>(buf.data(), n), 5'000 * kMs, &skipped));
  EXPECT_EQ(skipped, 0U);
  EXPECT_NEAR(e2->register_state(1).output_um, 4.0, 1e-9);
  e2->step(5'000 * kMs, {}, out);
  EXPECT_EQ(out.writes.size(), 0U);  // the NC already holds 4.0
  double last = 4.0;
  for (int k = 1; k <= 100; ++k) {
    e2->step(5'000 * kMs + k * kMs, {}, out);
    for (const auto& w : out.writes) {
      EXPECT_GE(w.value_um, last);
      EXPECT_LE(w.value_um - last, 0.1 + 1e-9);
      last = w.value_um;
    }
  }
  EXPECT_NEAR(e2->register_state(1).output_um, 10.0, 1e-9);
}

TEST(EngineState, EveryTruncationIsRejectedAndLeavesTheEngineUnchanged) {
  auto e1 = ramp_engine(10.0, 100.0);
  StepOutput out;
  for (int k = 0; k <= 20; ++k) {
    e1->step(k * kMs, {}, out);
  }
  std::vector<std::byte> buf(e1->state_capacity());
  const std::size_t n = e1->export_state(buf);
  auto e2 = ramp_engine(10.0, 100.0);
  for (std::size_t len = 0; len < n; ++len) {
    EXPECT_FALSE(e2->import_state(std::span<const std::byte>(buf.data(), len), 0)) << len;
  }
  EXPECT_DOUBLE_EQ(e2->register_state(1).output_um, 0.0);
  // A flipped magic byte and a NaN value are rejected too.
  auto bad = buf;
  bad[0] = std::byte{0};
  EXPECT_FALSE(e2->import_state(std::span<const std::byte>(bad.data(), n), 0));
  EXPECT_TRUE(e2->import_state(std::span<const std::byte>(buf.data(), n), 0));
  EXPECT_NEAR(e2->register_state(1).output_um, 2.0, 1e-9);
}

TEST(EngineState, AnOutputBeyondTheRegistersAbsoluteLimitIsRefused) {
  // Found by fuzz_state_import: a state whose register output lies beyond max_abs_um (a larger
  // limit before, or a corrupt file) was taken, and the limiter slewed from there: every write
  // lay beyond the limit.
  auto e1 = ramp_engine(40.0, 100.0);
  StepOutput out;
  for (int k = 0; k <= 500; ++k) e1->step(k * kMs, {}, out);
  ASSERT_NEAR(e1->register_state(1).output_um, 40.0, 1e-9);
  std::vector<std::byte> buf(e1->state_capacity());
  const std::size_t n = e1->export_state(buf);

  Engine e2;
  std::vector<std::unique_ptr<Module>> m;
  m.push_back(std::make_unique<RampModule>(RampConfig{"ramp", "a", 0.0, 10.0, 100.0}));
  e2.configure({reg("b"), reg("a", 30.0)}, std::move(m));
  EXPECT_FALSE(e2.import_state(std::span<const std::byte>(buf.data(), n), 0));
  EXPECT_DOUBLE_EQ(e2.register_state(1).output_um, 0.0);
  for (int k = 1; k <= 200; ++k) {
    e2.step(k * kMs, {}, out);
    for (const auto& w : out.writes) EXPECT_LE(std::fabs(w.value_um), 30.0);
  }
  // At the limit itself it is taken.
  Engine e3;
  e3.configure({reg("b"), reg("a", 40.0)}, {});
  EXPECT_TRUE(e3.import_state(std::span<const std::byte>(buf.data(), n), 0));
  EXPECT_NEAR(e3.register_state(1).output_um, 40.0, 1e-9);
}

TEST(EngineState, ImportSkipsRegistersAndModulesTheConfigNoLongerHas) {
  auto e1 = ramp_engine(10.0, 100.0);
  StepOutput out;
  e1->step(0, {}, out);
  e1->step(kMs, {}, out);
  std::vector<std::byte> buf(e1->state_capacity());
  const std::size_t n = e1->export_state(buf);
  Engine e2;
  e2.configure({reg("a")}, {});
  std::size_t skipped = 0;
  ASSERT_TRUE(e2.import_state(std::span<const std::byte>(buf.data(), n), 0, &skipped));
  EXPECT_EQ(skipped, 2U);  // register b and module ramp
  EXPECT_NEAR(e2.register_state(0).output_um, 0.1, 1e-9);
}

TEST(EngineState, ExportIntoTooSmallBufferReturnsZero) {
  auto e = ramp_engine(10.0, 100.0);
  std::vector<std::byte> buf(e->state_capacity() - 1);
  EXPECT_EQ(e->export_state(buf), 0U);
}

TEST(EngineRealtime, StepExportImportAllocateNothing) {
  auto e = ramp_engine(10.0, 100.0);
  StepOutput out;
  std::vector<std::byte> buf(e->state_capacity());
  AxisSample s;
  AxisSample bad;
  bad.position_mm[0] = std::numeric_limits<double>::quiet_NaN();
  ToolMeasurement faulted;
  faulted.wear_um[0] = std::numeric_limits<double>::quiet_NaN();
  faulted.fault = InputFault::kInvalid;
  const std::vector<Event> ev{s, bad, ToolChange{}, ProgramEvent{}, faulted};
  e->step(0, ev, out);  // warm-up
  nccomp::test::AllocationScope scope;
  std::size_t n = 0;
  for (int k = 1; k < 2000; ++k) {
    e->step(k * kMs, ev, out);
    if (k % 100 == 0) {
      n = e->export_state(buf);
      (void)e->import_state(std::span<const std::byte>(buf.data(), n), k * kMs);
    }
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_GT(n, 0U);
  EXPECT_NEAR(e->register_state(1).output_um, 10.0, 1e-9);
}

TEST(EngineState, GenerationAdvancesOnChangeOnly) {
  auto e = ramp_engine(0.2, 100.0);
  StepOutput out;
  e->step(0, {}, out);
  const auto g0 = e->state_generation();
  e->step(kMs, {}, out);
  EXPECT_GT(e->state_generation(), g0);
  for (int k = 2; k < 10; ++k) {
    e->step(k * kMs, {}, out);
  }
  const auto g1 = e->state_generation();
  e->step(10 * kMs, {}, out);  // ramp done, output at target
  EXPECT_EQ(e->state_generation(), g1);
}

}  // namespace
}  // namespace nccomp::core::engine

namespace nccomp::core::engine {
namespace {

// Writes `count` registers from `first`, each its own value, every cycle.
class TableModule final : public Module {
 public:
  TableModule(std::uint16_t first, std::uint16_t count, double value)
      : first_(first), count_(count), value_(value) {}
  std::string_view name() const noexcept override { return "table"; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    // Like S1 at part start: at most 32 new targets per cycle, in turn.
    for (int k = 0; k < 32; ++k) {
      const auto i = static_cast<std::uint16_t>(first_ + next_);
      out.writes.push(OffsetWrite{now_ns, i, value_ + static_cast<double>(next_)});
      next_ = static_cast<std::uint16_t>((next_ + 1) % count_);
    }
  }

 private:
  std::uint16_t first_;
  std::uint16_t count_;
  std::uint16_t next_{0};
  double value_;
};

TEST(Engine, FlagRegistersAreWrittenAsAskedWithinTheirAbsoluteBound) {
  Fixture f;
  // A restart path of 2.5 m [µm] into a flag register whose step and rate limits are tiny: the
  // flag is written at once; an offset register with the same limits would slew for hours.
  RegisterSpec flag{"restart_path", RegisterKind::kFlag, LimiterConfig{1e7, 0.001, 0.001}};
  f.configure({flag}, {{0, 2.5e6}});
  EXPECT_EQ(to_string(RegisterKind::kFlag), "flag");
  RegisterKind k{};
  ASSERT_TRUE(parse_register_kind("flag", k));
  EXPECT_EQ(k, RegisterKind::kFlag);
  f.step(0);
  ASSERT_EQ(f.out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(f.out.writes[0].value_um, 2.5e6);
  f.mods[0]->value_ = 0.0;  // and back to 0 at once (a flag cleared)
  f.step(kMs);
  ASSERT_EQ(f.out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(f.out.writes[0].value_um, 0.0);
  EXPECT_DOUBLE_EQ(f.engine.register_state(0).output_um, 0.0);
  // Beyond the absolute bound or not finite: refused with the limiter's alarms, value held.
  f.mods[0]->value_ = 2e7;
  f.step(2 * kMs);
  EXPECT_TRUE(f.out.writes.empty());
  ASSERT_EQ(f.out.alarms.size(), 1U);
  EXPECT_EQ(f.out.alarms[0].code, AlarmCode::kOffsetBeyondAbsoluteLimit);
  f.mods[0]->value_ = std::nan("");
  f.step(3 * kMs);
  EXPECT_TRUE(f.out.writes.empty());
  ASSERT_EQ(f.out.alarms.size(), 1U);
  EXPECT_EQ(f.out.alarms[0].code, AlarmCode::kOffsetNonFinite);
}

TEST(Engine, MoreWritesThanOneOutputHoldsAreDeferredInTurnNotLost) {
  // 400 registers (an S1 table of 400 checkpoints), each slewing at 1 µm per cycle towards
  // 20 + i µm: every cycle all of them want a write, 128 fit. Without taking turns registers
  // 128..399 would never be written.
  constexpr std::uint16_t kCount = 400;
  std::vector<RegisterSpec> regs;
  for (std::uint16_t i = 0; i < kCount; ++i) {
    regs.push_back(RegisterSpec{"cp" + std::to_string(i), RegisterKind::kCheckpoint,
                                LimiterConfig{1000.0, 1.0, 1000.0}});
  }
  Engine engine;
  std::vector<std::unique_ptr<Module>> mods;
  mods.push_back(std::make_unique<TableModule>(0, kCount, 20.0));
  engine.configure(std::move(regs), std::move(mods));
  StepOutput out;
  std::vector<int> writes(kCount, 0);
  for (int c = 0; c < 40; ++c) {
    engine.step(c * kMs, {}, out);
    EXPECT_LE(out.writes.size(), out.writes.capacity());
    for (const auto& w : out.writes) ++writes[w.register_index];
  }
  // No write was lost to a full output (the 400 "slewing" warnings do overflow the 32 alarm
  // slots: that is counted in output_overflows, and not this test's subject).
  EXPECT_EQ(out.writes.overflows(), 0U);
  EXPECT_GT(engine.counters().writes_deferred, 0U);
  // The module hands out 32 targets per cycle (all 400 after 13 cycles); from then on 128
  // writes per cycle go round all 400 registers: over the last 27 cycles each gets 8 or 9
  // turns, so every register has at least 8 and none starved.
  for (std::uint16_t i = 0; i < kCount; ++i) {
    EXPECT_GE(writes[i], 8) << "register " << i;
  }
  // Each write moved its register by 1 µm: register i holds its number of turns.
  EXPECT_DOUBLE_EQ(engine.register_state(399).output_um, static_cast<double>(writes[399]));
}

}  // namespace
}  // namespace nccomp::core::engine

namespace nccomp::core::engine {
namespace {

// Writes one register and says so.
class OwnedModule final : public Module {
 public:
  OwnedModule(const char* name, std::uint16_t reg) : name_(name), reg_(reg) {}
  std::string_view name() const noexcept override { return name_; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    out.writes.push(OffsetWrite{now_ns, reg_, 1.0});
  }
  std::vector<std::uint16_t> written_registers() const override { return {reg_}; }

 private:
  const char* name_;
  std::uint16_t reg_;
};

TEST(Engine, ConfigureRefusesTwoModulesOnOneRegister) {
  Engine e;
  std::vector<std::unique_ptr<Module>> m;
  m.push_back(std::make_unique<OwnedModule>("creep", 1));
  m.push_back(std::make_unique<OwnedModule>("calibration", 1));
  try {
    e.configure({reg("a"), reg("b")}, std::move(m));
    FAIL() << "configure accepted two writers of register 'b'";
  } catch (const std::invalid_argument& ex) {
    EXPECT_STREQ(ex.what(),
                 "engine: register 'b' is written by module 'creep' and by 'calibration'; give "
                 "each module its own registers");
  }
  std::vector<std::unique_ptr<Module>> ok;
  ok.push_back(std::make_unique<OwnedModule>("creep", 0));
  ok.push_back(std::make_unique<OwnedModule>("calibration", 1));
  EXPECT_NO_THROW(e.configure({reg("a"), reg("b")}, std::move(ok)));
}

}  // namespace
}  // namespace nccomp::core::engine
