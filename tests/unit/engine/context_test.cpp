// GIVEN the engine's machine context WHEN axis samples, tool changes, program events and
// temperatures arrive THEN the cut path per tool is counted exactly as the creep module counts
// it, the time since the warm start follows the documented rule (and its origin survives a
// restart), and every measurement record leaves the engine with path_mm, temp_c and time_s.
#include "core/engine/context.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

constexpr TimeNs kS = 1'000'000'000;

AxisSample sample(double x, double y, std::int32_t tool, bool cutting = true,
                  double program_path_mm = kNaN) {
  AxisSample a;
  a.position_mm = {x, y, 0.0, 0.0, 0.0, 0.0};
  a.tool = tool;
  a.cutting = cutting;
  a.program_path_mm = program_path_mm;
  return a;
}

void feed(MachineContext& c, TimeNs t, std::vector<Event> ev) { c.update(t, ev); }

TEST(MachineContextPath, ToolMemorySisterAndTheUnnamedTool) {
  MachineContext ctx;
  TimeNs t = 0;
  // Tool 5: 10 cutting samples 1 mm apart → 9 mm.
  for (int k = 0; k < 10; ++k) feed(ctx, t += kS, {sample(k, 0, 5)});
  EXPECT_DOUBLE_EQ(ctx.cut_path_mm(), 9.0);
  // Tool 6 (event; the tool goes there in rapid, not cutting), 4 mm; tool 5 back: its 9 mm
  // continue.
  t += kS;  // before the events that carry it (argument order is unspecified)
  feed(ctx, t, {sample(50, 0, 5, false), ToolChange{t, 6, false}});
  for (int k = 0; k < 5; ++k) feed(ctx, t += kS, {sample(100 + k, 0, 6)});
  EXPECT_DOUBLE_EQ(ctx.cut_path_mm(), 4.0);
  t += kS;
  feed(ctx, t, {sample(50, 0, 6, false), ToolChange{t, 5, false}});
  EXPECT_DOUBLE_EQ(ctx.cut_path_mm(), 9.0);
  EXPECT_DOUBLE_EQ(ctx.cut_path_mm(6), 4.0);
  // A sister replaces tool 5: path 0, tool 5 forgotten.
  t += kS;
  feed(ctx, t, {ToolChange{t, 7, true}});
  EXPECT_DOUBLE_EQ(ctx.cut_path_mm(), 0.0);
  EXPECT_TRUE(std::isnan(ctx.cut_path_mm(5)));
  // An interruption stops the count until the second cutting sample after the resume.
  feed(ctx, t += kS, {sample(0, 0, 7, false)});
  feed(ctx, t += kS, {sample(0, 0, 7)});
  feed(ctx, t += kS, {sample(2, 0, 7)});
  t += kS;
  feed(ctx, t, {ProgramEvent{t, ProgramEventKind::kInterruption, 3}, sample(4, 0, 7)});
  feed(ctx, t += kS, {sample(6, 0, 7)});
  t += kS;
  feed(ctx, t, {ProgramEvent{t, ProgramEventKind::kResume, 3}, sample(8, 0, 7)});
  feed(ctx, t += kS, {sample(10, 0, 7)});
  EXPECT_DOUBLE_EQ(ctx.cut_path_mm(), 4.0);  // 0→2 and 8→10
  // An NC that names no tool: one unnamed tool, whose path records of any tool get.
  MachineContext anon;
  for (int k = 0; k < 4; ++k) feed(anon, t += kS, {sample(3 * k, 0, 0)});
  EXPECT_DOUBLE_EQ(anon.cut_path_mm(), 9.0);
  MeasurementRecord r;
  r.tool = 1;
  anon.annotate(r);
  EXPECT_DOUBLE_EQ(r.path_mm, 9.0);
  // With named tools, an unknown tool's record stays unknown.
  MeasurementRecord q;
  q.tool = 99;
  ctx.annotate(q);
  EXPECT_TRUE(std::isnan(q.path_mm));
}

TEST(MachineContextClock, WarmStartFollowsTheIdleRule) {
  MachineContext ctx;
  ctx.configure(ContextOptions{0, 3600.0});
  // A fresh daemon: time counts from its first cycle until the first motion.
  feed(ctx, 10 * kS, {sample(0, 0, 1)});
  feed(ctx, 40 * kS, {sample(0, 0, 1)});  // no motion
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 30.0);
  EXPECT_TRUE(ctx.cold());
  EXPECT_EQ(ctx.warm_starts(), 0U);
  // The first motion is a warm start.
  feed(ctx, 100 * kS, {sample(5, 0, 1)});
  EXPECT_EQ(ctx.warm_starts(), 1U);
  EXPECT_FALSE(ctx.cold());
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 0.0);
  feed(ctx, 1900 * kS, {sample(6, 0, 1)});
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 1800.0);
  // Standing still for 3599 s is a pause, not a cold machine.
  feed(ctx, 5499 * kS, {sample(7, 0, 1)});
  EXPECT_EQ(ctx.warm_starts(), 1U);
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 5399.0);
  // 3600 s without motion (samples still arrive, the axes stand): the next motion is a warm
  // start.
  feed(ctx, 7000 * kS, {sample(7, 0, 1)});
  EXPECT_DOUBLE_EQ(ctx.idle_s(), 1501.0);
  feed(ctx, 9099 * kS, {sample(8, 0, 1)});
  EXPECT_EQ(ctx.warm_starts(), 2U);
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 0.0);
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(9199 * kS), 100.0);
  // A record made at 9150 s leaves with time_s = 51 s; one from before the origin with 0.
  MeasurementRecord r;
  r.time_ns = 9150 * kS;
  ctx.annotate(r);
  EXPECT_EQ(r.time_ns, 51 * kS);
  MeasurementRecord early;
  early.time_ns = 9000 * kS;
  ctx.annotate(early);
  EXPECT_EQ(early.time_ns, 0);
}

TEST(MachineContextClock, TheOriginSurvivesARestartAndARebootMakesTheMachineCold) {
  MachineContext a;
  a.configure(ContextOptions{0, 3600.0});
  feed(a, 1000 * kS, {sample(0, 0, 3)});
  feed(a, 1001 * kS, {sample(1, 0, 3)});  // warm start at 1001 s
  for (int k = 2; k <= 11; ++k) feed(a, (1000 + k) * kS, {sample(k, 0, 3)});
  feed(a, 2000 * kS, {sample(11, 0, 3)});  // standing since 1011 s
  ASSERT_DOUBLE_EQ(a.machine_time_s(), 999.0);
  std::vector<std::byte> bytes(MachineContext::kStateBytes);
  ASSERT_EQ(a.save(bytes), MachineContext::kStateBytes);

  // Restart within one boot, 500 s later: the same origin, the downtime is idle time.
  MachineContext b;
  b.configure(ContextOptions{0, 3600.0});
  ASSERT_TRUE(b.load(bytes, 2500 * kS));
  EXPECT_DOUBLE_EQ(b.machine_time_s(2600 * kS), 1599.0);
  EXPECT_DOUBLE_EQ(b.cut_path_mm(), 11.0);  // x = 0 → 11
  EXPECT_EQ(b.tool(), 3);
  feed(b, 2600 * kS, {sample(11, 0, 3)});
  feed(b, 2601 * kS, {sample(12, 0, 3)});  // idle 1590 s < 3600 s: no warm start
  EXPECT_EQ(b.warm_starts(), 1U);
  EXPECT_DOUBLE_EQ(b.machine_time_s(), 1600.0);
  // The same restart after a longer stop: 4000 s of downtime → the next motion is a warm start.
  MachineContext c;
  c.configure(ContextOptions{0, 3600.0});
  ASSERT_TRUE(c.load(bytes, 6000 * kS));
  feed(c, 6001 * kS, {sample(11, 0, 3)});
  feed(c, 6002 * kS, {sample(12, 0, 3)});
  EXPECT_EQ(c.warm_starts(), 2U);
  EXPECT_DOUBLE_EQ(c.machine_time_s(), 0.0);

  // Reboot: the clock went back (now 30 s after boot). The time goes on from 999 s, and the
  // machine is cold: its first motion is a warm start however short the stop was.
  MachineContext d;
  d.configure(ContextOptions{0, 3600.0});
  ASSERT_TRUE(d.load(bytes, 30 * kS));
  EXPECT_TRUE(d.cold());
  feed(d, 40 * kS, {sample(11, 0, 3)});
  EXPECT_DOUBLE_EQ(d.machine_time_s(), 1009.0);
  feed(d, 41 * kS, {sample(12, 0, 3)});
  EXPECT_EQ(d.warm_starts(), 2U);
  EXPECT_DOUBLE_EQ(d.machine_time_s(), 0.0);
  // The path is the tool's, not the clock's: 11 mm, + 1 mm between the two samples after the
  // restart (the first sample after a restart only starts the count).
  EXPECT_DOUBLE_EQ(d.cut_path_mm(), 12.0);

  // Bad bytes: refused, nothing changes.
  MachineContext e;
  auto bad = bytes;
  bad[0] = std::byte{0};
  EXPECT_FALSE(e.load(bad, 0));
  bad = bytes;
  const double nan = std::nan("");
  std::memcpy(bad.data() + 56 + 8, &nan, sizeof nan);  // first tool slot's path
  EXPECT_FALSE(e.load(bad, 0));
  EXPECT_FALSE(e.load(std::span<const std::byte>(bytes.data(), bytes.size() - 1), 0));
  EXPECT_TRUE(e.cold());
  EXPECT_FALSE(e.has_tool());
}

OperatorCommand warm_start(std::uint32_t sequence, std::int8_t at_next_motion) {
  OperatorCommand c;
  c.sequence = sequence;
  c.kind = OperatorCommandKind::kWarmStart;
  c.code = {at_next_motion, 0, 0, 0};
  return c;
}

TEST(MachineContextClock, AnOperatorDeclaresAWarmStartNowOrAtTheNextMotion) {
  MachineContext ctx;
  ctx.configure(ContextOptions{0, 3600.0});
  feed(ctx, 10 * kS, {sample(0, 0, 1)});
  feed(ctx, 100 * kS, {sample(5, 0, 1)});  // the idle rule's warm start
  ASSERT_EQ(ctx.warm_starts(), 1U);
  feed(ctx, 400 * kS, {sample(6, 0, 1)});
  ASSERT_DOUBLE_EQ(ctx.machine_time_s(), 300.0);
  const auto g = ctx.generation();

  // "Now" at 500 s (the machine stood since 400 s, less than 3600 s: the rule sees no warm
  // start): time_s counts from 500 s.
  feed(ctx, 500 * kS, {warm_start(7, 0)});
  EXPECT_EQ(ctx.warm_starts(), 2U);
  EXPECT_EQ(ctx.warm_start_commands(), 1U);
  EXPECT_EQ(ctx.last_command_sequence(), 7U);
  EXPECT_FALSE(ctx.cold());
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 0.0);
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(620 * kS), 120.0);
  EXPECT_DOUBLE_EQ(ctx.idle_s(), 0.0);  // the declared start counts as activity
  EXPECT_GT(ctx.generation(), g);       // saved with the state
  MeasurementRecord r;
  r.time_ns = 530 * kS;
  ctx.annotate(r);
  EXPECT_EQ(r.time_ns, 30 * kS);
  // The idle rule goes on from the declared start: motion 3599 s later is no warm start.
  feed(ctx, 4099 * kS, {sample(6, 0, 1)});
  feed(ctx, 4099 * kS + kS / 2, {sample(7, 0, 1)});
  EXPECT_EQ(ctx.warm_starts(), 2U);
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 3599.5);

  // "At the next motion": the machine is cold now (say it was switched off and on again while
  // nccompd ran); the time goes on until the axes move, which is the warm start.
  feed(ctx, 4200 * kS, {warm_start(8, 1)});
  EXPECT_TRUE(ctx.cold());
  EXPECT_EQ(ctx.warm_starts(), 2U);
  EXPECT_EQ(ctx.warm_start_commands(), 2U);
  EXPECT_EQ(ctx.last_command_sequence(), 8U);
  feed(ctx, 4300 * kS, {sample(7, 0, 1)});  // standing: still cold
  EXPECT_TRUE(ctx.cold());
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 3800.0);
  feed(ctx, 4310 * kS, {sample(9, 0, 1)});
  EXPECT_EQ(ctx.warm_starts(), 3U);
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 0.0);

  // A code the context does not know, and another command kind: ignored.
  feed(ctx, 4400 * kS, {warm_start(9, 2)});
  OperatorCommand other = warm_start(10, 0);
  other.kind = OperatorCommandKind::kCalibrationStatus;
  feed(ctx, 4500 * kS, {other});
  EXPECT_EQ(ctx.warm_start_commands(), 2U);
  EXPECT_EQ(ctx.last_command_sequence(), 8U);
  EXPECT_EQ(ctx.warm_starts(), 3U);
  EXPECT_DOUBLE_EQ(ctx.machine_time_s(), 190.0);
}

TEST(MachineContext, RefusesOptionsOutOfRange) {
  MachineContext c;
  EXPECT_THROW(c.configure(ContextOptions{256, 7200.0}), std::invalid_argument);
  EXPECT_THROW(c.configure(ContextOptions{-2, 7200.0}), std::invalid_argument);
  try {
    c.configure(ContextOptions{0, 10.0});
    FAIL() << "10 s accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("warm_start_idle_s"), std::string::npos) << e.what();
  }
  EXPECT_NO_THROW(c.configure(ContextOptions{-1, 60.0}));
}

// Emits one contour record per probe event (tool 4, path and temperature unknown), as S1 does.
class ProbeRecorder final : public Module {
 public:
  std::string_view name() const noexcept override { return "probe"; }
  void attach(const RegisterTable&) override {}
  void step(TimeNs, std::span<const Event> events, StepOutput& out) noexcept override {
    for (const Event& e : events) {
      if (const auto* p = std::get_if<ProbeMeasurement>(&e)) {
        MeasurementRecord r;
        r.time_ns = p->time_ns;
        r.tool = 4;
        r.kind = MeasurementKind::kContour;
        r.point = p->checkpoint;
        r.measured_um = p->raw_deviation_um;
        out.records.push(r);
      }
    }
  }
  void bind_context(const MachineContext& c) override { bound = &c; }
  const MachineContext* bound{nullptr};
};

class OptionsModule final : public Module {
 public:
  explicit OptionsModule(std::string name, ContextOptions o) : name_(std::move(name)), o_(o) {}
  std::string_view name() const noexcept override { return name_; }
  void attach(const RegisterTable&) override {}
  void step(TimeNs, std::span<const Event>, StepOutput&) noexcept override {}
  const ContextOptions* context_options() const noexcept override { return &o_; }

 private:
  std::string name_;
  ContextOptions o_;
};

std::unique_ptr<Engine> probe_engine(ContextOptions options, ProbeRecorder** rec = nullptr) {
  std::vector<std::unique_ptr<Module>> mods;
  auto p = std::make_unique<ProbeRecorder>();
  if (rec != nullptr) *rec = p.get();
  mods.push_back(std::move(p));
  mods.push_back(std::make_unique<OptionsModule>("options", options));
  auto e = std::make_unique<Engine>();
  e->configure({}, std::move(mods));
  return e;
}

TEST(EngineContext, RecordsLeaveWithPathTemperatureAndTimeSinceTheWarmStart) {
  ProbeRecorder* rec = nullptr;
  auto e = probe_engine(ContextOptions{2, 3600.0}, &rec);
  ASSERT_EQ(rec->bound, &e->context());
  EXPECT_EQ(e->context().options().temperature_sensor, 2);
  StepOutput out;
  TimeNs t = 50 * kS;
  e->step(t, {}, out);
  // Tool 4 cuts 30 mm along X from t = 60 s (the warm start), sensors 0 and 2 report.
  std::vector<Event> ev = {ToolChange{t, 4, false}, sample(0, 0, 4), TemperatureSample{t, 0, 19.0},
                           TemperatureSample{t, 2, 23.5}};
  e->step(t = 60 * kS, ev, out);
  for (int k = 1; k <= 30; ++k) {
    const std::vector<Event> s = {sample(k, 0, 4)};
    e->step(t += kS / 10, s, out);
  }
  // Another tool is in the spindle when the part is probed (90 s): the record is tool 4's.
  const std::vector<Event> probe = {ToolChange{t, 9, false},
                                    ProbeMeasurement{t + 27 * kS, 1, 7, 1.25, 0.0, 2.0, {}}};
  e->step(90 * kS, probe, out);
  ASSERT_EQ(out.records.size(), 1U);
  const MeasurementRecord& r = out.records[0];
  EXPECT_DOUBLE_EQ(r.path_mm, 30.0);
  EXPECT_DOUBLE_EQ(r.temp_c, 23.5);
  // The warm start was the first motion (60.1 s); the probe event is from 90 s.
  EXPECT_EQ(r.time_ns, 29'900'000'000);
  EXPECT_EQ(r.point, 7);
  EXPECT_DOUBLE_EQ(r.measured_um, 1.25);
}

TEST(EngineContext, TheContextIsSavedWithTheStateAndOldStatesStillLoad) {
  auto e1 = probe_engine(ContextOptions{0, 3600.0});
  StepOutput out;
  TimeNs t = 0;
  for (int k = 0; k <= 40; ++k) {
    const std::vector<Event> s = {sample(2.0 * k, 0, 8)};
    e1->step(t += kS, s, out);
  }
  ASSERT_DOUBLE_EQ(e1->context().cut_path_mm(), 80.0);
  std::vector<std::byte> buf(e1->state_capacity());
  const std::size_t n = e1->export_state(buf);
  ASSERT_GT(n, MachineContext::kStateBytes);
  auto e2 = probe_engine(ContextOptions{0, 3600.0});
  std::size_t skipped = 9;
  ASSERT_TRUE(e2->import_state(std::span<const std::byte>(buf.data(), n), t + 5 * kS, &skipped));
  EXPECT_EQ(skipped, 0U);
  EXPECT_DOUBLE_EQ(e2->context().cut_path_mm(), 80.0);
  EXPECT_EQ(e2->context().tool(), 8);
  EXPECT_DOUBLE_EQ(e2->context().machine_time_s(t + 5 * kS), 44.0);  // warm start at 2 s
  // A state of an engine without a context entry (magic, version 1, no registers, no modules):
  // accepted, the context stays fresh.
  std::vector<std::byte> old(16);
  const std::uint32_t words[4] = {0x4e45434eU, 1U, 0U, 0U};
  std::memcpy(old.data(), words, sizeof words);
  auto e3 = probe_engine(ContextOptions{0, 3600.0});
  ASSERT_TRUE(e3->import_state(old, 0));
  EXPECT_FALSE(e3->context().has_tool());
  EXPECT_TRUE(e3->context().cold());
}

TEST(EngineContext, OneModuleAtMostSetsTheOptionsAndBadOptionsAreRefused) {
  std::vector<std::unique_ptr<Module>> mods;
  mods.push_back(std::make_unique<OptionsModule>("a", ContextOptions{}));
  mods.push_back(std::make_unique<OptionsModule>("b", ContextOptions{}));
  Engine e;
  try {
    e.configure({}, std::move(mods));
    FAIL() << "two option modules accepted";
  } catch (const std::invalid_argument& ex) {
    EXPECT_NE(std::string(ex.what()).find("'a' and 'b' both set"), std::string::npos) << ex.what();
  }
  std::vector<std::unique_ptr<Module>> bad;
  bad.push_back(std::make_unique<OptionsModule>("a", ContextOptions{300, 7200.0}));
  Engine e2;
  EXPECT_THROW(e2.configure({}, std::move(bad)), std::invalid_argument);
  // Without such a module the engine options apply.
  Engine e3;
  EngineOptions o;
  o.context.temperature_sensor = 5;
  e3.configure({}, {}, o);
  EXPECT_EQ(e3.context().options().temperature_sensor, 5);
}

TEST(EngineContext, AWarmStartCommandIsValidatedCountedAndSaved) {
  auto e = probe_engine(ContextOptions{0, 3600.0});
  StepOutput out;
  std::vector<Event> ev = {sample(0, 0, 2)};
  e->step(10 * kS, ev, out);
  ev = {sample(1, 0, 2)};
  e->step(20 * kS, ev, out);  // warm start by the rule at 20 s
  ASSERT_EQ(e->counters().warm_starts, 1U);

  // Malformed: an unknown code, a code in an unused slot, sequence 0. Each is refused as an
  // invalid event (warning event_invalid), never reaches the context.
  OperatorCommand bad_code = warm_start(1, 3);
  OperatorCommand bad_slot = warm_start(2, 0);
  bad_slot.code[2] = 1;
  OperatorCommand no_sequence = warm_start(0, 0);
  ev = {bad_code, bad_slot, no_sequence};
  e->step(30 * kS, ev, out);
  EXPECT_EQ(e->counters().events_invalid, 3U);
  std::size_t invalid_alarms = 0;
  for (const auto& a : out.alarms) invalid_alarms += a.code == AlarmCode::kEventInvalid ? 1 : 0;
  EXPECT_EQ(invalid_alarms, 3U);
  EXPECT_EQ(e->counters().warm_start_commands, 0U);
  EXPECT_EQ(e->counters().last_warm_start_sequence, 0U);

  // A valid one at 50 s: taken, counted, its sequence published for the sender.
  ev = {warm_start(4, 0)};
  e->step(50 * kS, ev, out);
  EXPECT_EQ(e->counters().warm_start_commands, 1U);
  EXPECT_EQ(e->counters().last_warm_start_sequence, 4U);
  EXPECT_EQ(e->counters().warm_starts, 2U);
  EXPECT_DOUBLE_EQ(e->context().machine_time_s(80 * kS), 30.0);

  // The declared origin is in the state: a restart 10 s later continues from it.
  std::vector<std::byte> buf(e->state_capacity());
  const std::size_t n = e->export_state(buf);
  ASSERT_GT(n, 0U);
  auto f = probe_engine(ContextOptions{0, 3600.0});
  ASSERT_TRUE(f->import_state(std::span<const std::byte>(buf.data(), n), 60 * kS));
  EXPECT_DOUBLE_EQ(f->context().machine_time_s(80 * kS), 30.0);
  EXPECT_EQ(f->context().warm_starts(), 2U);
  EXPECT_EQ(f->counters().warm_start_commands, 0U);  // a count of the running process only

  // Taking a command allocates nothing.
  ev = {warm_start(5, 1)};
  const nccomp::test::AllocationScope scope;
  for (int k = 0; k < 100; ++k) e->step((100 + k) * kS, ev, out);
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(e->counters().warm_start_commands, 101U);
  EXPECT_TRUE(e->context().cold());
}

TEST(EngineContext, GenerationAdvancesOnChangesNotEveryCycle) {
  MachineContext c;
  TimeNs t = 0;
  feed(c, t += kS, {sample(0, 0, 1)});
  const auto g0 = c.generation();
  // 9 mm of cut: below the 10 mm persistence step, after the warm start's and tool's advances.
  for (int k = 1; k <= 9; ++k) feed(c, t += kS / 100, {sample(k, 0, 1)});
  const auto g1 = c.generation();
  EXPECT_EQ(g1, g0 + 1);  // the warm start at the first motion
  for (int k = 10; k <= 31; ++k) feed(c, t += kS / 100, {sample(k, 0, 1)});
  EXPECT_EQ(c.generation(), g1 + 3);  // 10, 20, 30 mm
  for (int k = 0; k < 100; ++k) feed(c, t += kS / 100, {sample(31, 0, 1)});
  EXPECT_EQ(c.generation(), g1 + 3);  // standing still: nothing to save
}

TEST(EngineContext, UpdateAnnotateSaveLoadAllocateNothing) {
  MachineContext c;
  std::vector<std::byte> buf(MachineContext::kStateBytes);
  std::vector<Event> ev = {sample(0, 0, 1), TemperatureSample{0, 0, 20.0},
                           ProgramEvent{0, ProgramEventKind::kPartStart, 1}};
  const nccomp::test::AllocationScope scope;
  for (int k = 0; k < 1000; ++k) {
    std::get<AxisSample>(ev[0]).position_mm[0] = k;
    std::get<AxisSample>(ev[0]).tool = 1 + k / 100;
    c.update(k * kS, ev);
    MeasurementRecord r;
    r.tool = 1;
    c.annotate(r);
    if (k % 100 == 0) {
      ASSERT_EQ(c.save(buf), MachineContext::kStateBytes);
      ASSERT_TRUE(c.load(buf, k * kS));
    }
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_DOUBLE_EQ(c.temp_c(), 20.0);
}

}  // namespace
}  // namespace nccomp::core::engine
