// The creep module inside the engine: register checks at attach, targets through the engine's
// limiters, state persisted and restored through the engine's export / import.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "bench/creep/engine_cycle.hpp"
#include "core/creep/creep_module.hpp"
#include "core/creep/state_v1.hpp"
#include "core/creep/state_v2.hpp"
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
    m.tool = tool;
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
  const AdoptedOutputs nothing_adopted{};
  std::memcpy(bytes.data() + sizeof(CreepState) + sizeof(ToolMemory), &nothing_adopted,
              sizeof(nothing_adopted));
  const std::size_t residual_at = sizeof(CreepState) + sizeof(ToolMemory) + sizeof(AdoptedOutputs);
  CreepModule::ResidualShift residual{};
  residual.shift_um[0] = kNaN;
  std::memcpy(bytes.data() + residual_at, &residual, sizeof(residual));
  EXPECT_FALSE(m.load_state(bytes));  // a residual shift that is not a number
  residual.shift_um[0] = 0.0;
  std::memcpy(bytes.data() + residual_at, &residual, sizeof(residual));
  // A bool byte that is neither 0 nor 1 (corrupt file) is refused before it is loaded.
  bytes[offsetof(CreepState, halted)] = std::byte{7};
  EXPECT_FALSE(m.load_state(bytes));
  bytes[offsetof(CreepState, halted)] = std::byte{0};
  nccomp::test::AllocationScope scope;
  EXPECT_TRUE(m.load_state(bytes));
  EXPECT_EQ(scope.count(), 0U);
}

TEST(CreepEngineModule, AStateOfLayoutVersion1IsConvertedNotDropped) {
  // A daemon upgraded across the state change (version 1 → 2) must resume with its wear: a
  // fresh state would slew the NC's wear offsets back to zero.
  auto mc = module_config();
  mc.creep.interval.removal_mm3_per_mm = 0.5;
  CreepModule m(mc);
  std::vector<RegisterSpec> regs = registers();
  m.attach(engine::RegisterTable(regs));
  v1::CreepState s;
  s.edge_points = 1;
  s.tool = 1;
  s.cut_path_mm = 30.0;
  s.creep_path_mm = 30.0;
  s.committed_um[0] = 2.0;
  s.measured_um[0] = 22.0;
  s.measurements = 2;
  s.last_measurement_cut_path_mm = 20.0;
  s.last_measurement_creep_path_mm = 20.0;
  s.creeps[0].active = true;
  s.creeps[0].seq = 1;
  s.creeps[0].start = 20.0;  // 20 µm over 50 mm, 10 mm done
  s.creeps[0].delta_um[0] = 20.0;
  s.creeps[0].span[0] = 50.0;
  s.channel_output_um[2] = -6.0;
  v1::ToolMemory mem;
  mem.tool[3] = 7;
  mem.last_use[3] = 1;
  mem.use_counter = 1;
  mem.state[3].edge_points = 1;
  mem.state[3].tool = 7;
  mem.state[3].measured_um[0] = 9.0;
  mem.state[3].committed_um[0] = 9.0;
  std::vector<std::byte> bytes(v1::kModuleStateBytes);
  std::memcpy(bytes.data(), &s, sizeof s);
  std::memcpy(bytes.data() + sizeof s, &mem, sizeof mem);
  ASSERT_NE(bytes.size(), m.state_capacity());
  nccomp::test::AllocationScope scope;
  ASSERT_TRUE(m.load_state(bytes));
  EXPECT_EQ(scope.count(), 0U);
  const auto& c = m.compensator();
  EXPECT_EQ(c.state().version, CreepState::kVersion);
  EXPECT_NEAR(c.applied_wear_um(0), 2.0 + 20.0 * 10.0 / 50.0, 1e-12);  // the creep goes on
  EXPECT_FALSE(c.state().creeps[0].eased);
  EXPECT_NEAR(c.state().channel_output_um[2], -6.0, 0.0);
  EXPECT_NEAR(c.removed_mm3(), 15.0, 1e-12);  // what version 1 counted: path × 0.5 mm²
  EXPECT_EQ(c.tool_memory().tool[3], 7);
  EXPECT_NEAR(c.tool_memory().state[3].measured_um[0], 9.0, 0.0);
  // A version-1-sized blob that is not version 1, or has a corrupt bool, is refused.
  CreepModule fresh(mc);
  fresh.attach(engine::RegisterTable(regs));
  bytes[offsetof(v1::CreepState, halted)] = std::byte{3};
  EXPECT_FALSE(fresh.load_state(bytes));
  bytes[offsetof(v1::CreepState, halted)] = std::byte{0};
  bytes[offsetof(v1::CreepState, version)] = std::byte{2};
  EXPECT_FALSE(fresh.load_state(bytes));
  EXPECT_EQ(fresh.compensator().state().measurements, 0U);
}

TEST(CreepEngineModule, AStateOfLayoutVersion2IsConvertedNotDropped) {
  // Version 3 appended the held normal and the request hold; a daemon upgraded across it resumes
  // with its wear, its creeps (eased and carried slopes kept) and its prediction's blend.
  auto mc = module_config();
  mc.creep.interval.basis = IntervalBasis::kPath;
  mc.creep.interval.interval_mm = 100.0;
  CreepModule m(mc);
  std::vector<RegisterSpec> regs = registers();
  m.attach(engine::RegisterTable(regs));
  v2::CreepState s;
  s.edge_points = 1;
  s.tool = 1;
  s.cut_path_mm = 130.0;
  s.creep_path_mm = 130.0;
  s.committed_um[0] = 2.0;
  s.measured_um[0] = 22.0;
  s.rate_um_per_mm[0] = 0.1;
  s.rate_prev_um_per_mm[0] = 0.05;
  s.rate_blend_mm = 4.0;
  s.measurements = 2;
  s.last_measurement_cut_path_mm = 120.0;
  s.last_measurement_creep_path_mm = 120.0;
  s.removed_mm3 = 7.0;
  s.last_measurement_removed_mm3 = 6.0;
  s.creeps[0].active = true;
  s.creeps[0].eased = true;
  s.creeps[0].seq = 1;
  s.creeps[0].start = 120.0;  // 20 µm over 50 mm, 10 mm done, eased
  s.creeps[0].delta_um[0] = 20.0;
  s.creeps[0].span[0] = 50.0;
  s.creeps[0].carry_slope[0] = 0.2;
  s.creeps[0].carry_span[0] = 10.0;
  s.channel_output_um[2] = -6.0;
  v2::ToolMemory mem;
  mem.tool[5] = 7;
  mem.last_use[5] = 1;
  mem.use_counter = 1;
  mem.state[5].edge_points = 1;
  mem.state[5].tool = 7;
  mem.state[5].measured_um[0] = 9.0;
  mem.state[5].committed_um[0] = 9.0;
  std::vector<std::byte> bytes(v2::kModuleStateBytes);
  std::memcpy(bytes.data(), &s, sizeof s);
  std::memcpy(bytes.data() + sizeof s, &mem, sizeof mem);
  ASSERT_NE(bytes.size(), m.state_capacity());
  ASSERT_NE(bytes.size(), v1::kModuleStateBytes);
  nccomp::test::AllocationScope scope;
  ASSERT_TRUE(m.load_state(bytes));
  EXPECT_EQ(scope.count(), 0U);
  const auto& c = m.compensator();
  const auto& st = c.state();
  EXPECT_EQ(st.version, CreepState::kVersion);
  EXPECT_TRUE(st.creeps[0].eased);
  EXPECT_NEAR(st.creeps[0].carry_slope[0], 0.2, 0.0);
  EXPECT_NEAR(st.creeps[0].carry_span[0], 10.0, 0.0);
  EXPECT_NEAR(st.rate_blend_mm, 4.0, 0.0);
  EXPECT_NEAR(st.rate_prev_um_per_mm[0], 0.05, 0.0);
  EXPECT_NEAR(c.removed_mm3(), 7.0, 0.0);
  EXPECT_NEAR(st.channel_output_um[2], -6.0, 0.0);
  EXPECT_FALSE(st.normal_held);
  EXPECT_FALSE(st.request_held);
  EXPECT_NEAR(c.next_measurement_path_mm(), 220.0, 1e-12);
  EXPECT_EQ(c.tool_memory().tool[5], 7);
  EXPECT_NEAR(c.tool_memory().state[5].measured_um[0], 9.0, 0.0);
  EXPECT_EQ(c.tool_memory().state[5].version, CreepState::kVersion);
  // A version-2-sized blob that is not version 2, or has a corrupt bool, is refused.
  CreepModule fresh(mc);
  fresh.attach(engine::RegisterTable(regs));
  bytes[offsetof(v2::CreepState, tool_change_flag)] = std::byte{2};
  EXPECT_FALSE(fresh.load_state(bytes));
  bytes[offsetof(v2::CreepState, tool_change_flag)] = std::byte{0};
  bytes[offsetof(v2::CreepState, version)] = std::byte{3};
  EXPECT_FALSE(fresh.load_state(bytes));
  EXPECT_EQ(fresh.compensator().state().measurements, 0U);
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

// ---- status --------------------------------------------------------------------------------

double status_value(const CreepModule& m, std::string_view key) {
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  const std::size_t n = m.status(v);
  for (std::size_t i = 0; i < n; ++i) {
    if (key == v[i].key) return v[i].value;
  }
  return kNaN;
}

std::vector<std::string> status_keys(const CreepModule& m) {
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  const std::size_t n = m.status(v);
  std::vector<std::string> keys;
  for (std::size_t i = 0; i < n; ++i) keys.emplace_back(v[i].key);
  return keys;
}

TEST(CreepEngineModule, StatusShowsTheWearOfEveryRememberedTool) {
  EngineRig r(module_config());
  const auto& m = dynamic_cast<const CreepModule&>(r.engine.module(0));
  const auto use = [&](std::int32_t tool, double wear) {
    r.ev.emplace_back(ToolChange{r.now, tool, false});
    r.tool = tool;
    r.advance(0.0);
    r.measure(wear);
    for (int i = 0; i < 120; ++i) r.advance(0.5);  // 60 mm: the 50 mm creep is done
  };
  r.advance(0.0);
  r.measure(12.0);
  for (int i = 0; i < 120; ++i) r.advance(0.5);
  // The spindle tool's wear in force is what was measured once its creep is done (not twice it).
  EXPECT_NEAR(status_value(m, "wear_in_force_um"), 12.0, 1e-9);
  EXPECT_NEAR(status_value(m, "creep_remaining_um"), 0.0, 1e-9);
  use(2, 5.0);
  use(3, 7.5);
  EXPECT_NEAR(status_value(m, "tool"), 3.0, 0.0);
  EXPECT_NEAR(status_value(m, "wear_measured_um"), 7.5, 0.0);
  EXPECT_NEAR(status_value(m, "T1_wear_um"), 12.0, 0.0);
  EXPECT_NEAR(status_value(m, "T2_wear_um"), 5.0, 0.0);
  EXPECT_TRUE(std::isnan(status_value(m, "T3_wear_um")));  // in the spindle: the values above
  // All fifteen values, then the remembered tools, the most recently used first.
  const std::vector<std::string> first{"mode",
                                       "tool",
                                       "wear_in_force_um",
                                       "wear_measured_um",
                                       "creep_remaining_um",
                                       "creeps_in_progress",
                                       "correction_um",
                                       "cut_path_mm",
                                       "wear_rate_um_per_mm",
                                       "halted",
                                       "latched_alarm",
                                       "acknowledged",
                                       "last_acknowledge",
                                       "measurements_accepted",
                                       "measurements_refused",
                                       "T2_wear_um",
                                       "T1_wear_um"};
  EXPECT_EQ(status_keys(m), first);
  // Eight remembered tools (one beyond 9999): every one is shown; three counters make room.
  use(4, 1.0);
  use(5, 2.0);
  use(6, 3.0);
  use(12345, 4.0);
  use(8, 6.0);
  use(9, 6.5);
  const auto keys = status_keys(m);
  ASSERT_EQ(keys.size(), engine::kMaxStatusValues);
  const std::vector<std::string> tail(keys.begin() + 8, keys.end());
  EXPECT_EQ(tail, (std::vector<std::string>{
                      "halted", "latched_alarm", "acknowledged", "last_acknowledge", "T8_wear_um",
                      "memory_slot_7_wear_um", "T6_wear_um", "T5_wear_um", "T4_wear_um",
                      "T3_wear_um", "T2_wear_um", "T1_wear_um"}))
      << "memory slot of 12345: " << keys[13];
  EXPECT_NEAR(status_value(m, "T1_wear_um"), 12.0, 0.0);
  EXPECT_NEAR(status_value(m, "T6_wear_um"), 3.0, 0.0);
  EXPECT_EQ(keys[7], "cut_path_mm");
  EXPECT_TRUE(std::isnan(status_value(m, "measurements_refused")));
  EXPECT_TRUE(std::isnan(status_value(m, "measurements_accepted")));
  EXPECT_TRUE(std::isnan(status_value(m, "wear_rate_um_per_mm")));
  // Real-time safe: no allocation.
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  nccomp::test::AllocationScope scope;
  EXPECT_EQ(m.status(v), engine::kMaxStatusValues);
  EXPECT_EQ(scope.count(), 0U);
}

TEST(CreepEngineModule, WithTheEstimatorEveryRememberedToolStillFitsInTheStatus) {
  // The estimator's five values make 20 of the spindle tool's own: each remembered tool makes
  // room for itself, the counters first, then the estimator's values from the last.
  CreepModuleConfig c = module_config();
  c.creep.estimator.enabled = true;
  c.creep.estimator.gate_sigmas = 0.0;  // the first measurements jump from 0 µm
  EngineRig r(c);
  const auto& m = dynamic_cast<const CreepModule&>(r.engine.module(0));
  r.advance(0.0);
  r.measure(12.0);
  auto keys = status_keys(m);
  ASSERT_EQ(keys.size(), engine::kMaxStatusValues);
  EXPECT_EQ(std::vector<std::string>(keys.end() - 5, keys.end()),
            (std::vector<std::string>{"wear_estimate_um", "wear_sigma_um", "nis_mean",
                                      "measurement_sigma_estimate_um",
                                      "rate_noise_um_per_mm_per_sqrt_m"}));
  EXPECT_NEAR(status_value(m, "nis_mean"), m.compensator().nis_mean(0), 0.0);
  // After the first measurement from the prior diag(1, 1e-4) at 0 mm: S = 2, ν = 12.
  EXPECT_NEAR(status_value(m, "nis_mean"), 144.0 / 2.0, 1e-9);
  EXPECT_NEAR(status_value(m, "rate_noise_um_per_mm_per_sqrt_m"), 0.0005, 1e-12);
  std::int32_t tool = 1;
  for (const std::int32_t t : {2, 3, 4, 5, 6, 7, 8, 9}) {
    r.ev.emplace_back(ToolChange{r.now, t, false});
    r.tool = t;
    r.advance(0.0);
    r.measure(1.0 + t);
    tool = t;
  }
  keys = status_keys(m);
  ASSERT_EQ(keys.size(), engine::kMaxStatusValues);
  for (const std::int32_t t : {1, 2, 3, 4, 5, 6, 7, 8}) {
    EXPECT_NEAR(status_value(m, "T" + std::to_string(t) + "_wear_um"), t == 1 ? 12.0 : 1.0 + t, 0.0)
        << t;
  }
  EXPECT_EQ(tool, 9);
  // 15 + 5 + 8 = 28 values: the first 8 of the yield list make room, wear_estimate_um stays.
  for (const char* gone : {"measurements_refused", "measurements_accepted", "wear_rate_um_per_mm",
                           "cut_path_mm", "rate_noise_um_per_mm_per_sqrt_m",
                           "measurement_sigma_estimate_um", "nis_mean", "wear_sigma_um"}) {
    EXPECT_TRUE(std::find(keys.begin(), keys.end(), gone) == keys.end()) << gone;
  }
  EXPECT_TRUE(std::find(keys.begin(), keys.end(), "wear_estimate_um") != keys.end());
}

// ---- real time: the engine's step with the creep module ---------------------------------------

TEST(CreepRealTime, EngineStepWithTheCreepModuleAllocatesNothing) {
  // The cycle bench_creep_cost times: Engine::step() with the creep module, 3 axes, 16 support
  // points, 4 creeps in progress; plus measurements (each folds the oldest creep), two tool
  // changes (the tool memory saves and restores a state with 4 creeps), the status and the state
  // export the loop thread also calls.
  auto rig = std::make_unique<bench::creep::EngineCycle>();
  ASSERT_EQ(rig->creeps_in_progress(), 4U);
  const auto& k = rig->module().compensator().counters();
  const auto accepted = k.measurements_accepted;
  const auto folded = k.creeps_folded;
  std::array<engine::StatusValue, engine::kMaxStatusValues> status{};
  std::vector<std::byte> state(rig->engine().state_capacity());
  std::size_t writes = 0;
  nccomp::test::AllocationScope scope;
  for (int i = 0; i < 2000; ++i) {
    if (i == 1000) {
      rig->change_tool(2);
    } else if (i == 1500) {
      rig->change_tool(1);
    } else if (i % 50 == 25) {
      rig->measure(rig->next_wear_base_um());
    } else {
      rig->cycle();
    }
    writes += rig->out().writes.size();
    (void)rig->module().status(status);
    if (i % 100 == 0) (void)rig->engine().export_state(state);
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(rig->creeps_in_progress(), 4U);  // tool 1 is back with its 4 creeps
  EXPECT_EQ(k.measurements_accepted - accepted, 40U);
  EXPECT_GE(k.creeps_folded - folded, 30U);
  EXPECT_GT(writes, 1000U);  // the offsets really move and are written
  EXPECT_FALSE(rig->module().compensator().halted());
}

}  // namespace
}  // namespace nccomp::core::creep
