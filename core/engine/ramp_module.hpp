// A commissioning module: ramps one register toward a target at a fixed rate.
//
// It is how an operator checks the path from the engine to the NC before any compensation module
// is enabled (the value visibly creeps in the NC's register), and how the daemon's crash-safety is
// tested: its progress is its persisted state, so a restart continues the ramp from where it was,
// never from zero and never past the target.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/engine/engine.hpp"

namespace nccomp::core::engine {

struct RampConfig {
  /// Module name (state key); unique among modules.
  std::string name{"ramp"};
  /// Register the ramp writes, by name.
  std::string register_name;
  /// Value the ramp starts from when it has no state [µm].
  double start_um{0.0};
  /// Value the ramp ends at [µm].
  double target_um{0.0};
  /// Speed of the ramp [µm/s] (> 0).
  double rate_um_per_s{1.0};
};

class RampModule final : public Module {
 public:
  /// Not real-time. Throws std::invalid_argument for non-finite values or a rate ≤ 0.
  explicit RampModule(RampConfig config);

  [[nodiscard]] std::string_view name() const noexcept override { return config_.name; }
  void attach(const RegisterTable& registers) override;
  /// Real-time safe.
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept override;
  [[nodiscard]] std::size_t state_capacity() const noexcept override;
  std::size_t save_state(std::span<std::byte> buf) const noexcept override;
  bool load_state(std::span<const std::byte> bytes) noexcept override;
  [[nodiscard]] std::uint64_t state_generation() const noexcept override { return generation_; }
  /// Without a state the ramp starts from what the NC holds instead of start_um: its configured
  /// target is the operator's decision, the NC's value its origin (never a jump to start_um).
  bool adopt_output(std::uint16_t register_index, double nc_value_um, TimeNs now_ns) override;

  /// Current value of the ramp [µm].
  [[nodiscard]] double value_um() const noexcept { return value_um_; }
  [[nodiscard]] bool done() const noexcept;
  /// The ramp's register (valid after attach()).
  [[nodiscard]] std::vector<std::uint16_t> written_registers() const override {
    return {register_index_};
  }

 private:
  RampConfig config_;
  std::uint16_t register_index_{0};
  double value_um_{0.0};
  TimeNs last_ns_{0};
  bool has_last_{false};
  std::uint64_t generation_{0};
};

}  // namespace nccomp::core::engine
