// GIVEN an engine with write receipts on (what the daemon's loop does) and a bus that writes less
// often than the engine steps, keeping only the latest value per register (the Modbus driver's
// slot; CAN while its link is down), WHEN a target far away is slewed to, THEN every value that
// reaches the NC differs from the one the NC held before by at most max_step_um: a write stays in
// flight until its receipt, a refused write puts the limiter back on the NC's value, a write of
// unknown fate is sent again as it is, flags are not held back, and a register in flight is sent
// again as it is after an import. Without receipts the same bus merges the limiter's steps (the
// issue these receipts fix, shown by the same model).
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

constexpr TimeNs kMs = 1'000'000;
constexpr double kStepUm = 5.0;

// Writes one absolute target to each of its registers every cycle.
class TargetModule final : public Module {
 public:
  TargetModule(std::vector<std::uint16_t> regs, double target_um)
      : value_um(target_um), regs_(std::move(regs)) {}
  std::string_view name() const noexcept override { return "target"; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    for (const std::uint16_t r : regs_) {
      out.writes.push(OffsetWrite{now_ns, r, value_um});
    }
  }
  std::vector<std::uint16_t> written_registers() const override { return regs_; }
  double value_um;

 private:
  std::vector<std::uint16_t> regs_;
};

/// Register 0 "wear": max_abs 200 µm, max_step 5 µm, max_rate 1000 µm/s (1 µm per 1 ms cycle,
/// 50 µm per 50 ms: the rate allows far more than max_step between two slow bus writes).
/// With `flag`, register 1 "flag" is a flag written by the same module.
std::unique_ptr<Engine> make_engine(double target_um, TargetModule** module = nullptr,
                                    bool flag = false) {
  auto e = std::make_unique<Engine>();
  std::vector<RegisterSpec> regs{
      {"wear", RegisterKind::kToolLengthWear, LimiterConfig{200.0, kStepUm, 1000.0}}};
  std::vector<std::uint16_t> written{0};
  if (flag) {
    regs.push_back({"flag", RegisterKind::kFlag, LimiterConfig{1e6, 1.0, 1.0}});
    written.push_back(1);
  }
  auto m = std::make_unique<TargetModule>(written, target_um);
  if (module != nullptr) {
    *module = m.get();
  }
  std::vector<std::unique_ptr<Module>> mods;
  mods.push_back(std::move(m));
  e->configure(std::move(regs), std::move(mods));
  return e;
}

/// A bus that keeps the latest value per register and writes it to the NC every `period`
/// cycles (the Modbus driver's slot and poll period), with the receipt of what it wrote.
struct CoalescingBus {
  struct Slot {
    bool dirty{false};
    double value_um{0.0};
    std::uint64_t sequence{0};
  };
  Slot slot;
  WriteReceipt receipt{};
  std::vector<double> nc;  // every value the NC received, in order

  void take(const StepOutput& out) {
    for (const OffsetWrite& w : out.writes) {
      if (w.register_index == 0) {
        slot = Slot{true, w.value_um, w.sequence};
      }
    }
  }
  void write() {
    if (slot.dirty) {
      nc.push_back(slot.value_um);
      receipt = WriteReceipt{slot.sequence, WriteOutcome::kReached};
      slot.dirty = false;
    }
  }
};

/// Steps the engine at 1 kHz for `cycles` from `t0`; the bus writes every `period(cycle)` ms
/// (0 = not this cycle). Returns the time after the last cycle.
template <typename Period>
TimeNs run(Engine& e, CoalescingBus& bus, TimeNs t0, int cycles, Period period) {
  StepOutput out;
  TimeNs t = t0;
  for (int c = 0; c < cycles; ++c) {
    t += kMs;
    e.write_receipt(0, bus.receipt, t);
    e.step(t, {}, out);
    bus.take(out);
    if (period(c)) {
      bus.write();
    }
  }
  return t;
}

double largest_step(const std::vector<double>& nc, double from_um) {
  double worst = 0.0;
  for (const double v : nc) {
    worst = std::max(worst, std::fabs(v - from_um));
    from_um = v;
  }
  return worst;
}

TEST(WriteReceipts, WithoutThemASlowBusMergesTheLimitersSteps) {
  // The model of the issue: 1 kHz loop, the bus writes every 50 ms, 1000 µm/s allowed.
  auto e = make_engine(150.0);
  CoalescingBus bus;
  run(*e, bus, 0, 400, [](int c) { return c % 50 == 49; });
  ASSERT_FALSE(bus.nc.empty());
  EXPECT_DOUBLE_EQ(bus.nc.back(), 150.0);
  EXPECT_GT(largest_step(bus.nc, 0.0), 40.0) << "the bus did not merge writes: no model";
}

TEST(WriteReceipts, EveryValueTheNcGetsIsWithinMaxStepOfTheOneBefore) {
  TargetModule* m = nullptr;
  auto e = make_engine(150.0, &m);
  e->set_write_receipts(true);
  CoalescingBus bus;
  // Every 50 ms (a 20 Hz poll), then every 7 ms, then an outage of 2 s (a back-off) with the
  // target moved back meanwhile, then every 333 ms.
  TimeNs t = run(*e, bus, 0, 1000, [](int c) { return c % 50 == 49; });
  t = run(*e, bus, t, 300, [](int c) { return c % 7 == 6; });
  m->value_um = -120.0;
  t = run(*e, bus, t, 2000, [](int /*c*/) { return false; });
  t = run(*e, bus, t, 20000, [](int c) { return c % 333 == 332; });
  (void)t;
  ASSERT_FALSE(bus.nc.empty());
  EXPECT_LE(largest_step(bus.nc, 0.0), kStepUm + 1e-9);
  EXPECT_GT(bus.nc.size(), 60U);  // 150 + 270 µm at 5 µm per write
  EXPECT_DOUBLE_EQ(bus.nc.back(), -120.0) << "the register converged on its target";
  EXPECT_DOUBLE_EQ(e->register_state(0).output_um, -120.0);
  EXPECT_GT(e->counters().writes_awaiting_nc, 1000U);
}

TEST(WriteReceipts, AWriteInFlightHoldsTheNextOneBackUntilItsReceipt) {
  auto e = make_engine(50.0);
  e->set_write_receipts(true);
  StepOutput out;
  e->step(1 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 5.0);  // the first write: max_step_um from 0
  const std::uint64_t seq = out.writes[0].sequence;
  EXPECT_NE(seq, 0U);
  EXPECT_EQ(e->write_in_flight(0), seq);
  EXPECT_TRUE(e->register_state(0).awaiting_nc);
  e->step(2 * kMs, {}, out);
  e->step(3 * kMs, {}, out);
  EXPECT_EQ(out.writes.size(), 0U);
  EXPECT_EQ(e->counters().writes_awaiting_nc, 2U);
  // A pending receipt, or one of an older write, finishes nothing.
  e->write_receipt(0, {seq, WriteOutcome::kPending}, 4 * kMs);
  e->write_receipt(0, {seq - 1, WriteOutcome::kReached}, 4 * kMs);
  e->step(4 * kMs, {}, out);
  EXPECT_EQ(out.writes.size(), 0U);
  // The NC took it at 50 ms: the next write moves max_step_um from there (the rate would allow
  // 49 µm since the last write).
  e->write_receipt(0, {seq, WriteOutcome::kReached}, 50 * kMs);
  EXPECT_FALSE(e->register_state(0).awaiting_nc);
  e->step(50 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 10.0);
  EXPECT_GT(out.writes[0].sequence, seq);
}

TEST(WriteReceipts, ARefusedWritePutsTheLimiterBackOnWhatTheNcHolds) {
  auto e = make_engine(50.0);
  e->set_write_receipts(true);
  ASSERT_TRUE(e->anchor_register(0, 20.0, 0).anchored);  // the NC holds 20 µm
  StepOutput out;
  e->step(10 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 25.0);
  e->write_receipt(0, {out.writes[0].sequence, WriteOutcome::kRefused}, 11 * kMs);
  EXPECT_DOUBLE_EQ(e->register_state(0).output_um, 20.0) << "the NC kept 20 µm";
  // 1 ms after the refusal the rate allows 1 µm from 20, not 5 µm from 25.
  e->step(12 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 21.0);
}

TEST(WriteReceipts, AWriteOfUnknownFateIsSentAgainAsItIs) {
  auto e = make_engine(50.0);
  e->set_write_receipts(true);
  StepOutput out;
  e->step(10 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  const std::uint64_t first = out.writes[0].sequence;
  // No acknowledge after the retries: the NC holds 5 µm or still 0.
  e->write_receipt(0, {first, WriteOutcome::kUnknown}, 200 * kMs);
  e->step(200 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 5.0) << "the same value, not a step further";
  EXPECT_GT(out.writes[0].sequence, first);
  e->step(201 * kMs, {}, out);
  EXPECT_EQ(out.writes.size(), 0U) << "in flight again";
  // The re-send is refused (dropped at a full queue): still unsure, the same value again.
  e->write_receipt(0, {e->write_in_flight(0), WriteOutcome::kRefused}, 202 * kMs);
  e->step(202 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 5.0);
  e->write_receipt(0, {e->write_in_flight(0), WriteOutcome::kReached}, 250 * kMs);
  e->step(250 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 10.0);
}

TEST(WriteReceipts, FlagsAreWrittenAsAskedWithoutWaiting) {
  TargetModule* m = nullptr;
  auto e = make_engine(50.0, &m, true);
  e->set_write_receipts(true);
  StepOutput out;
  int flag_writes = 0;
  for (int c = 1; c <= 5; ++c) {
    m->value_um = c;  // the flag register follows the same module value
    e->step(c * kMs, {}, out);
    for (const auto& w : out.writes) {
      if (w.register_index == 1) {
        ++flag_writes;
        EXPECT_DOUBLE_EQ(w.value_um, c);
      }
    }
  }
  EXPECT_EQ(flag_writes, 5);
  EXPECT_FALSE(e->register_state(1).awaiting_nc);
}

TEST(WriteReceipts, ARegisterInFlightIsSentAgainAsItIsAfterAReload) {
  auto a = make_engine(50.0);
  a->set_write_receipts(true);
  StepOutput out;
  a->step(10 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  const std::uint64_t old_seq = out.writes[0].sequence;
  std::vector<std::byte> state(a->state_capacity());
  const std::size_t n = a->export_state(state);
  ASSERT_GT(n, 0U);
  state.resize(n);

  // The new configuration takes over while 5 µm is still in flight (the NC holds 0 or 5).
  auto b = make_engine(50.0);
  b->set_write_receipts(true);
  b->continue_write_sequence(a->write_sequence());
  ASSERT_TRUE(b->import_state(state, 11 * kMs));
  b->step(12 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 5.0);
  EXPECT_GT(out.writes[0].sequence, old_seq);
  // The bus's receipt of the old engine's write is not the new one's.
  b->write_receipt(0, {old_seq, WriteOutcome::kReached}, 13 * kMs);
  EXPECT_NE(b->write_in_flight(0), 0U);
  b->write_receipt(0, {b->write_in_flight(0), WriteOutcome::kReached}, 60 * kMs);
  b->step(60 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 10.0);

  // A read-back at start-up says what the NC holds: nothing is in doubt any more.
  auto c = make_engine(50.0);
  c->set_write_receipts(true);
  ASSERT_TRUE(c->import_state(state, 0));
  ASSERT_TRUE(c->anchor_register(0, 5.0, 0).anchored);
  c->step(10 * kMs, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 10.0);
}

TEST(WriteReceipts, StepAndReceiptsAllocateNothing) {
  auto e = make_engine(150.0);
  e->set_write_receipts(true);
  CoalescingBus bus;
  bus.nc.reserve(100000);
  StepOutput out;
  const test::AllocationScope scope;
  TimeNs t = 0;
  for (int c = 0; c < 2000; ++c) {
    t += kMs;
    e->write_receipt(0, bus.receipt, t);
    e->step(t, {}, out);
    bus.take(out);
    if (c % 50 == 49) {
      bus.write();
    }
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
  EXPECT_DOUBLE_EQ(bus.nc.back(), 150.0);
}

}  // namespace
}  // namespace nccomp::core::engine
