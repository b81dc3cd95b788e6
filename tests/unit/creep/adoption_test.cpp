// The creep module started without a usable state (CreepModule::adopt_output(), docs/daemon.md
// "Start-up: ..."): GIVEN the NC holds -33 µm in the fallback channel's register (Z, sign -1)
// and 5 µm in the X register, WHEN the engine offers them to the fresh module, THEN nothing is
// written (the registers keep what the NC holds), the wear in force is 33 µm (the baseline),
// and the next measurement (40 µm) creeps Z from -33 to -40 (an increment of 7 µm, not
// excessive) while X fades from 5 to what the module computes (0) along the same creep; the
// adoption survives a restart before that measurement; another tool ends it; a state written
// before adoption existed still loads.
#include <gtest/gtest.h>

#include <cmath>
#include <cstddef>
#include <memory>
#include <utility>
#include <vector>

#include "core/creep/creep_module.hpp"
#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using engine::Engine;
using engine::RegisterKind;
using engine::RegisterSpec;
using engine::StartupAdoption;

std::vector<RegisterSpec> registers() {
  const LimiterConfig lim{100.0, 50.0, 1e5};
  return {{"X_offset", RegisterKind::kAxisOffset, lim},
          {"Y_offset", RegisterKind::kAxisOffset, lim},
          {"Z_offset", RegisterKind::kAxisOffset, lim}};
}

CreepModuleConfig module_config() {
  CreepModuleConfig m;
  m.creep = testing::base_config();  // axes, Z fallback sign -1, 50 mm linear creeps
  m.creep.output.warning_register = -1;
  m.creep.output.alarm_register = -1;
  m.creep.output.measurement_due_register = -1;
  m.creep.output.tool_change_register = -1;
  m.creep.tool_life.excessive_increment_um = 15.0;
  m.creep.tool_life.min_expected_increment_um = 10.0;
  return m;
}

struct Rig {
  Engine engine;
  StepOutput out;
  std::vector<Event> ev;
  TimeNs now{0};
  double path{0.0};
  std::int32_t tool{1};
  std::vector<OffsetWrite> writes;
  std::vector<AlarmEvent> alarms;

  Rig() {
    std::vector<std::unique_ptr<engine::Module>> mods;
    mods.push_back(std::make_unique<CreepModule>(module_config()));
    engine.configure(registers(), std::move(mods));
  }
  /// The daemon's start-up: the NC's values read back, anchored, offered to the module.
  void start(double x_um, double z_um) {
    using P = std::pair<std::size_t, double>;
    for (const auto& [reg, v] : {P{0, x_um}, P{1, 0.0}, P{2, z_um}}) {
      ASSERT_TRUE(engine.anchor_register(reg, v, now).anchored);
      ASSERT_EQ(engine.adopt_without_state(reg, v, true, now), StartupAdoption::kAdopted) << reg;
    }
  }
  void step() {
    engine.step(now, ev, out);
    ev.clear();
    for (const auto& w : out.writes) writes.push_back(w);
    for (const auto& a : out.alarms) alarms.push_back(a);
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
  [[nodiscard]] std::vector<double> written(std::uint16_t reg, std::size_t from = 0) const {
    std::vector<double> v;
    for (std::size_t k = from; k < writes.size(); ++k) {
      if (writes[k].register_index == reg) v.push_back(writes[k].value_um);
    }
    return v;
  }
  [[nodiscard]] const CreepModule& module() const {
    return dynamic_cast<const CreepModule&>(engine.module(0));
  }
};

TEST(CreepAdoption, TheNcsValuesStayUntilTheNextMeasurementWhichCreepsAndFadesFromThem) {
  Rig r;
  r.start(5.0, -33.0);
  for (int i = 0; i < 100; ++i) r.advance(0.5);  // 50 mm of cutting: no write at all
  EXPECT_TRUE(r.writes.empty()) << r.writes.front().register_index;
  EXPECT_DOUBLE_EQ(r.module().compensator().applied_wear_um(0), 33.0);
  EXPECT_DOUBLE_EQ(r.engine.register_state(0).target_um, 5.0);
  EXPECT_DOUBLE_EQ(r.engine.register_state(2).target_um, -33.0);

  r.measure(40.0);
  for (int i = 0; i < 50; ++i) r.advance(0.5);  // 25 of 50 mm
  // Z: 33 + 7 · 0.5; X: 5 · (1 - 0.5) (linear profile).
  EXPECT_NEAR(r.engine.register_state(2).output_um, -36.5, 1e-9);
  EXPECT_NEAR(r.engine.register_state(0).output_um, 2.5, 1e-9);
  for (int i = 0; i < 60; ++i) r.advance(0.5);
  EXPECT_NEAR(r.engine.register_state(2).output_um, -40.0, 1e-9);
  EXPECT_NEAR(r.engine.register_state(0).output_um, 0.0, 1e-9);
  double prev = -33.0;
  for (double v : r.written(2)) {
    EXPECT_LE(v, prev + 1e-9);  // only ever further into the wear, never back toward 0
    EXPECT_GE(v, -40.0 - 1e-9);
    prev = v;
  }
  EXPECT_GT(r.written(2).size(), 20U);  // crept, not stepped
  for (const auto& a : r.alarms) {
    EXPECT_NE(a.code, AlarmCode::kToolExcessivelyWorn);  // 7 µm from the baseline, not 40
  }
  EXPECT_EQ(r.module().compensator().counters().measurements_accepted, 1U);
  EXPECT_FALSE(r.module().compensator().adoption_active());
}

TEST(CreepAdoption, TheAdoptionSurvivesARestartBeforeTheNextMeasurement) {
  Rig a;
  a.start(5.0, -33.0);
  for (int i = 0; i < 10; ++i) a.advance(0.5);
  std::vector<std::byte> buf(a.engine.state_capacity());
  buf.resize(a.engine.export_state(buf));

  Rig b;
  ASSERT_TRUE(b.engine.import_state(buf, b.now));
  EXPECT_EQ(b.engine.module_state(0), engine::ModuleStateSource::kRestored);
  for (int i = 0; i < 40; ++i) b.advance(0.5);
  for (const auto& w : b.writes) {
    EXPECT_DOUBLE_EQ(w.value_um, w.register_index == 0   ? 5.0
                                 : w.register_index == 2 ? -33.0
                                                         : 0.0)
        << w.register_index;
  }
  b.measure(40.0);
  for (int i = 0; i < 50; ++i) b.advance(0.5);
  EXPECT_NEAR(b.engine.register_state(0).output_um, 2.5, 1e-9);
  EXPECT_NEAR(b.engine.register_state(2).output_um, -36.5, 1e-9);
}

TEST(CreepAdoption, AnotherToolEndsTheAdoption) {
  Rig r;
  r.start(5.0, -33.0);
  r.advance(0.5);
  r.ev.emplace_back(ToolChange{r.now, 2, false});
  r.tool = 2;
  r.step();
  for (int i = 0; i < 5; ++i) r.advance(0.0);
  // Tool 2 is new: its offsets are 0 (tool 1's were what the NC held).
  EXPECT_NEAR(r.engine.register_state(0).output_um, 0.0, 1e-12);
  EXPECT_NEAR(r.engine.register_state(2).output_um, 0.0, 1e-12);
  EXPECT_FALSE(r.module().compensator().adoption_active());
}

TEST(CreepAdoption, AStateWrittenBeforeAdoptionExistedStillLoads) {
  CreepModule m(module_config());
  m.attach(engine::RegisterTable(registers()));
  std::vector<std::byte> bytes(m.state_capacity());
  ASSERT_EQ(m.save_state(bytes), m.state_capacity());
  bytes.resize(sizeof(CreepState) + sizeof(ToolMemory));
  CreepModule n(module_config());
  n.attach(engine::RegisterTable(registers()));
  EXPECT_TRUE(n.load_state(bytes));
  EXPECT_FALSE(n.compensator().adoption_active());
  // A corrupt adoption part is refused (the whole state, as for any other part).
  std::vector<std::byte> full(m.state_capacity());
  ASSERT_EQ(m.save_state(full), full.size());
  full[sizeof(CreepState) + sizeof(ToolMemory) + 4] = std::byte{7};  // held[0] = 7
  EXPECT_FALSE(n.load_state(full));
}

}  // namespace
}  // namespace nccomp::core::creep
