// Trims a tool measurement sees (core/engine/engine.hpp, "Trims"): a module whose trims include
// a prediction of the tool's wear (a model's terms of kind tool_wear) is a ToolWearTrimSource;
// a module that learns the wear from the tool measurement (S0) is a ToolWearTrimUser and learns
// only the residual of those trims, so the wear is not compensated twice. S1 is a user too: it
// keeps the trims each checkpoint was cut with. The engine connects them at configure().
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

namespace nccomp::core::engine {

class ToolWearTrimSource {
 public:
  virtual ~ToolWearTrimSource() = default;
  /// Real-time safe. The part of this module's trim in force on register_index (the last one the
  /// engine accepted, see trim_in_force()) that predicts what a tool measurement sees [µm] (0:
  /// none). A trim the engine refused (beyond the register's limit: alarm) is not in force, so
  /// the learning module must not take it out of what it measured.
  [[nodiscard]] virtual double tool_wear_trim_um(std::uint16_t register_index) const noexcept = 0;
  /// Real-time safe. Called by the engine in step() when it accepts the trim this module
  /// published on register_index in the same step.
  virtual void trim_in_force(std::uint16_t register_index) noexcept = 0;
  /// Real-time safe. This module's whole trim in force on register_index [µm], what a part is
  /// cut with (S1 keeps it per checkpoint for a later trim handover); NaN: not known.
  [[nodiscard]] virtual double trim_in_force_um(std::uint16_t register_index) const noexcept {
    (void)register_index;
    return std::numeric_limits<double>::quiet_NaN();
  }
};

class ToolWearTrimUser {
 public:
  virtual ~ToolWearTrimUser() = default;
  /// Not real-time (configure(), after attach()): the engine's other modules that are sources;
  /// they live as long as the engine.
  virtual void bind_tool_wear_trims(std::vector<const ToolWearTrimSource*> sources) = 0;
};

}  // namespace nccomp::core::engine
