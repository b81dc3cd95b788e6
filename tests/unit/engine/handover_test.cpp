// GIVEN a register written by a learning module and trimmed by a model, WHEN a state is handed to
// an engine whose trims come from something else (a model loaded, replaced, taken out) THEN the
// register's total stays where it was and the writer takes the difference; the same trims (a
// restart) are not rebased.
#include <gtest/gtest.h>

#include <cstring>
#include <memory>
#include <vector>

#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

constexpr TimeNs kMs = 1'000'000;

// Writes its learned value to register 0 every cycle; a rebase shifts it (as S1 does).
class Learner final : public Module {
 public:
  explicit Learner(double value, bool can_rebase = true) : value_(value), can_rebase_(can_rebase) {}
  std::string_view name() const noexcept override { return "learner"; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    out.writes.push(OffsetWrite{now_ns, 0, value_});
  }
  std::size_t state_capacity() const noexcept override { return sizeof(double); }
  std::size_t save_state(std::span<std::byte> buf) const noexcept override {
    std::memcpy(buf.data(), &value_, sizeof value_);
    return sizeof value_;
  }
  bool load_state(std::span<const std::byte> bytes) noexcept override {
    if (bytes.size() != sizeof(double)) return false;
    std::memcpy(&value_, bytes.data(), sizeof value_);
    return true;
  }
  std::vector<std::uint16_t> written_registers() const override { return {0}; }
  bool rebase_output(std::uint16_t register_index, double delta_um,
                     TimeNs /*now_ns*/) noexcept override {
    if (!can_rebase_ || register_index != 0) return false;
    value_ += delta_um;
    return true;
  }
  double value_;
  bool can_rebase_;
};

// A model's trim of register 0, with the identity of its model.
class Model final : public Module {
 public:
  Model(double trim, std::uint64_t identity) : trim_(trim), identity_(identity) {}
  std::string_view name() const noexcept override { return "model"; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    out.trims.push(OffsetWrite{now_ns, 0, trim_});
  }
  std::uint64_t trim_identity() const noexcept override { return identity_; }
  double trim_;
  std::uint64_t identity_;
};

struct Machine {
  Engine engine;
  Learner* learner{nullptr};
  Model* model{nullptr};
  StepOutput out;
  TimeNs t{0};
  double largest_write_change_um{0.0};
  double nc_um{0.0};

  // max_step 5 µm: a handover that moved the total would show as slewing writes.
  Machine(double learned, const Model* with_model, bool can_rebase = true) {
    std::vector<std::unique_ptr<Module>> m;
    auto l = std::make_unique<Learner>(learned, can_rebase);
    learner = l.get();
    m.push_back(std::move(l));
    if (with_model != nullptr) {
      auto p = std::make_unique<Model>(with_model->trim_, with_model->identity_);
      model = p.get();
      m.push_back(std::move(p));
    }
    engine.configure({RegisterSpec{"T1_radius_wear", RegisterKind::kToolRadiusWear,
                                   LimiterConfig{200.0, 5.0, 1e6}}},
                     std::move(m));
  }
  void run(int cycles) {
    for (int k = 0; k < cycles; ++k) {
      t += kMs;
      engine.step(t, {}, out);
      for (const auto& w : out.writes) {
        largest_write_change_um = std::max(largest_write_change_um, std::fabs(w.value_um - nc_um));
        nc_um = w.value_um;
      }
    }
  }
  std::vector<std::byte> state() const {
    std::vector<std::byte> buf(engine.state_capacity());
    buf.resize(engine.export_state(buf));
    return buf;
  }
  // Takes over from another machine's state at its time and NC value (a reload or restart).
  void take_over(const Machine& from) {
    t = from.t;
    nc_um = from.nc_um;
    const auto s = from.state();
    ASSERT_TRUE(engine.import_state(s, t));
  }
  double total_um() const {
    const RegisterState r = engine.register_state(0);
    return r.target_um + r.trim_um;
  }
};

TEST(TrimHandover, LoadingAModelKeepsTheTotalAndTheLearnerKeepsOnlyTheResidual) {
  // GIVEN S1 has learned −42 µm of wear and no model runs.
  Machine before(-42.0, nullptr);
  before.run(20);
  ASSERT_DOUBLE_EQ(before.nc_um, -42.0);
  // WHEN a model predicting −50 µm takes over.
  const Model m(-50.0, 7);
  Machine after(-42.0, &m);
  after.take_over(before);
  after.largest_write_change_um = 0.0;
  after.run(20);
  // THEN the NC keeps −42 (nothing written), the learner holds −42 − (−50) = 8.
  EXPECT_DOUBLE_EQ(after.nc_um, -42.0);
  EXPECT_DOUBLE_EQ(after.largest_write_change_um, 0.0);
  EXPECT_DOUBLE_EQ(after.learner->value_, 8.0);
  EXPECT_DOUBLE_EQ(after.engine.register_state(0).trim_um, -50.0);
  EXPECT_DOUBLE_EQ(after.total_um(), -42.0);
  EXPECT_EQ(after.engine.counters().handover_rebases, 1U);
  EXPECT_EQ(after.engine.counters().handovers, 1U);
  EXPECT_DOUBLE_EQ(after.engine.counters().last_handover_trim_change_um, 50.0);
  EXPECT_DOUBLE_EQ(after.engine.counters().last_handover_unabsorbed_um, 0.0);
  // And the model predicts from here: 3 µm more wear reach the NC through the limiter.
  after.model->trim_ = -53.0;
  after.run(5);
  EXPECT_DOUBLE_EQ(after.nc_um, -45.0);
}

TEST(TrimHandover, TakingTheModelOutOrReplacingItKeepsTheTotal) {
  const Model m(-50.0, 7);
  Machine with(8.0, &m);
  with.run(20);
  with.model->trim_ = -55.0;  // the model's prediction moved since
  with.run(20);
  ASSERT_DOUBLE_EQ(with.nc_um, -47.0);
  // Rollback to no model: the learner takes the model's −55 µm.
  Machine none(8.0, nullptr);
  none.take_over(with);
  none.largest_write_change_um = 0.0;
  none.run(20);
  EXPECT_DOUBLE_EQ(none.nc_um, -47.0);
  EXPECT_DOUBLE_EQ(none.learner->value_, -47.0);
  EXPECT_DOUBLE_EQ(none.largest_write_change_um, 0.0);
  // Another model (identity 9, −60 µm): the learner takes the difference, 5 µm.
  const Model other(-60.0, 9);
  Machine replaced(8.0, &other);
  replaced.take_over(with);
  replaced.largest_write_change_um = 0.0;
  replaced.run(20);
  EXPECT_DOUBLE_EQ(replaced.nc_um, -47.0);
  EXPECT_DOUBLE_EQ(replaced.learner->value_, 13.0);
  EXPECT_DOUBLE_EQ(replaced.largest_write_change_um, 0.0);
}

TEST(TrimHandover, TheSameModelAfterARestartIsNotRebased) {
  const Model m(-50.0, 7);
  Machine first(8.0, &m);
  first.run(20);
  // The restarted daemon's model predicts 2 µm more (time went on): that is the model's job.
  const Model again(-52.0, 7);
  Machine restarted(8.0, &again);
  restarted.take_over(first);
  restarted.run(20);
  EXPECT_DOUBLE_EQ(restarted.learner->value_, 8.0);
  EXPECT_DOUBLE_EQ(restarted.nc_um, -44.0);
  EXPECT_EQ(restarted.engine.counters().handover_rebases, 0U);
  EXPECT_EQ(restarted.engine.counters().handover_unabsorbed, 0U);
  EXPECT_EQ(restarted.engine.counters().handovers, 0U);
}

TEST(TrimHandover, AWriterThatCannotRebaseMovesThroughTheLimiterAndIsCounted) {
  Machine before(-42.0, nullptr);
  before.run(20);
  const Model m(-50.0, 7);
  Machine after(-42.0, &m, /*can_rebase=*/false);
  after.take_over(before);
  after.largest_write_change_um = 0.0;
  after.run(30);
  EXPECT_DOUBLE_EQ(after.nc_um, -92.0);
  EXPECT_DOUBLE_EQ(after.largest_write_change_um, 5.0);
  EXPECT_EQ(after.engine.counters().handover_unabsorbed, 1U);
  EXPECT_EQ(after.engine.counters().handover_rebases, 0U);
  EXPECT_EQ(after.engine.counters().handovers, 1U);
  EXPECT_DOUBLE_EQ(after.engine.counters().last_handover_trim_change_um, 50.0);
  EXPECT_DOUBLE_EQ(after.engine.counters().last_handover_unabsorbed_um, 50.0);
}

TEST(TrimHandover, TheHandoverStepAllocatesNothing) {
  Machine before(-42.0, nullptr);
  before.run(20);
  const Model m(-50.0, 7);
  Machine after(-42.0, &m);
  const auto s = before.state();
  test::AllocationScope scope;
  ASSERT_TRUE(after.engine.import_state(s, before.t));
  after.engine.step(before.t + kMs, {}, after.out);
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
  EXPECT_EQ(after.engine.counters().handover_rebases, 1U);
}

}  // namespace
}  // namespace nccomp::core::engine

namespace nccomp::core::engine {
namespace {

// Found by the e2e rollback: a reload swapped in before the first cycle of a restarted daemon
// exported an engine that had imported the model's trim but not yet stepped: trim 0, identity 0.
// The next engine saw nothing to hand over and the learner's residual (≈ 0) became the total.
TEST(TrimHandover, AnEngineSwappedOutBeforeItsFirstStepPassesTheImportedTrimsOn) {
  const Model m(-50.0, 7);
  Machine with(8.0, &m);
  with.run(20);
  Machine restarted(8.0, &m);
  restarted.take_over(with);  // a restart with the model: imported, never stepped
  Machine none(8.0, nullptr);
  none.take_over(restarted);  // the reload's swap in the first cycle
  none.run(20);
  EXPECT_DOUBLE_EQ(none.nc_um, -42.0);
  EXPECT_DOUBLE_EQ(none.learner->value_, -42.0);
}

}  // namespace
}  // namespace nccomp::core::engine
