// The daemon's `[measurement_context]` section (docs/config.md): the options of the engine's
// machine context (core/engine/context.hpp) that stamps every measurement record and that the
// [model] section evaluates with: which temperature sensor is the log's temp_c, and how long
// the machine must stand still to be cold (its next motion is a warm start, the origin of the
// log's time_s). Optional: without it the defaults apply (sensor 0, 7200 s). Its engine module
// carries the options and shows the context in `nccomp status`.
#pragma once

#include <memory>

#include "core/engine/context.hpp"
#include "core/engine/engine.hpp"
#include "daemon/config/config.hpp"

namespace nccomp::daemon::sections {

struct MeasurementContextSection final : config::Section {
  core::engine::ContextOptions options;
  formats::Where where;
};

/// The options in force for a config: its [measurement_context] section, or the defaults.
core::engine::ContextOptions measurement_context_options(const config::Config& config);
/// Where the temperature sensor is set (for errors that refer to it); empty if defaulted.
formats::Where measurement_context_where(const config::Config& config);

/// The module that hands the options to the engine and reports the context's status:
/// machine_time_s, idle_s, warm_starts, cold (1/0), tool, cut_path_mm, temp_c.
class MeasurementContextModule final : public core::engine::Module {
 public:
  explicit MeasurementContextModule(core::engine::ContextOptions options) : options_(options) {}
  std::string_view name() const noexcept override { return "measurement_context"; }
  void attach(const core::engine::RegisterTable&) override {}
  void step(core::TimeNs, std::span<const core::Event>, core::StepOutput&) noexcept override {}
  const core::engine::ContextOptions* context_options() const noexcept override {
    return &options_;
  }
  void bind_context(const core::engine::MachineContext& context) override { context_ = &context; }
  std::size_t status(std::span<core::engine::StatusValue> out) const noexcept override;

 private:
  core::engine::ContextOptions options_;
  const core::engine::MachineContext* context_{nullptr};
};

}  // namespace nccomp::daemon::sections
