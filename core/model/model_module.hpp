// The engine module of the daemon's [model] section (docs/config.md, docs/closing-the-loop.md):
// evaluates chosen terms of the model `nccomp analyze` fitted (model.toml) at the machine context
// and publishes each as an additive trim on a register (core/engine/engine.hpp, "Trims"), on top
// of what the register's own module (e.g. S1 checkpoints) writes. It writes no target of its
// own, so it never fights the module that owns the register.
//
// The context is the engine's MachineContext (core/engine/context.hpp), the same one every
// measurement record is stamped with: time since the warm start, part, tool, temp_c, machine
// position, the cut path per tool, and the last value of every temperature sensor (extra model
// columns mapped with [[model.inputs]]). So a term is evaluated on exactly the columns it was
// fitted on. A module not attached to an engine (unit tests) follows its own context.
//
// A session term (session_offset, form "session") is learned: at a warm start (a new session)
// its offset starts at 0, the prior mean, and each measurement record of the session the term
// applies to moves it to the posterior mean of the session's offset (Model::observe(), with the
// model's between-session and noise sigma). What it has learned is the module's state, so a
// restart within the session continues it.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/engine/context.hpp"
#include "core/engine/engine.hpp"
#include "core/engine/tool_wear_trims.hpp"
#include "core/model/model.hpp"

namespace nccomp::core::model {

/// One fitted term mapped onto one register: trim_um = gain × term(context). Entries on the
/// same register add up.
struct ModelApply {
  std::size_t term_index{0};
  std::uint16_t register_index{0};
  double gain{-1.0};
  /// Context columns fixed by the entry (kind, point, tool, angle); NaN = from the loop /
  /// unknown. A fixed tool also selects that tool's cut path.
  double kind{1.0};
  double point{kUnknown};
  double tool{kUnknown};
  double angle_deg{kUnknown};
};

/// An extra model column fed from a TemperatureSample sensor (any scalar the bus map publishes
/// on a sensor channel: an ambient temperature, a second structure temperature, …).
struct ModelInput {
  int column{-1};  // Row index (≥ kStandardColumns)
  int sensor{0};
};

class ModelModule final : public core::engine::Module, public core::engine::ToolWearTrimSource {
 public:
  /// update_each_cycle: re-evaluate every cycle (time / temperature / position / path terms);
  /// otherwise at start-up, part start, tool change and warm start only (the trim is constant
  /// over a part).
  ModelModule(Model model, std::vector<ModelApply> applies, bool update_each_cycle,
              std::vector<ModelInput> inputs = {});
  ModelModule(const ModelModule&) = delete;
  ModelModule& operator=(const ModelModule&) = delete;

  std::string_view name() const noexcept override { return "model"; }
  /// Real-time safe. The sum of the trims in force (the last the engine accepted) of the entries
  /// on register_index whose kind is tool_wear (the laser's rows: it measures the wear they
  /// predict).
  [[nodiscard]] double tool_wear_trim_um(std::uint16_t register_index) const noexcept override;
  /// Real-time safe: the engine accepted this step's trim on register_index.
  void trim_in_force(std::uint16_t register_index) noexcept override;
  /// Checks the register indices (offset registers only: a trim on a flag makes no sense).
  void attach(const core::engine::RegisterTable& registers) override;
  void bind_context(const core::engine::MachineContext& context) override;
  /// Real-time safe: fixed-size Row, evaluation state sized in the constructor.
  void step(core::TimeNs now_ns, std::span<const core::Event> events,
            core::StepOutput& out) noexcept override;
  /// Real-time safe: learns the session term's offset from the record (no-op without one).
  void observe_record(const core::MeasurementRecord& record) noexcept override;
  /// The state is what the session term has learned of the current session (the context is
  /// saved by the engine). A state of an earlier version (part, tool, flags[, cut path]) is
  /// still read: its part stands in until the first part start.
  [[nodiscard]] std::size_t state_capacity() const noexcept override;
  std::size_t save_state(std::span<std::byte> buf) const noexcept override;
  bool load_state(std::span<const std::byte> bytes) noexcept override;
  [[nodiscard]] std::uint64_t state_generation() const noexcept override { return generation_; }
  std::size_t status(std::span<core::engine::StatusValue> out) const noexcept override;

  /// A hash of the model's terms and coefficients, the apply entries and the inputs: a reload
  /// or restart with another model hands the trims over (core/engine/engine.hpp, "Trim
  /// handover"), the same model does not. Real-time safe.
  [[nodiscard]] std::uint64_t trim_identity() const noexcept override { return identity_; }
  /// The trim on register_index at `inputs` (engine/input_snapshot.hpp): every column the
  /// snapshot holds as it holds it (time, session, part, tool and its cut path, temp_c, position,
  /// the sensors of the mapped inputs), the others as now; the lag terms' filters as now. NaN:
  /// no entry on the register. Real-time safe.
  [[nodiscard]] double trim_at_inputs(
      std::uint16_t register_index,
      const core::engine::InputSnapshot& inputs) const noexcept override;
  /// Real-time safe. The sum of all trims in force on register_index (0: none).
  [[nodiscard]] double trim_in_force_um(std::uint16_t register_index) const noexcept override;

  /// The session term's current offset [µm] (its posterior mean; 0 without a session term).
  [[nodiscard]] double session_offset_um() const noexcept;

  /// The trim last published for apply entry i [µm].
  [[nodiscard]] double trim_um(std::size_t i) const noexcept { return trims_um_[i]; }
  /// The context the module evaluates with (the engine's once attached).
  [[nodiscard]] const core::engine::MachineContext& context() const noexcept { return *context_; }

 private:
  void evaluate(core::TimeNs now_ns, core::StepOutput& out) noexcept;
  /// The context's row at machine time time_s, without the apply entries' columns.
  [[nodiscard]] Row context_row(double time_s) const noexcept;
  /// Apply entry i's trim on `row` for `tool` at path_mm (a fixed tool of another number: that
  /// tool's own path now) [µm].
  [[nodiscard]] double apply_trim_um(std::size_t i, Row& row, double tool,
                                     double path_mm) const noexcept;

  Model model_;
  std::vector<ModelApply> applies_;
  std::vector<ModelInput> inputs_;
  std::vector<double> trims_um_;
  /// Per register: the tool_wear entries' share of the trim the engine last accepted, and the
  /// whole of it (sized in attach()).
  std::vector<double> wear_in_force_um_;
  std::vector<double> in_force_um_;
  EvalState state_;
  bool each_cycle_;
  std::uint64_t identity_{0};
  core::engine::MachineContext own_context_;
  const core::engine::MachineContext* context_{&own_context_};
  bool bound_{false};
  // What the last evaluation saw: a change re-evaluates (part start, tool change, warm start).
  bool seen_part_{false};
  std::int32_t last_part_{0};
  std::int32_t last_tool_{-1};
  std::uint64_t last_warm_starts_{0};
  // The part of an earlier version's state, until the context knows one.
  bool has_restored_part_{false};
  std::int32_t restored_part_{0};
  bool dirty_{true};  // publish on the first step (start-up, restart)
  std::uint64_t generation_{0};
};

}  // namespace nccomp::core::model
