// The creep module inside the engine: register checks at attach, targets through the engine's
// limiters, state persisted and restored through the engine's export / import.
#include <gtest/gtest.h>

#include <cstddef>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/creep/creep_module.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using engine::Engine;
using engine::RegisterKind;
using engine::RegisterSpec;

std::vector<RegisterSpec> registers() {
  const LimiterConfig lim{100.0, 50.0, 1e5};
  return {{"X_offset", RegisterKind::kAxisOffset, lim},
          {"Y_offset", RegisterKind::kAxisOffset, lim},
          {"Z_offset", RegisterKind::kAxisOffset, {80.0, 50.0, 1e5}},
          {"T1_length_wear", RegisterKind::kToolLengthWear, lim}};
}

CreepModuleConfig module_config() {
  CreepModuleConfig m;
  m.creep = testing::base_config();
  m.creep.output.warning_register = -1;
  m.creep.output.alarm_register = -1;
  m.creep.output.measurement_due_register = -1;
  m.creep.output.tool_change_register = -1;
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

  explicit EngineRig(const CreepModuleConfig& m) {
    std::vector<std::unique_ptr<engine::Module>> mods;
    mods.push_back(std::make_unique<CreepModule>(m));
    engine.configure(registers(), std::move(mods));
    ev.emplace_back(ToolChange{now, 1, false});
    step();
  }
  void step() {
    engine.step(now, ev, out);
    ev.clear();
    for (const auto& w : out.writes) writes.push_back(w);
  }
  void advance(double ds) {
    now += 10'000'000;
    path += ds;
    AxisSample a;
    a.time_ns = now;
    a.program_path_mm = path;
    a.tool = tool;
    ev.emplace_back(a);
    step();
  }
  void measure(double w) {
    ToolMeasurement m;
    m.tool = 1;
    m.wear_um[0] = w;
    now += 1'000'000;
    ev.emplace_back(m);
    step();
  }
  [[nodiscard]] double last(std::uint16_t reg) const {
    double v = kNaN;
    for (const auto& w : writes) {
      if (w.register_index == reg) v = w.value_um;
    }
    return v;
  }
};

TEST(CreepEngineModule, CreepsThroughTheEngine) {
  EngineRig r(module_config());
  r.advance(0.0);
  r.measure(20.0);
  for (int i = 0; i < 50; ++i) r.advance(0.5);  // 25 of 50 mm
  EXPECT_NEAR(r.last(2), -10.0, 1e-9);
  const auto& comp = dynamic_cast<const CreepModule&>(r.engine.module(0)).compensator();
  // The module took the most restrictive limits of its registers (Z: 80 µm).
  EXPECT_NEAR(comp.config().limiter.max_abs_um, 80.0, 0.0);
}

TEST(CreepEngineModule, StateSurvivesARestartThroughTheEngine) {
  EngineRig a(module_config());
  a.advance(0.0);
  a.measure(20.0);
  for (int i = 0; i < 20; ++i) a.advance(0.5);  // 10 mm
  std::vector<std::byte> buf(a.engine.state_capacity());
  const std::size_t n = a.engine.export_state(buf);
  ASSERT_GT(n, sizeof(CreepState));
  buf.resize(n);

  EngineRig b(module_config());
  std::size_t skipped = 0;
  ASSERT_TRUE(b.engine.import_state(buf, b.now, &skipped));
  EXPECT_EQ(skipped, 0U);
  const auto& comp = dynamic_cast<const CreepModule&>(b.engine.module(0)).compensator();
  EXPECT_NEAR(comp.state().committed_um[0] + comp.applied_wear_um(0), 4.0, 1e-9);
  b.path = 1000.0;  // the program path after restart is wherever the NC is; re-anchored
  b.advance(0.0);
  for (int i = 0; i < 20; ++i) b.advance(0.5);  // 10 mm more: 20 of 50 mm
  EXPECT_NEAR(b.last(2), -8.0, 1e-9);
}

TEST(CreepEngineModule, RememberedToolsSurviveARestart) {
  EngineRig a(module_config());
  a.advance(0.0);
  a.measure(12.0);
  for (int i = 0; i < 200; ++i) a.advance(0.5);
  a.ev.emplace_back(ToolChange{a.now, 2, false});
  a.tool = 2;
  a.advance(0.0);
  a.advance(0.0);
  EXPECT_NEAR(a.last(2), 0.0, 1e-12);  // tool 2 is new
  std::vector<std::byte> buf(a.engine.state_capacity());
  buf.resize(a.engine.export_state(buf));

  EngineRig b(module_config());
  std::size_t skipped = 0;
  ASSERT_TRUE(b.engine.import_state(buf, b.now, &skipped));
  EXPECT_EQ(skipped, 0U);
  const auto& comp = dynamic_cast<const CreepModule&>(b.engine.module(0)).compensator();
  EXPECT_EQ(comp.state().tool, 2);
  EXPECT_EQ(comp.tool_memory().tool[0], 1);
  b.ev.emplace_back(ToolChange{b.now, 1, false});
  b.tool = 1;
  b.advance(0.0);  // the first step re-sends what the NC holds (the rate limit allows no move)
  b.advance(0.0);
  EXPECT_NEAR(b.last(2), -12.0, 1e-9);  // tool 1 is back with its wear
  EXPECT_NEAR(b.engine.register_state(2).output_um, -12.0, 1e-9);
}

TEST(CreepEngineModule, LoadStateRefusesForeignBytes) {
  CreepModule m(module_config());
  std::vector<RegisterSpec> regs = registers();
  m.attach(engine::RegisterTable(regs));
  std::vector<std::byte> bytes(m.state_capacity() - 1);
  EXPECT_FALSE(m.load_state(bytes));
  bytes.assign(m.state_capacity(), std::byte{0});
  EXPECT_FALSE(m.load_state(bytes));  // version 0, edge points 0: not a state
  CreepState s = m.compensator().export_state();
  s.committed_um[0] = kNaN;
  std::memcpy(bytes.data(), &s, sizeof(s));
  EXPECT_FALSE(m.load_state(bytes));
  s.committed_um[0] = 3.0;
  std::memcpy(bytes.data(), &s, sizeof(s));
  // A bool byte that is neither 0 nor 1 (corrupt file) is refused before it is loaded.
  bytes[offsetof(CreepState, halted)] = std::byte{7};
  EXPECT_FALSE(m.load_state(bytes));
  bytes[offsetof(CreepState, halted)] = std::byte{0};
  nccomp::test::AllocationScope scope;
  EXPECT_TRUE(m.load_state(bytes));
  EXPECT_EQ(scope.count(), 0U);
}

TEST(CreepEngineModule, RegistersByName) {
  auto c = module_config();
  c.creep.output.channel_register = {-1, -1, -1, -1, -1};
  c.registers.channel = {"X_offset", "", "Z_offset", "", ""};
  EngineRig r(c);
  r.advance(0.0);
  r.measure(10.0);
  for (int i = 0; i < 100; ++i) r.advance(0.5);
  EXPECT_NEAR(r.last(2), -10.0, 1e-9);
  c.registers.channel[2] = "Z_offst";
  CreepModule typo(c);
  std::vector<RegisterSpec> regs = registers();
  try {
    typo.attach(engine::RegisterTable(regs));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("creep.output.z_register: no register named 'Z_offst'"),
              std::string::npos);
  }
  c.registers.channel = {"", "", "", "", ""};
  CreepModule none(c);
  EXPECT_THROW(none.attach(engine::RegisterTable(regs)), std::invalid_argument);
}

TEST(CreepEngineModule, AttachChecksIndicesAndKinds) {
  std::vector<RegisterSpec> regs = registers();
  auto c = module_config();
  c.creep.output.channel_register = {0, 1, 7, -1, -1};
  CreepModule bad_index(c);
  try {
    bad_index.attach(engine::RegisterTable(regs));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("creep.output.z_register"), std::string::npos);
  }
  c = module_config();
  c.creep.output.channel_register = {0, 1, 3, -1, -1};  // Z on a tool length wear register
  CreepModule bad_kind(c);
  try {
    bad_kind.attach(engine::RegisterTable(regs));
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("T1_length_wear"), std::string::npos);
  }
}

}  // namespace
}  // namespace nccomp::core::creep
