#include "core/checkpoint/module.hpp"

#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
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
  // The second record's offset becomes NaN (header 24 bytes, records 336 bytes: layout 4).
  ASSERT_EQ(bad.size(), 24U + 2U * 336U);
  const auto nan_bytes = std::bit_cast<std::array<std::byte, sizeof(double)>>(std::nan(""));
  for (std::size_t k = 0; k < nan_bytes.size(); ++k) bad[24 + 336 + 8 + k] = nan_bytes[k];
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

namespace nccomp::core::checkpoint {
namespace {

// A model's path term on the live register: trim = slope × the tool's cut path, re-evaluated
// every cycle (as `update = "cycle"` does).
class PathTrim final : public engine::Module {
 public:
  explicit PathTrim(double slope_um_per_mm) : slope_(slope_um_per_mm) {}
  std::string_view name() const noexcept override { return "model"; }
  void attach(const engine::RegisterTable& /*registers*/) override {}
  void bind_context(const engine::MachineContext& context) override { context_ = &context; }
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    out.trims.push(OffsetWrite{now_ns, 0, slope_ * context_->cut_path_mm()});
  }
  std::uint64_t trim_identity() const noexcept override { return 7; }
  double trim_at_inputs(std::uint16_t register_index,
                        const engine::InputSnapshot& inputs) const noexcept override {
    return register_index == 0 ? slope_ * inputs.path_mm : kNaN;
  }

 private:
  double slope_;
  const engine::MachineContext* context_{nullptr};
};

AxisSample cutting(double x, TimeNs t_ns) {
  AxisSample s = sample(x, 0, -5, x, 12, t_ns);
  s.cutting = true;
  return s;
}

// The wall's error without compensation grows with the tool's cut path p: e = 0.5 µm/mm × p.
constexpr double kWearUmPerMm = 0.5;

// GIVEN S1 alone cut part 1 (checkpoints at 10, 20, 30 mm of cut path) and probed it: it learned
//      e = 5, 10, 15 µm, and the tool is at 40 mm when a model of the wear (trim −0.5 µm/mm × p)
//      is loaded with S1's state
// WHEN the handover rebases S1
// THEN S1 keeps each checkpoint's residual at the path where it was cut (0: the model explains
//      the whole error), not at the 40 mm of the switch (−15, −10, −5), and part 2 is cut with
//      the whole compensation −e(p) at every checkpoint.
TEST(Module, AHandoverTakesTheTrimAtEachCheckpointsOwnCutPath) {
  auto a = make_engine(3);
  StepOutput out;
  TimeNs t = 0;
  std::vector<Event> ev = {part_start(1)};
  a->step(t += 1'000'000, ev, out);
  for (int x = 0; x <= 40; ++x) {
    ev = {cutting(x, t += 1'000'000)};
    a->step(t, ev, out);
  }
  const auto& s1a = dynamic_cast<const CheckpointModule&>(a->module(0)).compensator();
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_DOUBLE_EQ(s1a.point(i).cut_inputs.path_mm, 10.0 * static_cast<double>(i + 1)) << i;
    EXPECT_EQ(s1a.point(i).cut_inputs.tool, 12.0);
  }
  ev = {probe(1, 0, kWearUmPerMm * 10.0), probe(1, 1, kWearUmPerMm * 20.0),
        probe(1, 2, kWearUmPerMm * 30.0)};
  a->step(t += 1'000'000, ev, out);
  ASSERT_NEAR(s1a.register_value_um(2), -15.0, 1e-9);
  std::vector<std::byte> buf(a->state_capacity());
  buf.resize(a->export_state(buf));

  auto b = std::make_unique<engine::Engine>();
  std::vector<std::unique_ptr<engine::Module>> mods;
  mods.push_back(std::make_unique<CheckpointModule>(module_config(), line_plan(3)));
  mods.push_back(std::make_unique<PathTrim>(-kWearUmPerMm));
  b->configure(registers(3), std::move(mods));
  ASSERT_TRUE(b->import_state(buf, t));
  b->step(t += 1'000'000, {}, out);  // the swap's cycle
  ASSERT_EQ(b->counters().handover_rebases, 1U);
  const auto& s1b = dynamic_cast<const CheckpointModule&>(b->module(0)).compensator();
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_NEAR(s1b.learned_um(i), 0.0, 1e-9) << i;
    EXPECT_NEAR(s1b.register_value_um(i), 0.0, 1e-9) << i;
  }
  ev = {part_start(2)};
  b->step(t += 1'000'000, ev, out);
  for (int x = 0; x <= 40; ++x) {
    ev = {cutting(x, t += 1'000'000)};
    b->step(t, ev, out);
    if (x % 10 == 0 && x > 0 && x < 40) {
      const engine::RegisterState r = b->register_state(0);
      const double path_mm = b->context().cut_path_mm(12);
      EXPECT_DOUBLE_EQ(path_mm, 40.0 + x);
      EXPECT_NEAR(r.target_um + r.trim_um, -kWearUmPerMm * path_mm, 1e-9) << x;
    }
  }
}

// The state of `a` (n checkpoints cut along 0…30 mm at 21 °C and probed) in layout 4.
std::vector<std::byte> layout4_state(const engine::Engine& a) {
  const auto& m = dynamic_cast<const CheckpointModule&>(a.module(0));
  std::vector<std::byte> v4(m.state_capacity());
  EXPECT_EQ(m.save_state(v4), v4.size());
  return v4;
}

std::unique_ptr<engine::Engine> cut_and_probe_two() {
  auto a = make_engine(2);
  StepOutput out;
  std::vector<Event> ev = {part_start(1)};
  a->step(1, ev, out);
  for (int x = 0; x <= 30; ++x) {
    ev = {TemperatureSample{2 + x, 0, 21.0}, cutting(x, 2 + x)};
    a->step(2 + x, ev, out);
  }
  ev = {probe(1, 0, 6.0), probe(1, 1, 3.0)};
  a->step(40, ev, out);
  return a;
}

constexpr std::size_t kHeaderBytes = 24;
constexpr std::size_t kV2Record = 176;
constexpr std::size_t kV4Record = 336;

// GIVEN the bytes of a layout-2 state (before the cut inputs)
// THEN they load: the values as saved, the cut inputs unknown (a handover takes the trim at the
//      switch for these checkpoints, as before).
TEST(Module, AStateOfLayoutVersion2IsConverted) {
  auto a = cut_and_probe_two();
  const auto& m = dynamic_cast<const CheckpointModule&>(a->module(0));
  const std::vector<std::byte> v4 = layout4_state(*a);
  ASSERT_EQ(v4.size(), kHeaderBytes + 2 * kV4Record);
  // Layout 2: the same header (version 2) and the first 176 bytes of each record.
  std::vector<std::byte> v2(kHeaderBytes + 2 * kV2Record);
  std::memcpy(v2.data(), v4.data(), kHeaderBytes);
  const std::uint32_t version = 2;
  std::memcpy(v2.data() + 4, &version, sizeof version);
  for (std::size_t i = 0; i < 2; ++i) {
    std::memcpy(v2.data() + kHeaderBytes + i * kV2Record, v4.data() + kHeaderBytes + i * kV4Record,
                kV2Record);
  }
  CheckpointModule fresh(module_config(), line_plan(2));
  fresh.attach(engine::RegisterTable(registers(2)));
  ASSERT_TRUE(fresh.load_state(v2));
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_EQ(fresh.compensator().register_value_um(i), m.compensator().register_value_um(i));
    EXPECT_EQ(fresh.compensator().point(i).history_n, 1U);
    EXPECT_TRUE(std::isnan(fresh.compensator().point(i).cut_inputs.path_mm));
    EXPECT_DOUBLE_EQ(m.compensator().point(i).cut_inputs.path_mm,
                     10.0 * static_cast<double>(i + 1));
  }
  EXPECT_FALSE(fresh.load_state(std::span<const std::byte>(v2.data(), v2.size() - 1)));
}

// GIVEN the bytes of a layout-3 state (the tool and cut path of each checkpoint's last cut)
// THEN they load: the tool and path as saved, the other inputs and the trims unknown (a
//      handover takes them as at the switch for these checkpoints, as before).
TEST(Module, AStateOfLayoutVersion3IsConverted) {
  auto a = cut_and_probe_two();
  const auto& m = dynamic_cast<const CheckpointModule&>(a->module(0));
  const std::vector<std::byte> v4 = layout4_state(*a);
  // Layout 3: each record is the 176 bytes of layout 2, the cut path, the tool and 4 spare bytes.
  constexpr std::size_t kV3Record = 192;
  std::vector<std::byte> v3(kHeaderBytes + 2 * kV3Record);
  std::memcpy(v3.data(), v4.data(), kHeaderBytes);
  const std::uint32_t version = 3;
  std::memcpy(v3.data() + 4, &version, sizeof version);
  for (std::size_t i = 0; i < 2; ++i) {
    std::byte* r = v3.data() + kHeaderBytes + i * kV3Record;
    std::memcpy(r, v4.data() + kHeaderBytes + i * kV4Record, kV2Record);
    const double path_mm = 10.0 * static_cast<double>(i + 1);
    const std::int32_t tool = 12;
    std::memcpy(r + kV2Record, &path_mm, sizeof path_mm);
    std::memcpy(r + kV2Record + 8, &tool, sizeof tool);
  }
  CheckpointModule fresh(module_config(), line_plan(2));
  fresh.attach(engine::RegisterTable(registers(2)));
  ASSERT_TRUE(fresh.load_state(v3));
  for (std::size_t i = 0; i < 2; ++i) {
    const LearnedPoint& p = fresh.compensator().point(i);
    EXPECT_EQ(fresh.compensator().register_value_um(i), m.compensator().register_value_um(i));
    EXPECT_DOUBLE_EQ(p.cut_inputs.path_mm, 10.0 * static_cast<double>(i + 1));
    EXPECT_EQ(p.cut_inputs.tool, 12.0);
    EXPECT_TRUE(std::isnan(p.cut_inputs.time_s));
    EXPECT_TRUE(std::isnan(p.cut_inputs.temp_c));
    EXPECT_TRUE(std::isnan(p.cut_trim_um));
    // Layout 4 kept them: 21 °C, and the trims (none: 0).
    EXPECT_DOUBLE_EQ(m.compensator().point(i).cut_inputs.temp_c, 21.0);
    EXPECT_EQ(m.compensator().point(i).cut_trim_um, 0.0);
  }
  EXPECT_FALSE(fresh.load_state(std::span<const std::byte>(v3.data(), v3.size() - 1)));
}

// GIVEN a layout-4 state whose checkpoint 1 says it was cut at an infinite temperature
// THEN it is refused whole (nothing changes).
TEST(Module, AStateWithAnInfiniteCutInputIsRefused) {
  auto a = cut_and_probe_two();
  std::vector<std::byte> v4 = layout4_state(*a);
  const double inf = std::numeric_limits<double>::infinity();
  // temp_c: the sixth double of the snapshot, after the 176 bytes of layout 2.
  std::memcpy(v4.data() + kHeaderBytes + kV4Record + kV2Record + 5 * 8, &inf, sizeof inf);
  CheckpointModule fresh(module_config(), line_plan(2));
  fresh.attach(engine::RegisterTable(registers(2)));
  EXPECT_FALSE(fresh.load_state(v4));
  EXPECT_EQ(fresh.compensator().point(0).history_n, 0U);
}

}  // namespace
}  // namespace nccomp::core::checkpoint
