// The cycle that issue 3 asks to be costed: the engine (core::engine::Engine, what the loop thread
// steps as `core.step()`) with the creep module attached, 3 axes, 16 edge support points and 4
// creeps in progress, one axis sample with a surface normal per cycle at 1 kHz, prediction,
// deflection table and adaptive interval on. bench_creep_cost times it; the unit test
// CreepRealTime.EngineStepWithTheCreepModuleAllocatesNothing counts its allocations: both run
// this very code.
#pragma once

#include <cmath>
#include <cstddef>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/common/output.hpp"
#include "core/creep/creep_module.hpp"
#include "core/engine/engine.hpp"

namespace nccomp::bench::creep {

/// estimator: [creep.estimator] on as well, its rate noise adapted at every measurement (gate
/// off, so that every measurement of the cycle, whose first ones jump, takes the accepted path
/// with the filter's update).
inline core::creep::CreepModuleConfig engine_cycle_module_config(bool estimator = false) {
  using namespace nccomp::core;
  using namespace nccomp::core::creep;
  CreepModuleConfig m;
  CreepConfig& c = m.creep;
  c.creep_basis = CreepBasis::kPath;
  c.creep_length_mm = 1e6;  // the 4 creeps stay in progress for the whole run
  c.profile = ProfileShape::kCosine;
  c.max_creeps = 4;
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 16;
  c.edge.normal_source = NormalSource::kAxisSample;
  c.output.mode = OutputMode::kAxes;
  c.output.channel_register = {-1, -1, -1, -1, -1};
  c.interval.basis = IntervalBasis::kAdaptive;
  c.predict.enabled = true;
  c.estimator.enabled = estimator;
  c.estimator.gate_sigmas = 0.0;
  c.estimator.adapt_rate_noise = estimator;
  c.deflection = {{0, {0.0, 20.0, 50.0}, {0.0, 2.0, 6.0}, {0.0, 1.0, 4.0}}};
  c.tool_life.min_expected_increment_um = 100.0;
  m.registers.channel = {"X_wear", "Y_wear", "Z_wear", "", ""};
  m.registers.warning = "creep_warning";
  m.registers.alarm = "creep_alarm";
  m.registers.measurement_due = "measure_request";
  m.registers.tool_change = "sister_request";
  return m;
}

inline std::vector<core::engine::RegisterSpec> engine_cycle_registers() {
  using core::engine::RegisterKind;
  const core::LimiterConfig offset{500.0, 50.0, 1e4};
  const core::LimiterConfig flag{10.0, 10.0, 1e6};
  return {
      {"X_wear", RegisterKind::kAxisOffset, offset}, {"Y_wear", RegisterKind::kAxisOffset, offset},
      {"Z_wear", RegisterKind::kAxisOffset, offset}, {"creep_warning", RegisterKind::kFlag, flag},
      {"creep_alarm", RegisterKind::kFlag, flag},    {"measure_request", RegisterKind::kFlag, flag},
      {"sister_request", RegisterKind::kFlag, flag}};
}

class EngineCycle {
 public:
  /// Not real-time: configures the engine (through_engine) or only the module (its peer in the
  /// cost benchmark: CreepModule::step() without the engine's validation, limiters and write
  /// batching), and brings 4 creeps into progress (throws if not).
  explicit EngineCycle(bool through_engine = true, bool estimator = false)
      : through_engine_(through_engine) {
    auto m = std::make_unique<core::creep::CreepModule>(engine_cycle_module_config(estimator));
    module_ = m.get();
    if (through_engine_) {
      std::vector<std::unique_ptr<core::engine::Module>> mods;
      mods.push_back(std::move(m));
      engine_.configure(engine_cycle_registers(), std::move(mods));
    } else {
      specs_ = engine_cycle_registers();
      m->attach(core::engine::RegisterTable(specs_));
      alone_ = std::move(m);
    }
    events_.reserve(8);
    sample_.has_normal = true;
    sample_.tool = 1;
    events_.emplace_back(core::ToolChange{now_ns_, 1, false});
    run(events_);
    for (int k = 0; k < 4; ++k) {
      for (int i = 0; i < 200; ++i) cycle();
      measure(3.0 * (k + 1) * (k + 1));
    }
    if (creeps_in_progress() != 4) {
      throw std::runtime_error("engine cycle setup: " + std::to_string(creeps_in_progress()) +
                               " creeps in progress, expected 4");
    }
  }

  /// One loop cycle: 1 ms later, 0.026 mm further along the path (1555 mm/min), the surface
  /// normal turning slowly in XZ. Real-time part: engine_.step().
  void cycle() { step(false, 0.0); }
  /// The same cycle carrying a 16-point laser measurement (a new creep folds the oldest of 4).
  void measure(double wear_base_um) { step(true, wear_base_um); }
  /// A tool change to `tool` in the same cycle as an axis sample naming it.
  void change_tool(std::int32_t tool) {
    sample_.tool = tool;
    events_.clear();
    events_.emplace_back(core::ToolChange{now_ns_, tool, false});
    step_with_events(false, 0.0);
  }

  [[nodiscard]] std::size_t creeps_in_progress() const noexcept {
    return module_->compensator().creeps_in_progress();
  }
  [[nodiscard]] const core::creep::CreepModule& module() const noexcept { return *module_; }
  [[nodiscard]] core::engine::Engine& engine() noexcept { return engine_; }
  [[nodiscard]] const core::StepOutput& out() const noexcept { return out_; }
  /// The next measurement's wear at point 0: 0.1 or 0.3 µm more, in turn, so that it never
  /// equals what the fitted rate predicts (that would start no creep and fold none).
  [[nodiscard]] double next_wear_base_um() noexcept {
    return module_->compensator().state().measured_um[0] + ((++measurements_ % 2) ? 0.1 : 0.3);
  }

 private:
  void step(bool with_measurement, double wear_base_um) {
    events_.clear();
    step_with_events(with_measurement, wear_base_um);
  }
  void step_with_events(bool with_measurement, double wear_base_um) {
    now_ns_ += 1'000'000;
    path_mm_ += 0.026;
    const double ang = 0.001 * path_mm_;
    sample_.time_ns = now_ns_;
    sample_.program_path_mm = path_mm_;
    sample_.position_mm = {path_mm_, 0.5 * path_mm_, 0.0, 0.0, 0.0, 0.0};
    sample_.normal = {std::sin(ang), 0.0, std::cos(ang)};
    events_.emplace_back(sample_);
    if (with_measurement) {
      core::ToolMeasurement m;
      m.time_ns = now_ns_;
      m.tool = sample_.tool;
      m.point_count = 16;
      for (std::size_t i = 0; i < 16; ++i) {
        m.wear_um[i] = wear_base_um + 0.2 * static_cast<double>(i);
      }
      events_.emplace_back(m);
    }
    run(events_);
  }
  void run(const std::vector<core::Event>& events) {
    if (through_engine_) {
      engine_.step(now_ns_, events, out_);
    } else {
      out_.clear();
      alone_->step(now_ns_, events, out_);
    }
  }

  bool through_engine_{true};
  core::engine::Engine engine_;
  std::vector<core::engine::RegisterSpec> specs_;
  std::unique_ptr<core::creep::CreepModule> alone_;
  const core::creep::CreepModule* module_{nullptr};
  core::StepOutput out_{};
  std::vector<core::Event> events_;
  core::TimeNs now_ns_{0};
  double path_mm_{0.0};
  unsigned measurements_{0};
  core::AxisSample sample_{};
};

}  // namespace nccomp::bench::creep
