// GIVEN an engine at start-up (core/engine/engine.hpp, "Start-up holds"):
// - a register whose NC value lies beyond max_abs_um (read back, or restored / carried over a
//   reload that narrowed the limit) WHEN the engine steps THEN nothing is written to it, not even
//   inward, one alarm register_beyond_limit (60) is raised; WHEN the operator releases it
//   (OperatorCommand kRegisterRelease) THEN the target is written in one move, within the limit;
// - a module without restored state WHEN offered the NC's value (adopt_without_state()) THEN a
//   module that adopts keeps the register where it is (notice 61), one that cannot leaves it held
//   (alarm 62) until released, after which it slews from the NC's value; an unanswered read-back
//   holds too, until a later start reads the NC; a bus that cannot read back, a restored module
//   and a flag change nothing;
// - the holds survive export / import (restart, reload); no write beyond max_abs_um ever leaves
//   the engine; stepping with commands allocates nothing.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

constexpr TimeNs kMs = 1'000'000;

// Writes one absolute target to register 0 (and a flag to register 2) every cycle; adopts what
// it is offered if `adopts`; its state is its target (8 bytes).
class Writer final : public Module {
 public:
  explicit Writer(double target_um) : value_um(target_um) {}
  std::string_view name() const noexcept override { return "writer"; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    if (publish) out.writes.push(OffsetWrite{now_ns, 0, value_um});
    if (publish) out.writes.push(OffsetWrite{now_ns, 2, 0.0});
  }
  std::vector<std::uint16_t> written_registers() const override { return {0, 2}; }
  std::size_t state_capacity() const noexcept override { return sizeof(double); }
  std::size_t save_state(std::span<std::byte> buf) const noexcept override {
    std::memcpy(buf.data(), &value_um, sizeof value_um);
    return sizeof value_um;
  }
  bool load_state(std::span<const std::byte> bytes) noexcept override {
    if (bytes.size() != sizeof(double) || refuse_state) return false;
    std::memcpy(&value_um, bytes.data(), sizeof value_um);
    return true;
  }
  bool adopt_output(std::uint16_t register_index, double nc_value_um, TimeNs /*now*/) override {
    offered.push_back(register_index);
    if (!adopts || register_index != 0) return false;
    value_um = nc_value_um;
    return true;
  }
  double value_um;
  bool publish{true};
  bool adopts{true};
  bool refuse_state{false};
  std::vector<std::uint16_t> offered;
};

/// Register 0: max_abs_um (200), max_step 5 µm, 1000 µm/s; register 1: nobody writes it;
/// register 2: a flag.
std::unique_ptr<Engine> make_engine(double target_um, Writer** module, double max_abs_um = 200.0) {
  auto e = std::make_unique<Engine>();
  std::vector<RegisterSpec> regs{
      {"T1_length_wear", RegisterKind::kToolLengthWear, LimiterConfig{max_abs_um, 5.0, 1000.0}},
      {"spare", RegisterKind::kToolRadiusWear, LimiterConfig{200.0, 5.0, 1000.0}},
      {"alarm_flag", RegisterKind::kFlag, LimiterConfig{1.0, 1.0, 1.0}}};
  std::vector<std::unique_ptr<Module>> mods;
  auto m = std::make_unique<Writer>(target_um);
  *module = m.get();
  mods.push_back(std::move(m));
  e->configure(std::move(regs), std::move(mods));
  return e;
}

struct Outcome {
  std::vector<double> written;  // register 0, in order
  std::vector<AlarmEvent> alarms;
  std::size_t writes_all{0};
};

Outcome run(Engine& e, TimeNs& t, int cycles, std::span<const Event> first_events = {}) {
  Outcome r;
  StepOutput out;
  for (int k = 0; k < cycles; ++k) {
    e.step(t += 10 * kMs, k == 0 ? first_events : std::span<const Event>{}, out);
    r.writes_all += out.writes.size();
    for (const auto& w : out.writes) {
      if (w.register_index == 0) r.written.push_back(w.value_um);
    }
    for (const auto& a : out.alarms) r.alarms.push_back(a);
  }
  return r;
}

Event release(double index, std::uint32_t sequence) {
  OperatorCommand c;
  c.kind = OperatorCommandKind::kRegisterRelease;
  c.sequence = sequence;
  c.value = {index, 0.0};
  return c;
}

std::vector<std::byte> state_of(const Engine& e) {
  std::vector<std::byte> buf(e.state_capacity());
  buf.resize(e.export_state(buf));
  return buf;
}

std::size_t count(const std::vector<AlarmEvent>& alarms, AlarmCode code) {
  std::size_t n = 0;
  for (const auto& a : alarms) n += a.code == code ? 1U : 0U;
  return n;
}

TEST(StartupHold, AReadBackBeyondTheLimitIsNeverWrittenUntilReleasedThenTheTargetInOneMove) {
  Writer* m = nullptr;
  auto e = make_engine(10.0, &m);
  const AnchorResult a = e->anchor_register(0, 250.0, 0);
  EXPECT_TRUE(a.beyond_limit);
  EXPECT_EQ(e->register_state(0).hold, RegisterHold::kBeyondLimit);
  TimeNs t = 0;
  // Before this, the register slewed inward from 250: 245, 240, ... all beyond 200 µm.
  const Outcome held = run(*e, t, 100);
  EXPECT_TRUE(held.written.empty()) << held.written.front();
  ASSERT_EQ(count(held.alarms, AlarmCode::kRegisterBeyondLimit), 1U);
  EXPECT_EQ(held.alarms[0].severity, Severity::kAlarm);
  EXPECT_EQ(held.alarms[0].subject, 0);
  EXPECT_DOUBLE_EQ(held.alarms[0].value, 250.0);
  EXPECT_EQ(e->counters().writes_blocked, 100U);
  EXPECT_DOUBLE_EQ(e->register_state(0).output_um, 250.0);  // what the NC holds
  // A bus reconnect resends every known value: never a held one.
  e->resend_all();
  EXPECT_TRUE(run(*e, t, 5).written.empty());

  const Event r = release(0.0, 7);
  const Outcome after = run(*e, t, 20, {&r, 1});
  ASSERT_EQ(after.written.size(), 1U);
  EXPECT_DOUBLE_EQ(after.written[0], 10.0);
  EXPECT_EQ(e->register_state(0).hold, RegisterHold::kNone);
  EXPECT_EQ(e->counters().release_commands, 1U);
  EXPECT_EQ(e->counters().last_release_sequence, 7U);
  EXPECT_EQ(e->counters().last_release_count, 1U);
  // Later targets move through the limiter as usual.
  m->value_um = 30.0;
  const Outcome later = run(*e, t, 10);
  ASSERT_EQ(later.written.size(), 4U);
  EXPECT_DOUBLE_EQ(later.written[0], 15.0);
  EXPECT_DOUBLE_EQ(later.written[3], 30.0);
  // Nothing held any more: a second release releases nothing.
  const Event r2 = release(-1.0, 8);
  (void)run(*e, t, 1, {&r2, 1});
  EXPECT_EQ(e->counters().last_release_count, 0U);
  EXPECT_EQ(e->counters().last_release_sequence, 8U);
}

TEST(StartupHold, ReleasedWithoutATargetTheRegisterStartsFromTheBoundNeverBeyondIt) {
  Writer* m = nullptr;
  auto e = make_engine(10.0, &m);
  m->publish = false;
  ASSERT_TRUE(e->anchor_register(0, 1e30, 0).beyond_limit);
  TimeNs t = 0;
  const Event r = release(0.0, 1);
  EXPECT_TRUE(run(*e, t, 5, {&r, 1}).written.empty());
  EXPECT_EQ(e->counters().last_release_count, 1U);
  EXPECT_DOUBLE_EQ(e->register_state(0).output_um, 200.0);
  m->publish = true;
  const Outcome w = run(*e, t, 60);
  ASSERT_FALSE(w.written.empty());
  EXPECT_DOUBLE_EQ(w.written.front(), 195.0);
  EXPECT_DOUBLE_EQ(w.written.back(), 10.0);
  for (double v : w.written) EXPECT_LE(std::fabs(v), 200.0);
}

// A restored target beyond a narrowed limit cannot be the released value: the register starts
// from the bound (what status shows), and later targets slew from there, never beyond it.
TEST(StartupHold, ReleasedWithARestoredTargetBeyondANarrowedLimitTheRegisterStartsFromTheBound) {
  Writer* m = nullptr;
  auto before = make_engine(150.0, &m);
  TimeNs t = 0;
  (void)run(*before, t, 40);  // target and output 150 µm, saved
  const auto state = state_of(*before);
  auto e = make_engine(150.0, &m, 100.0);
  m->publish = false;  // no new target: the restored 150 µm stands
  ASSERT_TRUE(e->import_state(state, t));
  ASSERT_EQ(e->register_state(0).hold, RegisterHold::kBeyondLimit);
  ASSERT_DOUBLE_EQ(e->register_state(0).target_um, 150.0);
  const Event r = release(0.0, 1);
  const Outcome w = run(*e, t, 5, {&r, 1});
  EXPECT_EQ(e->counters().last_release_count, 1U);
  EXPECT_EQ(e->register_state(0).hold, RegisterHold::kNone);
  EXPECT_DOUBLE_EQ(e->register_state(0).output_um, 100.0);
  // The NC held 150 µm: the release moves it to the bound in one write, although the goal is
  // what was last sent before the limit narrowed.
  ASSERT_EQ(w.written.size(), 1U);
  EXPECT_DOUBLE_EQ(w.written[0], 100.0);
  m->value_um = 50.0;
  m->publish = true;
  const Outcome later = run(*e, t, 20);
  ASSERT_FALSE(later.written.empty());
  EXPECT_DOUBLE_EQ(later.written.front(), 95.0);
  EXPECT_DOUBLE_EQ(later.written.back(), 50.0);
}

TEST(StartupHold, ARestoredOutputBeyondANarrowedLimitIsHeldAndAReadBackWithinItEndsTheHold) {
  Writer* m = nullptr;
  auto before = make_engine(150.0, &m);
  TimeNs t = 0;
  (void)run(*before, t, 40);  // 150 µm reached and saved
  const auto state = state_of(*before);
  // The reloaded configuration allows 100 µm: the NC holds 150.
  auto e = make_engine(50.0, &m, 100.0);
  ASSERT_TRUE(e->import_state(state, t));
  EXPECT_EQ(e->register_state(0).hold, RegisterHold::kBeyondLimit);
  m->value_um = 50.0;
  const Outcome held = run(*e, t, 20);
  EXPECT_TRUE(held.written.empty());
  EXPECT_EQ(count(held.alarms, AlarmCode::kRegisterBeyondLimit), 1U);
  // A restart whose read-back finds 90 µm (corrected by hand): no longer held, slews from 90.
  auto f = make_engine(50.0, &m, 100.0);
  ASSERT_TRUE(f->import_state(state, t));
  ASSERT_FALSE(f->anchor_register(0, 90.0, t).beyond_limit);
  EXPECT_EQ(f->register_state(0).hold, RegisterHold::kNone);
  m->value_um = 50.0;
  const Outcome w = run(*f, t, 20);
  EXPECT_EQ(count(w.alarms, AlarmCode::kRegisterBeyondLimit), 0U);
  ASSERT_FALSE(w.written.empty());
  EXPECT_DOUBLE_EQ(w.written.front(), 85.0);
  EXPECT_DOUBLE_EQ(w.written.back(), 50.0);
}

TEST(StartupHold, MalformedReleasesAreInvalidEventsAndReleaseNothing) {
  Writer* m = nullptr;
  auto e = make_engine(10.0, &m);
  ASSERT_TRUE(e->anchor_register(0, 250.0, 0).beyond_limit);
  TimeNs t = 0;
  std::vector<Event> bad{release(3.0, 1), release(0.5, 2), release(-2.0, 3), release(0.0, 0),
                         release(std::numeric_limits<double>::quiet_NaN(), 4)};
  OperatorCommand coded = std::get<OperatorCommand>(release(0.0, 5));
  coded.code[1] = 1;
  bad.push_back(coded);
  OperatorCommand second = std::get<OperatorCommand>(release(0.0, 6));
  second.value[1] = 1.0;
  bad.push_back(second);
  const Outcome w = run(*e, t, 5, bad);
  EXPECT_TRUE(w.written.empty());
  EXPECT_EQ(e->counters().events_invalid, bad.size());
  EXPECT_EQ(e->counters().release_commands, 0U);
  EXPECT_EQ(e->register_state(0).hold, RegisterHold::kBeyondLimit);
}

TEST(StartupHold, AModuleWithoutStateThatAdoptsKeepsTheNcsValueNoWrite) {
  Writer* m = nullptr;
  auto e = make_engine(0.0, &m);  // fresh: the module would write 0
  EXPECT_EQ(e->module_state(0), ModuleStateSource::kFresh);
  ASSERT_TRUE(e->anchor_register(0, -33.0, 0).anchored);
  EXPECT_EQ(e->adopt_without_state(0, -33.0, true, 0), StartupAdoption::kAdopted);
  EXPECT_DOUBLE_EQ(m->value_um, -33.0);
  EXPECT_DOUBLE_EQ(e->register_state(0).target_um, -33.0);
  EXPECT_EQ(e->register_state(0).hold, RegisterHold::kNone);
  TimeNs t = 0;
  const Outcome w = run(*e, t, 50);
  EXPECT_TRUE(w.written.empty());
  ASSERT_EQ(count(w.alarms, AlarmCode::kRegisterAdopted), 1U);
  EXPECT_EQ(w.alarms[0].severity, Severity::kWarning);
  EXPECT_DOUBLE_EQ(w.alarms[0].value, -33.0);
  // The flag register: offered to the module too (it sees the NC's value), written as computed.
  ASSERT_TRUE(e->anchor_register(2, 1.0, 0).anchored);
  EXPECT_EQ(e->adopt_without_state(2, 1.0, true, 0), StartupAdoption::kFlag);
  EXPECT_EQ(e->register_state(2).hold, RegisterHold::kNone);
  // No module writes register 1.
  EXPECT_EQ(e->adopt_without_state(1, 5.0, true, 0), StartupAdoption::kNotNeeded);
}

TEST(StartupHold, AModuleThatCannotAdoptLeavesTheRegisterHeldUntilReleasedThenItSlews) {
  Writer* m = nullptr;
  auto e = make_engine(0.0, &m);
  m->adopts = false;
  ASSERT_TRUE(e->anchor_register(0, -33.0, 0).anchored);
  EXPECT_EQ(e->adopt_without_state(0, -33.0, true, 0), StartupAdoption::kHeld);
  EXPECT_EQ(e->register_state(0).hold, RegisterHold::kWithoutState);
  TimeNs t = 0;
  const Outcome held = run(*e, t, 50);
  EXPECT_TRUE(held.written.empty());
  ASSERT_EQ(count(held.alarms, AlarmCode::kRegisterHeldWithoutState), 1U);
  EXPECT_DOUBLE_EQ(held.alarms[0].value, -33.0);
  // Saved and restored (a restart, a reload): still held, the alarm raised again.
  auto f = make_engine(0.0, &m);
  m->adopts = false;
  ASSERT_TRUE(f->import_state(state_of(*e), t));
  EXPECT_EQ(f->module_state(0), ModuleStateSource::kRestored);
  EXPECT_EQ(f->register_state(0).hold, RegisterHold::kWithoutState);
  const Outcome still = run(*f, t, 20);
  EXPECT_TRUE(still.written.empty());
  EXPECT_EQ(count(still.alarms, AlarmCode::kRegisterHeldWithoutState), 1U);
  // The operator decides: from -33 to the module's 0 through the limiter (5 µm per write).
  const Event r = release(-1.0, 1);
  const Outcome w = run(*f, t, 20, {&r, 1});
  EXPECT_EQ(f->counters().last_release_count, 1U);
  ASSERT_EQ(w.written.size(), 7U);
  EXPECT_DOUBLE_EQ(w.written.front(), -28.0);
  EXPECT_DOUBLE_EQ(w.written.back(), 0.0);
  // The released state no longer holds it.
  auto g = make_engine(0.0, &m);
  ASSERT_TRUE(g->import_state(state_of(*f), t));
  EXPECT_EQ(g->register_state(0).hold, RegisterHold::kNone);
}

TEST(StartupHold, AnUnansweredReadBackHoldsAnUnreadableBusAndARestoredModuleDoNot) {
  Writer* m = nullptr;
  auto e = make_engine(0.0, &m);
  EXPECT_EQ(e->adopt_without_state(0, std::nullopt, true, 0), StartupAdoption::kHeld);
  TimeNs t = 0;
  const Outcome held = run(*e, t, 10);
  EXPECT_TRUE(held.written.empty());
  ASSERT_EQ(count(held.alarms, AlarmCode::kRegisterHeldWithoutState), 1U);
  EXPECT_TRUE(std::isnan(held.alarms[0].value));
  EXPECT_TRUE(m->offered.empty());  // nothing to offer
  // The next start reads the NC (-33 µm): the restored module is offered it, the hold ends.
  auto again = make_engine(0.0, &m);
  ASSERT_TRUE(again->import_state(state_of(*e), t));
  EXPECT_EQ(again->register_state(0).hold, RegisterHold::kWithoutState);
  ASSERT_TRUE(again->anchor_register(0, -33.0, t).anchored);
  EXPECT_EQ(again->adopt_without_state(0, -33.0, true, t), StartupAdoption::kAdopted);
  EXPECT_EQ(again->register_state(0).hold, RegisterHold::kNone);
  const Outcome adopted = run(*again, t, 10);
  EXPECT_TRUE(adopted.written.empty());
  EXPECT_EQ(count(adopted.alarms, AlarmCode::kRegisterHeldWithoutState), 0U);
  EXPECT_EQ(count(adopted.alarms, AlarmCode::kRegisterAdopted), 1U);

  // A bus that cannot read back (CAN): the module's values are written (documented).
  auto f = make_engine(2.0, &m);
  EXPECT_EQ(f->adopt_without_state(0, std::nullopt, false, 0), StartupAdoption::kNotReadable);
  const Outcome w = run(*f, t, 1);
  ASSERT_EQ(w.written.size(), 1U);
  EXPECT_DOUBLE_EQ(w.written[0], 2.0);

  // A restored module needs nothing; one whose bytes it refused is "unreadable", not restored.
  const auto state = state_of(*f);
  auto g = make_engine(2.0, &m);
  ASSERT_TRUE(g->import_state(state, t));
  EXPECT_EQ(g->module_state(0), ModuleStateSource::kRestored);
  EXPECT_EQ(g->adopt_without_state(0, -33.0, true, t), StartupAdoption::kNotNeeded);
  auto h = make_engine(2.0, &m);
  m->refuse_state = true;
  std::size_t skipped = 0;
  ASSERT_TRUE(h->import_state(state, t, &skipped));
  EXPECT_EQ(skipped, 1U);
  EXPECT_EQ(h->module_state(0), ModuleStateSource::kUnreadable);
  ASSERT_TRUE(h->anchor_register(0, -33.0, t).anchored);
  EXPECT_EQ(h->adopt_without_state(0, -33.0, true, t), StartupAdoption::kAdopted);
  // An NC at 0 (nothing to lose) is not held even if the module cannot adopt it.
  auto k = make_engine(2.0, &m);
  m->adopts = false;
  EXPECT_EQ(k->adopt_without_state(0, 0.05, true, 0), StartupAdoption::kNotNeeded);
}

TEST(StartupHold, SteppingWithReleasesAndHeldRegistersAllocatesNothing) {
  Writer* m = nullptr;
  auto e = make_engine(10.0, &m);
  ASSERT_TRUE(e->anchor_register(0, 250.0, 0).beyond_limit);
  TimeNs t = 0;
  StepOutput out;
  e->step(t += 10 * kMs, {}, out);  // the first step (alarms) outside the scope
  const Event r = release(0.0, 1);
  test::AllocationScope scope;
  for (int k = 0; k < 100; ++k) {
    e->step(t += 10 * kMs, {}, out);
  }
  e->step(t += 10 * kMs, {&r, 1}, out);
  e->step(t += 10 * kMs, {}, out);
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
}

}  // namespace
}  // namespace nccomp::core::engine
