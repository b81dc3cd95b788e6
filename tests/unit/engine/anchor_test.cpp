// GIVEN an engine restarted from its state (or fresh) and a value read back from the NC's
// register, WHEN the register is anchored to it (Engine::anchor_register / adopt_register, the
// daemon's start-up), THEN the next writes move from what the NC holds, never more than
// max_step_um per write nor faster than max_rate_um_per_s, and converge on the module's target;
// a non-finite read-back is refused and changes nothing.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <vector>

#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

constexpr TimeNs kMs = 1'000'000;

// Writes one absolute target to register 0 every cycle (what S0/S1 do with a held value).
class TargetModule final : public Module {
 public:
  explicit TargetModule(double value_um) : value_um_(value_um) {}
  std::string_view name() const noexcept override { return "target"; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    if (publish) out.writes.push(OffsetWrite{now_ns, 0, value_um_});
  }
  std::vector<std::uint16_t> written_registers() const override { return {0}; }
  bool publish{true};
  double value_um_;
};

/// Register 0: max_abs 200 µm, max_step 5 µm, 1000 µm/s (steps of 10 ms allow 10 µm: the step
/// limit is the one that binds). Register 1: a second register nobody writes.
std::unique_ptr<Engine> make_engine(double target_um, TargetModule** module = nullptr,
                                    double max_rate_um_per_s = 1000.0) {
  auto e = std::make_unique<Engine>();
  std::vector<RegisterSpec> regs{
      {"D22", RegisterKind::kCheckpoint, LimiterConfig{200.0, 5.0, max_rate_um_per_s}},
      {"spare", RegisterKind::kToolLengthWear, LimiterConfig{200.0, 5.0, max_rate_um_per_s}}};
  std::vector<std::unique_ptr<Module>> mods;
  auto m = std::make_unique<TargetModule>(target_um);
  if (module != nullptr) *module = m.get();
  mods.push_back(std::move(m));
  e->configure(std::move(regs), std::move(mods));
  return e;
}

/// Steps every 10 ms from t; returns every value written to register 0, in order.
std::vector<double> run(Engine& e, TimeNs& t, int cycles) {
  std::vector<double> written;
  StepOutput out;
  for (int k = 0; k < cycles; ++k) {
    e.step(t += 10 * kMs, {}, out);
    for (const auto& w : out.writes) {
      if (w.register_index == 0) written.push_back(w.value_um);
    }
  }
  return written;
}

/// The state of an engine that sent target_um to register 0 (what the state file holds).
std::vector<std::byte> state_after_sending(double target_um) {
  auto e = make_engine(target_um);
  TimeNs t = 0;
  const auto w = run(*e, t, 10);
  EXPECT_DOUBLE_EQ(w.back(), target_um);
  std::vector<std::byte> buf(e->state_capacity());
  buf.resize(e->export_state(buf));
  return buf;
}

TEST(EngineAnchor, ARestartedRegisterSlewsFromTheValueTheNcHoldsNotFromTheRestoredOne) {
  // Before the restart the engine sent −8.0 µm; while it was down an operator set +80.0 µm.
  const auto state = state_after_sending(-8.0);

  // Without the read-back the engine believes the NC holds −8.0 (its target): it writes
  // nothing, and the NC keeps +80.0 while the daemon shows −8.0.
  {
    auto e = make_engine(-8.0);
    ASSERT_TRUE(e->import_state(state, 1000 * kMs));
    TimeNs t = 1000 * kMs;
    EXPECT_TRUE(run(*e, t, 100).empty());
    EXPECT_DOUBLE_EQ(e->register_state(0).output_um, -8.0);
  }

  auto e = make_engine(-8.0);
  ASSERT_TRUE(e->import_state(state, 1000 * kMs));
  const auto g0 = e->state_generation();
  const AnchorResult a = e->anchor_register(0, 80.0, 1000 * kMs);
  EXPECT_TRUE(a.anchored);
  EXPECT_TRUE(a.known);
  EXPECT_DOUBLE_EQ(a.before_um, -8.0);
  EXPECT_FALSE(a.beyond_limit);
  EXPECT_FALSE(a.adopted);
  EXPECT_GT(e->state_generation(), g0);  // the state file gets the NC's value
  EXPECT_DOUBLE_EQ(e->register_state(0).output_um, 80.0);
  EXPECT_DOUBLE_EQ(e->register_state(0).target_um, -8.0);  // the target is the module's

  // From +80.0 to the module's −8.0 in steps of max_step_um = 5: 75, 70, ..., −5, then −8.
  TimeNs t = 1000 * kMs;
  const auto w = run(*e, t, 40);
  ASSERT_EQ(w.size(), 18U);
  double nc = 80.0;  // every value the NC receives, starting from what it held
  for (std::size_t k = 0; k < w.size(); ++k) {
    EXPECT_LE(std::fabs(w[k] - nc), 5.0 + 1e-9) << "write " << k;
    nc = w[k];
  }
  EXPECT_DOUBLE_EQ(w[0], 75.0);
  EXPECT_DOUBLE_EQ(w[16], -5.0);
  EXPECT_DOUBLE_EQ(w[17], -8.0);
  EXPECT_DOUBLE_EQ(e->register_state(0).output_um, -8.0);
  EXPECT_FALSE(e->register_state(0).slewing);
}

TEST(EngineAnchor, TheRateLimitStartsAtTheAnchor) {
  // 50 µm/s: over 10 ms cycles the rate binds (0.5 µm per write), from the anchor's time on.
  TargetModule* m = nullptr;
  auto e = make_engine(0.0, &m, 50.0);
  const AnchorResult a = e->anchor_register(0, 30.0, 2000 * kMs);
  EXPECT_TRUE(a.anchored);
  EXPECT_FALSE(a.known);  // fresh engine: nothing restored, nothing sent
  EXPECT_DOUBLE_EQ(a.before_um, 0.0);
  TimeNs t = 2000 * kMs;
  const auto w = run(*e, t, 100);  // 1 s: 50 µm/s × 1 s > 30 µm
  ASSERT_EQ(w.size(), 60U);
  double nc = 30.0;
  TimeNs prev = 2000 * kMs;
  for (std::size_t k = 0; k < w.size(); ++k) {
    const TimeNs at = 2000 * kMs + static_cast<TimeNs>(k + 1) * 10 * kMs;
    EXPECT_LE(std::fabs(w[k] - nc), 50.0 * seconds(at - prev) + 1e-9) << "write " << k;
    nc = w[k];
    prev = at;
  }
  EXPECT_NEAR(w[0], 29.5, 1e-9);
  EXPECT_NEAR(w.back(), 0.0, 1e-9);
}

TEST(EngineAnchor, AFreshEngineWithoutTheReadBackWouldJumpToItsTarget) {
  // The same fresh start without anchoring: the first write goes straight from what the engine
  // assumes (0) to the target, whatever the NC held. Shown for the contrast with the test above.
  auto e = make_engine(2.0);
  TimeNs t = 0;
  const auto w = run(*e, t, 1);
  ASSERT_EQ(w.size(), 1U);
  EXPECT_DOUBLE_EQ(w[0], 2.0);
  // Anchored at 30 µm instead, the same target arrives in steps of at most 5 µm.
  auto f = make_engine(2.0);
  ASSERT_TRUE(f->anchor_register(0, 30.0, 0).anchored);
  TimeNs u = 0;
  const auto v = run(*f, u, 10);
  ASSERT_EQ(v.size(), 6U);
  EXPECT_DOUBLE_EQ(v[0], 25.0);
  EXPECT_DOUBLE_EQ(v[5], 2.0);
}

TEST(EngineAnchor, NonFiniteReadBackAndUnknownRegisterAreRefusedAndChangeNothing) {
  const auto state = state_after_sending(-8.0);
  auto e = make_engine(-8.0);
  ASSERT_TRUE(e->import_state(state, 0));
  const auto g0 = e->state_generation();
  for (const double bad :
       {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
        -std::numeric_limits<double>::infinity()}) {
    const AnchorResult a = e->anchor_register(0, bad, 0);
    EXPECT_FALSE(a.anchored) << bad;
    EXPECT_FALSE(e->adopt_register(0, bad, 0).anchored) << bad;
  }
  EXPECT_FALSE(e->anchor_register(2, 1.0, 0).anchored);
  EXPECT_FALSE(e->adopt_register(99, 1.0, 0).anchored);
  EXPECT_EQ(e->state_generation(), g0);
  EXPECT_DOUBLE_EQ(e->register_state(0).output_um, -8.0);
  TimeNs t = 0;
  EXPECT_TRUE(run(*e, t, 10).empty());  // still at the restored value: nothing to write
}

TEST(EngineAnchor, AdoptKeepsTheNcsValueUntilAModuleAsksForAnother) {
  const auto state = state_after_sending(-8.0);
  TargetModule* m = nullptr;
  auto e = make_engine(-8.0, &m);
  ASSERT_TRUE(e->import_state(state, 0));
  // A module that adopts the NC's +80.0 but publishes it only later (S1 writes 32 table
  // registers per cycle): until then the engine must not pull the register back to −8.0.
  m->publish = false;
  const AnchorResult a = e->adopt_register(0, 80.0, 0);
  EXPECT_TRUE(a.anchored);
  EXPECT_TRUE(a.adopted);
  EXPECT_DOUBLE_EQ(e->register_state(0).target_um, 80.0);
  TimeNs t = 0;
  EXPECT_TRUE(run(*e, t, 20).empty());
  // The module then publishes the adopted value: still nothing to write.
  m->value_um_ = 80.0;
  m->publish = true;
  EXPECT_TRUE(run(*e, t, 20).empty());
  // A new target later moves it through the limiter from +80.0.
  m->value_um_ = 70.0;
  const auto w = run(*e, t, 5);
  ASSERT_EQ(w.size(), 2U);
  EXPECT_DOUBLE_EQ(w[0], 75.0);
  EXPECT_DOUBLE_EQ(w[1], 70.0);

  // Anchoring alone (no adopt) with the module silent: the restored target −8.0 wins.
  auto f = make_engine(-8.0, &m);
  ASSERT_TRUE(f->import_state(state, 0));
  m->publish = false;
  ASSERT_TRUE(f->anchor_register(0, 80.0, 0).anchored);
  TimeNs u = 0;
  const auto v = run(*f, u, 40);
  ASSERT_FALSE(v.empty());
  EXPECT_DOUBLE_EQ(v.front(), 75.0);
  EXPECT_DOUBLE_EQ(v.back(), -8.0);
}

TEST(EngineAnchor, AValueBeyondTheAbsoluteLimitIsHeldNeverAdoptedNeverSlewedFrom) {
  const auto state = state_after_sending(10.0);
  auto e = make_engine(10.0);
  ASSERT_TRUE(e->import_state(state, 0));
  // The NC holds 230 µm (beyond max_abs_um = 200): the register is held, nothing is written to
  // it (slewing inward would send 225, 220, ... beyond the limit; tests/unit/engine/
  // startup_hold_test.cpp has the release).
  const AnchorResult a = e->adopt_register(0, 230.0, 0);
  EXPECT_TRUE(a.anchored);
  EXPECT_TRUE(a.beyond_limit);
  EXPECT_FALSE(a.adopted);
  EXPECT_DOUBLE_EQ(e->register_state(0).target_um, 10.0);
  EXPECT_EQ(e->register_state(0).hold, RegisterHold::kBeyondLimit);
  TimeNs t = 0;
  EXPECT_TRUE(run(*e, t, 60).empty());
}

TEST(EngineAnchor, AnAnchoredValueIsWhatTheStateFileKeeps) {
  const auto state = state_after_sending(-8.0);
  TargetModule* m = nullptr;
  auto e = make_engine(-8.0, &m);
  ASSERT_TRUE(e->import_state(state, 0));
  m->publish = false;
  ASSERT_TRUE(e->anchor_register(1, 12.5, 0).anchored);  // a register nobody writes
  std::vector<std::byte> buf(e->state_capacity());
  buf.resize(e->export_state(buf));
  auto f = make_engine(-8.0);
  ASSERT_TRUE(f->import_state(buf, 0));
  EXPECT_DOUBLE_EQ(f->register_state(1).output_um, 12.5);
  EXPECT_FALSE(f->register_state(1).has_target);  // nothing to write to it
  TimeNs t = 0;
  StepOutput out;
  f->step(t += 10 * kMs, {}, out);
  for (const auto& w : out.writes) EXPECT_NE(w.register_index, 1);
}

TEST(EngineAnchor, AnchoringAllocatesNothing) {
  auto e = make_engine(-8.0);
  test::AllocationScope scope;
  for (int k = 0; k < 100; ++k) {
    (void)e->anchor_register(0, 0.5 * k, k * kMs);
    (void)e->adopt_register(1, -0.5 * k, k * kMs);
  }
  EXPECT_EQ(scope.count(), 0U);
}

}  // namespace
}  // namespace nccomp::core::engine
