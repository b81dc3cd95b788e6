// The operator's acknowledgement of a latched creep alarm through the engine (`nccomp
// acknowledge`: an OperatorCommand kAcknowledge): a halt after a broken tool (alarm 23) or an
// excessive increment (alarm 22, on_excessive = "stop") is lifted, the alarm flag register is
// written 0 and the overdue measurement is asked for in the same cycle, a following good
// measurement is accepted and creeps; the command is counted (engine and module), advances the
// state generation, changes nothing when nothing is latched, and a malformed one is refused by
// the engine as an invalid event. Allocation-free.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "core/creep/creep_module.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using engine::Engine;
using engine::RegisterKind;
using engine::RegisterSpec;

constexpr std::uint16_t kZ = 2;
constexpr std::uint16_t kWarning = 4;
constexpr std::uint16_t kAlarm = 5;
constexpr std::uint16_t kRequest = 6;

std::vector<RegisterSpec> registers() {
  const LimiterConfig lim{100.0, 50.0, 1e5};
  const LimiterConfig flag{10.0, 10.0, 1e6};
  return {{"X_offset", RegisterKind::kAxisOffset, lim},
          {"Y_offset", RegisterKind::kAxisOffset, lim},
          {"Z_offset", RegisterKind::kAxisOffset, lim},
          {"T1_length_wear", RegisterKind::kToolLengthWear, lim},
          {"creep_warning", RegisterKind::kFlag, flag},
          {"creep_alarm", RegisterKind::kFlag, flag},
          {"measure_request", RegisterKind::kFlag, flag},
          {"tool_change", RegisterKind::kFlag, flag}};
}

/// X/Y/Z on 0/1/2 (mean wear on Z, sign −1), flags on 4..7, a measurement every 100 mm of cut
/// path, a creep over 50 mm.
CreepModuleConfig module_config() {
  CreepModuleConfig m;
  m.creep = testing::base_config();
  m.creep.output.warning_register = kWarning;
  m.creep.output.alarm_register = kAlarm;
  m.creep.output.measurement_due_register = kRequest;
  m.creep.output.tool_change_register = 7;
  m.creep.interval.basis = IntervalBasis::kPath;
  m.creep.interval.interval_mm = 100.0;
  m.creep.tool_life.noise_um = 2.0;
  m.creep.tool_life.implausible_factor = 5.0;
  m.creep.tool_life.min_expected_increment_um = 10.0;
  return m;
}

struct EngineRig {
  Engine engine;
  StepOutput out;
  std::vector<Event> ev;
  TimeNs now{0};
  double path{0.0};
  std::int32_t tool{1};
  std::vector<OffsetWrite> writes;
  std::vector<AlarmEvent> alarms;

  explicit EngineRig(const CreepModuleConfig& m) {
    std::vector<std::unique_ptr<engine::Module>> mods;
    mods.push_back(std::make_unique<CreepModule>(m));
    engine.configure(registers(), std::move(mods));
    ev.emplace_back(ToolChange{now, 1, false});
    step();
  }
  [[nodiscard]] const CreepModule& module() const {
    return dynamic_cast<const CreepModule&>(engine.module(0));
  }
  void step() {
    engine.step(now, ev, out);
    ev.clear();
    for (const auto& w : out.writes) writes.push_back(w);
    for (const auto& a : out.alarms) alarms.push_back(a);
  }
  void sample() {
    AxisSample a;
    a.time_ns = now;
    a.program_path_mm = path;
    a.tool = tool;
    a.cutting = true;
    ev.emplace_back(a);
  }
  void advance(double ds) {
    now += 10'000'000;
    path += ds;
    sample();
    step();
  }
  void run_to(double p) {
    while (path + 0.5 <= p + 1e-9) advance(0.5);
  }
  void measure(double w, bool broken = false) {
    ToolMeasurement m;
    m.time_ns = now;
    m.tool = tool;
    m.broken = broken;
    m.wear_um[0] = w;
    now += 1'000'000;
    ev.emplace_back(m);
    step();
  }
  /// One cycle with an axis sample (no motion) and the operator's command.
  void command(std::uint32_t sequence, std::int8_t code0 = 0) {
    OperatorCommand c;
    c.sequence = sequence;
    c.kind = OperatorCommandKind::kAcknowledge;
    c.code = {code0, 0, 0, 0};
    now += 10'000'000;
    sample();
    ev.emplace_back(c);
    step();
  }
  /// Every value written to a register, in order.
  [[nodiscard]] std::vector<double> values(std::uint16_t reg) const {
    std::vector<double> v;
    for (const auto& w : writes) {
      if (w.register_index == reg) v.push_back(w.value_um);
    }
    return v;
  }
  [[nodiscard]] double last(std::uint16_t reg) const {
    const auto v = values(reg);
    return v.empty() ? kNaN : v.back();
  }
  [[nodiscard]] std::size_t count(AlarmCode code) const {
    std::size_t n = 0;
    for (const auto& a : alarms) n += a.code == code ? 1U : 0U;
    return n;
  }
};

engine::StatusValue status_of(const CreepModule& m, std::string_view key) {
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  const std::size_t n = m.status(v);
  for (std::size_t i = 0; i < n; ++i) {
    if (key == v[i].key) return v[i];
  }
  return {nullptr, kNaN, nullptr};
}

std::string text_of(const CreepModule& m, std::string_view key) {
  const auto v = status_of(m, key);
  return v.text != nullptr ? v.text : "";
}

TEST(CreepAcknowledge, TheOperatorLiftsABrokenToolHaltAndTheNextGoodMeasurementCreeps) {
  EngineRig r(module_config());
  r.run_to(100.0);
  r.measure(5.0);  // accepted: creeps to Z = -5 over 50 mm
  r.run_to(200.0);
  EXPECT_NEAR(r.last(kZ), -5.0, 1e-9);
  EXPECT_NEAR(r.last(kRequest), 1.0, 0.0);
  r.measure(6.0, /*broken=*/true);  // coolant on the laser: "broken"
  const CreepModule& m = r.module();
  ASSERT_TRUE(m.compensator().halted());
  EXPECT_EQ(r.count(AlarmCode::kToolBrokenOrMismeasured), 1U);
  EXPECT_NEAR(r.last(kAlarm), 1.0, 0.0);
  EXPECT_NEAR(r.last(kRequest), 0.0, 0.0);
  EXPECT_NEAR(status_of(m, "halted").value, 1.0, 0.0);
  EXPECT_NEAR(status_of(m, "latched_alarm").value, 23.0, 0.0);
  EXPECT_EQ(text_of(m, "last_acknowledge"), "none yet");
  r.run_to(400.0);  // two intervals later, still halted: nothing asked, nothing applied
  EXPECT_NEAR(r.last(kRequest), 0.0, 0.0);
  EXPECT_NEAR(r.last(kZ), -5.0, 1e-9);
  r.measure(7.0);  // refused while halted (logged, event_invalid)
  EXPECT_EQ(m.compensator().counters().measurements_accepted, 1U);
  EXPECT_NEAR(m.compensator().state().measured_um[0], 5.0, 0.0);

  // The operator acknowledges (sequence 7).
  const std::uint64_t generation = m.state_generation();
  const std::size_t writes_before = r.writes.size();
  r.command(7);
  EXPECT_FALSE(m.compensator().halted());
  EXPECT_GT(m.state_generation(), generation);  // persisted: a restart stays acknowledged
  EXPECT_EQ(r.engine.counters().acknowledge_commands, 1U);
  EXPECT_EQ(r.engine.counters().last_acknowledge_sequence, 7U);
  EXPECT_EQ(m.acknowledged(), 1U);
  EXPECT_TRUE(m.last_acknowledgement().halted);
  EXPECT_TRUE(m.last_acknowledgement().alarm_flag);
  EXPECT_FALSE(m.last_acknowledgement().warning_flag);
  EXPECT_TRUE(m.last_acknowledgement().request_held);
  EXPECT_EQ(m.last_acknowledgement().alarm_code, 23);
  // In the command's cycle: the alarm flag register falls to 0 and the overdue measurement
  // (400 mm of cut path since the last accepted one at 100 mm) is asked for.
  std::vector<double> cycle_alarm;
  std::vector<double> cycle_request;
  for (std::size_t i = writes_before; i < r.writes.size(); ++i) {
    if (r.writes[i].register_index == kAlarm) cycle_alarm.push_back(r.writes[i].value_um);
    if (r.writes[i].register_index == kRequest) cycle_request.push_back(r.writes[i].value_um);
  }
  EXPECT_EQ(cycle_alarm, (std::vector<double>{0.0}));
  EXPECT_EQ(cycle_request, (std::vector<double>{1.0}));
  EXPECT_NEAR(status_of(m, "halted").value, 0.0, 0.0);
  EXPECT_NEAR(status_of(m, "latched_alarm").value, 0.0, 0.0);
  EXPECT_NEAR(status_of(m, "acknowledged").value, 1.0, 0.0);
  EXPECT_EQ(text_of(m, "last_acknowledge"), "halt and alarm flag cleared");
  EXPECT_NEAR(status_of(m, "last_acknowledge").value, 23.0, 0.0);
  EXPECT_EQ(r.values(kAlarm), (std::vector<double>{0.0, 1.0, 0.0}));

  // The re-measurement is good: accepted, the request falls, the 3 µm creep in over 50 mm.
  r.advance(0.5);
  r.measure(8.0);
  EXPECT_EQ(m.compensator().counters().measurements_accepted, 2U);
  EXPECT_NEAR(r.last(kRequest), 0.0, 0.0);
  r.run_to(r.path + 25.0);
  EXPECT_NEAR(r.last(kZ), -6.5, 1e-9);
  r.run_to(r.path + 30.0);
  EXPECT_NEAR(r.last(kZ), -8.0, 1e-9);
  EXPECT_NEAR(r.last(kAlarm), 0.0, 0.0);
  EXPECT_EQ(r.count(AlarmCode::kToolBrokenOrMismeasured), 1U);
}

TEST(CreepAcknowledge, AnExcessiveIncrementStopIsAcknowledgedLikeABrokenTool) {
  auto c = module_config();
  c.creep.tool_life.excessive_increment_um = 8.0;
  c.creep.tool_life.on_excessive = ExcessivePolicy::kStop;
  EngineRig r(c);
  r.run_to(100.0);
  r.measure(5.0);
  r.run_to(200.0);
  r.measure(20.0);  // +15 µm > 8: alarm 22, halted, not applied
  const CreepModule& m = r.module();
  ASSERT_TRUE(m.compensator().halted());
  EXPECT_EQ(r.count(AlarmCode::kToolExcessivelyWorn), 1U);
  EXPECT_NEAR(status_of(m, "latched_alarm").value, 22.0, 0.0);
  EXPECT_NEAR(r.last(kAlarm), 1.0, 0.0);
  r.command(1);
  EXPECT_FALSE(m.compensator().halted());
  EXPECT_NEAR(r.last(kAlarm), 0.0, 0.0);
  EXPECT_NEAR(r.last(kRequest), 1.0, 0.0);
  EXPECT_EQ(m.last_acknowledgement().alarm_code, 22);
  EXPECT_NEAR(status_of(m, "last_acknowledge").value, 22.0, 0.0);
  r.measure(12.0);  // +7 µm: accepted
  EXPECT_EQ(m.compensator().counters().measurements_accepted, 2U);
  r.run_to(r.path + 50.0);
  EXPECT_NEAR(r.last(kZ), -12.0, 1e-9);
}

TEST(CreepAcknowledge, AWarningFlagIsClearedAndNamed) {
  auto c = module_config();
  c.creep.tool_life.excessive_increment_um = 8.0;
  c.creep.tool_life.on_excessive = ExcessivePolicy::kSister;
  EngineRig r(c);
  r.run_to(100.0);
  r.measure(5.0);
  r.run_to(200.0);
  r.measure(20.0);  // warning 22: the sister tool is requested, nothing applied, not halted
  const CreepModule& m = r.module();
  EXPECT_FALSE(m.compensator().halted());
  EXPECT_NEAR(r.last(kWarning), 1.0, 0.0);
  EXPECT_NEAR(status_of(m, "latched_alarm").value, 0.0, 0.0);
  EXPECT_EQ(m.latched_warning_code(), 22);
  r.command(3);
  EXPECT_NEAR(r.last(kWarning), 0.0, 0.0);
  EXPECT_EQ(text_of(m, "last_acknowledge"), "warning flag cleared");
  EXPECT_NEAR(status_of(m, "last_acknowledge").value, 22.0, 0.0);
  EXPECT_EQ(m.latched_warning_code(), 0);
}

TEST(CreepAcknowledge, WithNothingLatchedTheCommandIsCountedAndChangesNothing) {
  EngineRig r(module_config());
  r.run_to(100.0);
  r.measure(10.0);
  r.run_to(120.0);  // 20 of 50 mm of the creep
  const CreepModule& m = r.module();
  const CreepState before = m.compensator().export_state();
  const std::size_t writes_before = r.writes.size();
  r.command(1);
  EXPECT_EQ(r.engine.counters().acknowledge_commands, 1U);
  EXPECT_EQ(m.acknowledged(), 1U);
  EXPECT_EQ(text_of(m, "last_acknowledge"), "nothing latched");
  EXPECT_NEAR(status_of(m, "last_acknowledge").value, 0.0, 0.0);
  // The same cycle without motion writes nothing, with or without the command.
  EXPECT_EQ(r.writes.size(), writes_before);
  const CreepState after = m.compensator().export_state();
  EXPECT_EQ(after.halted, before.halted);
  EXPECT_EQ(after.measured_um[0], before.measured_um[0]);
  EXPECT_EQ(after.cut_path_mm, before.cut_path_mm);
  r.run_to(150.0);
  EXPECT_NEAR(r.last(kZ), -10.0, 1e-9);  // the creep went on as before
}

TEST(CreepAcknowledge, AMalformedCommandIsRefusedByTheEngineAndChangesNothing) {
  EngineRig r(module_config());
  r.run_to(100.0);
  r.measure(5.0, /*broken=*/true);
  const CreepModule& m = r.module();
  ASSERT_TRUE(m.compensator().halted());
  const auto invalid = r.engine.counters().events_invalid;
  r.command(0);     // sequence 0
  r.command(4, 1);  // a module selector: reserved
  EXPECT_EQ(r.engine.counters().events_invalid, invalid + 2);
  EXPECT_EQ(r.engine.counters().acknowledge_commands, 0U);
  EXPECT_EQ(m.acknowledged(), 0U);
  EXPECT_TRUE(m.compensator().halted());
  EXPECT_NEAR(r.last(kAlarm), 1.0, 0.0);
  r.command(5);
  EXPECT_FALSE(m.compensator().halted());
  EXPECT_EQ(r.engine.counters().last_acknowledge_sequence, 5U);
}

TEST(CreepAcknowledge, AHaltRestoredFromTheStateIsClearedWithItsCauseUnknown) {
  EngineRig a(module_config());
  a.run_to(100.0);
  a.measure(5.0, /*broken=*/true);
  std::vector<std::byte> buf(a.engine.state_capacity());
  buf.resize(a.engine.export_state(buf));
  EngineRig b(module_config());
  ASSERT_TRUE(b.engine.import_state(buf, b.now, nullptr));
  const CreepModule& m = b.module();
  ASSERT_TRUE(m.compensator().halted());
  EXPECT_NEAR(status_of(m, "latched_alarm").value, -1.0, 0.0);  // raised by another process
  b.command(1);
  EXPECT_FALSE(m.compensator().halted());
  EXPECT_EQ(text_of(m, "last_acknowledge"), "halt and alarm flag cleared");
  EXPECT_NEAR(status_of(m, "last_acknowledge").value, -1.0, 0.0);
  EXPECT_NEAR(b.last(kAlarm), 0.0, 0.0);
}

TEST(CreepAcknowledge, TheCommandThroughTheEngineAllocatesNothing) {
  EngineRig r(module_config());
  r.run_to(100.0);
  r.measure(5.0);
  r.run_to(200.0);
  r.writes.reserve(r.writes.size() + 64);
  r.alarms.reserve(r.alarms.size() + 64);
  r.ev.reserve(8);
  ToolMeasurement broken;
  broken.tool = 1;
  broken.broken = true;
  OperatorCommand c;
  c.sequence = 9;
  c.kind = OperatorCommandKind::kAcknowledge;
  std::array<engine::StatusValue, engine::kMaxStatusValues> status{};
  const CreepModule& m = r.module();
  nccomp::test::AllocationScope scope;
  r.now += 1'000'000;
  r.ev.emplace_back(broken);
  r.engine.step(r.now, r.ev, r.out);
  r.ev.clear();
  const bool halted = m.compensator().halted();
  r.now += 1'000'000;
  r.ev.emplace_back(c);
  r.engine.step(r.now, r.ev, r.out);
  r.ev.clear();
  (void)m.status(status);
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_TRUE(halted);
  EXPECT_FALSE(m.compensator().halted());
  EXPECT_EQ(r.engine.counters().acknowledge_commands, 1U);
}

}  // namespace
}  // namespace nccomp::core::creep
