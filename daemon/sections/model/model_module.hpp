// The engine module of the daemon's [model] section (docs/config.md, docs/closing-the-loop.md):
// evaluates chosen terms of the model `nccomp analyze` fitted (model.toml) at the machine context
// the loop knows (part number from ProgramEvents, tool, temperature, time, machine position and
// the tool's cut path from AxisSamples) and publishes each as an
// additive trim on a register (core/engine/engine.hpp, "Trims"), on top of what the register's
// own module (e.g. S1 checkpoints) writes. It writes no target of its own, so it never fights the
// module that owns the register.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/engine/engine.hpp"
#include "core/model/model.hpp"

namespace nccomp::daemon::sections {

/// One fitted term mapped onto one register: trim_um = gain × term(context).
struct ModelApply {
  std::size_t term_index{0};
  std::uint16_t register_index{0};
  double gain{-1.0};
  /// Context columns fixed by the entry (kind, point, tool); NaN = from the loop / unknown.
  double kind{1.0};
  double point{core::model::kUnknown};
  double tool{core::model::kUnknown};
};

class ModelModule final : public core::engine::Module {
 public:
  /// update_each_cycle: re-evaluate every cycle (time / temperature terms); otherwise at start-up,
  /// part start and tool change only (part terms: the trim is constant over a part).
  ModelModule(core::model::Model model, std::vector<ModelApply> applies, bool update_each_cycle,
              int temperature_sensor);

  std::string_view name() const noexcept override { return "model"; }
  /// Checks the register indices (offset registers only: a trim on a flag makes no sense).
  void attach(const core::engine::RegisterTable& registers) override;
  /// Real-time safe: fixed-size Row, evaluation state sized in the constructor.
  void step(core::TimeNs now_ns, std::span<const core::Event> events,
            core::StepOutput& out) noexcept override;
  std::size_t state_capacity() const noexcept override { return kStateBytes; }
  std::size_t save_state(std::span<std::byte> buf) const noexcept override;
  bool load_state(std::span<const std::byte> bytes) noexcept override;
  std::uint64_t state_generation() const noexcept override { return generation_; }
  std::size_t status(std::span<core::engine::StatusValue> out) const noexcept override;

  /// The trim last published for apply entry i [µm].
  [[nodiscard]] double trim_um(std::size_t i) const noexcept { return trims_um_[i]; }
  [[nodiscard]] std::int32_t part() const noexcept { return part_; }
  /// Cut path of the tool in the spindle since it was loaded [mm] (the log's path_mm).
  [[nodiscard]] double cut_path_mm() const noexcept { return cut_path_mm_; }

 private:
  // magic, part, tool, flags, cut path; a 16-byte state (before the cut path) is still read.
  static constexpr std::size_t kStateBytes = 4 + 4 + 4 + 4 + 8;
  static constexpr std::size_t kLegacyStateBytes = 16;
  void evaluate(core::TimeNs now_ns, core::StepOutput& out) noexcept;
  void on_tool(std::int32_t tool) noexcept;
  void on_axis_sample(const core::AxisSample& a) noexcept;

  core::model::Model model_;
  std::vector<ModelApply> applies_;
  std::vector<double> trims_um_;
  core::model::EvalState state_;
  bool each_cycle_;
  int temperature_sensor_;
  std::int32_t part_{0};
  std::int32_t tool_{0};
  bool has_part_{false};
  bool has_tool_{false};
  double temp_c_{core::model::kUnknown};
  // Context from the axis samples: machine position (x_mm, y_mm, z_mm) and the cut path of the
  // tool since it was loaded (path_mm), accumulated as the creep module does: program path where
  // the NC publishes it, else the XYZ distance, only between two cutting samples.
  std::array<double, 3> position_mm_{core::model::kUnknown, core::model::kUnknown,
                                     core::model::kUnknown};
  double cut_path_mm_{0.0};
  double saved_path_mm_{0.0};
  core::AxisSample last_sample_{};
  bool have_sample_{false};
  bool dirty_{true};  // publish on the first step (start-up, restart)
  std::uint64_t generation_{0};
};

}  // namespace nccomp::daemon::sections
