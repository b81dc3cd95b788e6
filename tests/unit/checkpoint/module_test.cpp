#include "core/checkpoint/module.hpp"

#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <memory>
#include <stdexcept>
#include <string_view>
#include <utility>
#include <vector>

#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/checkpoint/helpers.hpp"

namespace nccomp::core::checkpoint {
namespace {

using test::line_plan;
using test::part_start;
using test::probe;
using test::sample;

std::vector<engine::RegisterSpec> registers(std::size_t n) {
  std::vector<engine::RegisterSpec> r;
  LimiterConfig lim;
  lim.max_abs_um = 100.0;
  lim.max_step_um = 50.0;
  lim.max_rate_um_per_s = 1e6;
  r.push_back({"d19_radius_wear", engine::RegisterKind::kToolRadiusWear, lim});
  for (std::size_t i = 0; i < n; ++i) {
    r.push_back({"cp" + std::to_string(i), engine::RegisterKind::kCheckpoint, lim});
  }
  return r;
}

CompensatorConfig module_config() {
  CompensatorConfig c;
  c.finishing_tool = 12;
  c.register_base = 1;
  c.active_register = 0;
  c.ewma_weight = 1.0;
  c.dead_band_um = 0.0;
  c.probe_repeatability_um = 0.0;
  c.write_threshold_um = 0.0;
  c.apply = ApplyMode::kStep;
  return c;
}

std::unique_ptr<engine::Engine> make_engine(std::size_t n) {
  auto e = std::make_unique<engine::Engine>();
  std::vector<std::unique_ptr<engine::Module>> mods;
  mods.push_back(std::make_unique<CheckpointModule>(module_config(), line_plan(n)));
  e->configure(registers(n), std::move(mods));
  return e;
}

TEST(Module, TheEngineForwardsTheTableAndTheLiveRegister) {
  auto eng = make_engine(3);
  StepOutput out;
  std::vector<Event> ev = {probe(1, 0, 6.0), probe(1, 1, -4.0), probe(1, 2, 2.0)};
  eng->step(0, ev, out);
  ev = {part_start(2)};
  eng->step(1'000'000, ev, out);
  // Registers 1..3 = −6, 4, −2 and the live register pre-positioned to −6.
  std::vector<double> reg(4, 99.0);
  for (const OffsetWrite& w : out.writes) reg[w.register_index] = w.value_um;
  EXPECT_DOUBLE_EQ(reg[1], -6.0);
  EXPECT_DOUBLE_EQ(reg[2], 4.0);
  EXPECT_DOUBLE_EQ(reg[3], -2.0);
  EXPECT_DOUBLE_EQ(reg[0], -6.0);
  // The finishing tool past checkpoint 1 (path 20): the live register becomes 4.
  ev = {sample(21, 0, -5, 21, 12, 2'000'000)};
  eng->step(2'000'000, ev, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_EQ(out.writes[0].register_index, 0U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 4.0);
}

TEST(Module, StateSurvivesARestartThroughTheEnginesBytes) {
  auto a = make_engine(3);
  StepOutput out;
  std::vector<Event> ev = {part_start(1), probe(1, 0, 6.0), probe(1, 2, 2.5)};
  a->step(0, ev, out);
  std::vector<std::byte> buf(a->state_capacity());
  const std::size_t n = a->export_state(buf);
  ASSERT_GT(n, 0U);
  buf.resize(n);

  auto b = make_engine(3);
  ASSERT_TRUE(b->import_state(buf, 0));
  const auto& mb = dynamic_cast<const CheckpointModule&>(b->module(0));
  EXPECT_DOUBLE_EQ(mb.compensator().register_value_um(0), -6.0);
  EXPECT_DOUBLE_EQ(mb.compensator().register_value_um(2), -2.5);
  EXPECT_EQ(mb.compensator().part_counter(), 1);
  EXPECT_DOUBLE_EQ(mb.compensator().point(0).applied_um, 0.0);  // part 1 was cut with 0
  // A plan of another size does not take these bytes.
  auto c = make_engine(4);
  std::size_t skipped = 0;
  (void)c->import_state(buf, 0, &skipped);
  const auto& mc = dynamic_cast<const CheckpointModule&>(c->module(0));
  EXPECT_DOUBLE_EQ(mc.compensator().register_value_um(0), 0.0);
}

TEST(Module, LoadStateRefusesCorruptBytesAllOrNothing) {
  CheckpointModule m(module_config(), line_plan(2));
  const auto regs = registers(2);
  m.attach(engine::RegisterTable(regs));
  StepOutput out;
  std::vector<Event> ev = {probe(1, 0, 6.0), probe(1, 1, 3.0)};
  m.step(0, ev, out);
  std::vector<std::byte> buf(m.state_capacity());
  ASSERT_EQ(m.save_state(buf), buf.size());
  CheckpointModule fresh(module_config(), line_plan(2));
  fresh.attach(engine::RegisterTable(regs));
  std::vector<std::byte> bad = buf;
  // The second record's offset becomes NaN (header 24 bytes, records 176 bytes: layout 2).
  ASSERT_EQ(bad.size(), 24U + 2U * 176U);
  const auto nan_bytes = std::bit_cast<std::array<std::byte, sizeof(double)>>(std::nan(""));
  for (std::size_t k = 0; k < nan_bytes.size(); ++k) bad[24 + 176 + 8 + k] = nan_bytes[k];
  EXPECT_FALSE(fresh.load_state(bad));
  EXPECT_DOUBLE_EQ(fresh.compensator().register_value_um(0), 0.0);  // nothing changed
  EXPECT_FALSE(fresh.load_state(std::span<const std::byte>(buf.data(), buf.size() - 1)));
  EXPECT_TRUE(fresh.load_state(buf));
  EXPECT_DOUBLE_EQ(fresh.compensator().register_value_um(1), -3.0);
  EXPECT_TRUE(fresh.load_state({}));
}

TEST(Module, AttachChecksRegisterKinds) {
  auto regs = registers(3);
  regs[2].kind = engine::RegisterKind::kToolLengthWear;
  CheckpointModule m(module_config(), line_plan(3));
  EXPECT_THROW(m.attach(engine::RegisterTable(regs)), std::invalid_argument);
  regs = registers(3);
  regs[0].kind = engine::RegisterKind::kCheckpoint;
  EXPECT_THROW(m.attach(engine::RegisterTable(regs)), std::invalid_argument);
  regs = registers(2);  // one checkpoint register short
  EXPECT_THROW(m.attach(engine::RegisterTable(regs)), std::invalid_argument);
}

double status_value(const CheckpointModule& m, const char* key) {
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  const std::size_t n = m.status(v);
  for (std::size_t i = 0; i < n; ++i) {
    if (std::string_view(v[i].key) == key) return v[i].value;
  }
  ADD_FAILURE() << "no status value " << key;
  return -1e300;
}

TEST(Module, StatusShowsTheLearnedValuesBoundedAndWithoutAllocating) {
  CheckpointModule m(module_config(), line_plan(6));
  const auto regs = registers(6);
  m.attach(engine::RegisterTable(regs));
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  ASSERT_EQ(m.status(v), 16U);  // within the engine's bound whatever the plan's size
  EXPECT_TRUE(std::isnan(status_value(m, "learned_min_um")));  // nothing learned yet
  EXPECT_EQ(status_value(m, "checkpoint"), -1.0);
  StepOutput out;
  std::vector<Event> ev = {part_start(1), probe(1, 0, 6.0), probe(1, 3, -4.5), probe(1, 5, 2.0)};
  m.step(0, ev, out);
  EXPECT_EQ(status_value(m, "checkpoints"), 6.0);
  EXPECT_EQ(status_value(m, "learned"), 3.0);
  EXPECT_NEAR(status_value(m, "learned_min_um"), -4.5, 1e-12);
  EXPECT_EQ(status_value(m, "learned_min_checkpoint"), 3.0);
  EXPECT_NEAR(status_value(m, "learned_max_um"), 6.0, 1e-12);
  EXPECT_EQ(status_value(m, "learned_max_checkpoint"), 0.0);
  // The focus is the checkpoint of the last event: the last reading ...
  EXPECT_EQ(status_value(m, "checkpoint"), 5.0);
  EXPECT_NEAR(status_value(m, "checkpoint_learned_um"), 2.0, 1e-12);
  EXPECT_EQ(status_value(m, "checkpoint_count"), 1.0);
  EXPECT_NEAR(status_value(m, "checkpoint_offset_um"), -2.0, 1e-12);
  // ... then the checkpoint the finishing tool passed last (path 31 is past checkpoint 2).
  ev = {part_start(2), sample(0, 0, -5, 0, 12, 1'000'000)};
  m.step(1'000'000, ev, out);
  ev = {sample(31, 0, -5, 31, 12, 2'000'000)};
  nccomp::test::AllocationScope scope;
  m.step(2'000'000, ev, out);
  const std::size_t n = m.status(v);
  EXPECT_EQ(scope.count(), 0U);
  ASSERT_EQ(n, 16U);
  EXPECT_EQ(status_value(m, "passed"), 3.0);
  EXPECT_EQ(status_value(m, "checkpoint"), 2.0);
  EXPECT_EQ(status_value(m, "checkpoint_count"), 0.0);
  EXPECT_NEAR(status_value(m, "checkpoint_offset_um"), 0.0, 1e-12);
  // A smaller output span gets the first values only.
  std::array<engine::StatusValue, 3> few{};
  EXPECT_EQ(m.status(few), 3U);
}

TEST(Module, EngineStepAllocatesNothing) {
  auto eng = make_engine(8);
  std::vector<Event> probes;
  for (int i = 0; i < 8; ++i) probes.emplace_back(probe(1, i, 1.0 + i));
  const Event start = part_start(1);
  StepOutput out;
  std::vector<std::byte> buf(eng->state_capacity());
  nccomp::test::AllocationScope scope;
  for (int part = 0; part < 3; ++part) {
    eng->step(0, {&start, 1}, out);
    for (int k = 0; k < 100; ++k) {
      const Event s = sample(k, 0, -5, k, 12, k * 1'000'000);
      eng->step(k * 1'000'000, {&s, 1}, out);
    }
    eng->step(0, probes, out);
    (void)eng->export_state(buf);
  }
  EXPECT_EQ(scope.count(), 0U);
}

}  // namespace
}  // namespace nccomp::core::checkpoint

namespace nccomp::core::checkpoint {
namespace {

// A model's trim of the live register (as the [model] section publishes it).
class LiveTrim final : public engine::Module {
 public:
  explicit LiveTrim(double trim_um) : trim_um_(trim_um) {}
  std::string_view name() const noexcept override { return "model"; }
  void attach(const engine::RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    out.trims.push(OffsetWrite{now_ns, 0, trim_um_});
  }
  std::uint64_t trim_identity() const noexcept override { return 3; }
  double trim_um_;
};

// GIVEN S1 learned errors 6, −4, 2 µm (offsets −6, 4, −2) and part 2 was finished with them
// WHEN a model trimming the live register by −5 µm is handed S1's state before part 2 is probed
// THEN S1 keeps only the residual (−1, 9, 3), part 2's probe (0 µm: the wall was right) changes
// nothing, and part 3 is cut with the same −6, 4, −2 in total (not −11, −1, −7).
TEST(Module, AModelTakingOverTheLiveRegisterLeavesTheTotalAndS1LearnsTheResidual) {
  auto a = make_engine(3);
  StepOutput out;
  TimeNs t = 0;
  std::vector<Event> ev = {probe(1, 0, 6.0), probe(1, 1, -4.0), probe(1, 2, 2.0)};
  a->step(t, ev, out);
  ev = {part_start(2)};
  a->step(t += 1'000'000, ev, out);
  for (double x : {5.0, 15.0, 25.0, 35.0}) {
    ev = {sample(x, 0, -5, x, 12, t += 1'000'000)};
    a->step(t, ev, out);
  }
  std::vector<std::byte> buf(a->state_capacity());
  buf.resize(a->export_state(buf));

  auto b = std::make_unique<engine::Engine>();
  std::vector<std::unique_ptr<engine::Module>> mods;
  mods.push_back(std::make_unique<CheckpointModule>(module_config(), line_plan(3)));
  mods.push_back(std::make_unique<LiveTrim>(-5.0));
  b->configure(registers(3), std::move(mods));
  ASSERT_TRUE(b->import_state(buf, t));
  b->step(t += 1'000'000, {}, out);  // the swap's cycle
  EXPECT_EQ(b->counters().handover_rebases, 1U);
  ev = {probe(2, 0, 0.0), probe(2, 1, 0.0), probe(2, 2, 0.0)};
  b->step(t += 1'000'000, ev, out);
  const auto& s1 = dynamic_cast<const CheckpointModule&>(b->module(0)).compensator();
  EXPECT_NEAR(s1.register_value_um(0), -1.0, 1e-9);
  EXPECT_NEAR(s1.register_value_um(1), 9.0, 1e-9);
  EXPECT_NEAR(s1.register_value_um(2), 3.0, 1e-9);
  EXPECT_NEAR(s1.learned_um(0), 1.0, 1e-9);
  // Part 3: pre-positioned, then past checkpoints 1 and 2: the totals S1 learned before.
  ev = {part_start(3)};
  b->step(t += 1'000'000, ev, out);
  const auto total = [&] {
    const engine::RegisterState r = b->register_state(0);
    return r.target_um + r.trim_um;
  };
  EXPECT_NEAR(total(), -6.0, 1e-9);
  for (const auto& [x, want] : {std::pair{11.0, -6.0}, {21.0, 4.0}, {31.0, -2.0}}) {
    ev = {sample(x, 0, -5, x, 12, t += 1'000'000)};
    b->step(t, ev, out);
    EXPECT_NEAR(total(), want, 1e-9) << x;
  }
}

}  // namespace
}  // namespace nccomp::core::checkpoint
