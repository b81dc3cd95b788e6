// The creeping wear correction as an engine module (core/engine/engine.hpp): the daemon builds
// one from the `[creep]` config section, the engine steps it with the validated events, limits
// its absolute targets per register and persists its state with the rest of the engine's.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "core/common/profile.hpp"
#include "core/creep/config.hpp"
#include "core/creep/wear_compensator.hpp"
#include "core/engine/engine.hpp"
#include "core/engine/tool_wear_trims.hpp"

namespace nccomp::core::creep {

/// The registers of [creep.output] by name (TOML: `x_register = "X_offset"` etc.), resolved at
/// attach() to indices in the engine's [[registers]] list. Empty = use the index already in
/// CreepConfig::output (or none).
struct CreepRegisterNames {
  std::array<std::string, kChannelCount> channel;  // x, y, z, radius, length
  std::string warning;
  std::string alarm;
  std::string measurement_due;
  std::string tool_change;
  std::string restart_path;
};

struct CreepModuleConfig {
  /// Module name (state key); unique among modules.
  std::string name{"creep"};
  CreepRegisterNames registers{};
  CreepConfig creep{};
};

class CreepModule final : public engine::Module, public engine::ToolWearTrimUser {
 public:
  /// Not real-time. Stores the config; everything is validated at attach(), when the register
  /// names can be resolved.
  explicit CreepModule(CreepModuleConfig config);

  [[nodiscard]] std::string_view name() const noexcept override { return config_.name; }

  /// Not real-time. Resolves register names, checks every index against the table and its
  /// kind (x/y/z →
  /// axis_offset, radius → tool_radius_wear, length → tool_length_wear); takes the most
  /// restrictive limits of the offset registers it drives as its own limiter (so a measurement
  /// the engine would reject is refused before it changes any state); validates and configures
  /// the core. Throws core::ConfigInvalid naming the key.
  void attach(const engine::RegisterTable& registers) override;

  /// Real-time safe.
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept override;

  /// The residual shift saved after the AdoptedOutputs (version 1).
  struct ResidualShift {
    static constexpr std::uint32_t kVersion = 1;
    std::uint32_t version{kVersion};
    std::uint32_t reserved{0};
    /// Per channel [µm]: added to the compensator's output (rebase_output(),
    /// bind_tool_wear_trims()).
    std::array<double, kChannelCount> shift_um{};
  };

  [[nodiscard]] std::size_t state_capacity() const noexcept override {
    return sizeof(CreepState) + sizeof(ToolMemory) + sizeof(AdoptedOutputs) + sizeof(ResidualShift);
  }
  /// Real-time safe: the plain-data CreepState of the active tool, then the ToolMemory of the
  /// tools out of the spindle, then what was adopted at a start without state (AdoptedOutputs),
  /// then the ResidualShift, byte for byte.
  std::size_t save_state(std::span<std::byte> buf) const noexcept override;
  /// Real-time safe: false if the bytes are not a state valid for this config (the module then
  /// keeps its fresh state). A state written by version 1 of the layout (before the eased
  /// superposition) or version 2 (before the held normal and the request hold) is converted
  /// (core/creep/state_v1.hpp, state_v2.hpp); version 3 (before the wear estimator) and 4
  /// (before the learned process noise) too, with or without their AdoptedOutputs
  /// (state_v3.hpp, state_v4.hpp), and 5 (before the learned rate prior) with or without its
  /// AdoptedOutputs and ResidualShift (state_v5.hpp); one without the AdoptedOutputs (before
  /// start-up adoption) loads with nothing adopted, one without the ResidualShift with none.
  bool load_state(std::span<const std::byte> bytes) noexcept override;
  /// Advances on every discrete change (measurement, tool change, halt), every 1 mm of cut
  /// path while creeps, entries or predictions are in progress, and when the held surface
  /// normal turned by more than 1°.
  [[nodiscard]] std::uint64_t state_generation() const noexcept override { return generation_; }
  /// Real-time safe: mode, tool, wear in force / measured / still to creep (max over the edge)
  /// [µm], creeps in progress, the correction along the normal [µm], cut path [mm], fitted wear
  /// rate [µm/mm], halted, latched_alarm (latched_alarm_code()), acknowledged (count),
  /// last_acknowledge (text: what the last acknowledgement cleared; value: the alarm code it
  /// cleared, else the warning code, 0 = none), measurements accepted / refused; then the
  /// measured wear of every remembered tool (`T<n>_wear_um`, most recently used first;
  /// `memory_slot_<k>_wear_um` for a tool number beyond 9999). With [creep.estimator] on, also
  /// wear_estimate_um and wear_sigma_um (the estimate at the current cut path and its standard
  /// deviation, NaN before its first measurement), nis_mean and measurement_sigma_estimate_um
  /// (the check of σ, WearCompensator::nis_mean()) and rate_noise_um_per_mm_per_sqrt_m (the
  /// process noise in use, configured or learned) before the remembered tools. With more than
  /// five remembered tools (any with the estimator) counters make room (refused, accepted, rate,
  /// cut path, then the estimator's values from the last) so that all fit into
  /// engine::kMaxStatusValues (20).
  std::size_t status(std::span<engine::StatusValue> out) const noexcept override;
  /// The offset and flag registers of [creep.output] (valid after attach()).
  [[nodiscard]] std::vector<std::uint16_t> written_registers() const override;
  /// Without a state: a channel register's value is held until the next measurement and the
  /// fallback channel's sets the wear baseline (WearCompensator::adopt_channel()); the warning,
  /// alarm and tool change flags read back high stay latched (adopt_flag()). The measurement
  /// request and the restart path are recomputed (false).
  bool adopt_output(std::uint16_t register_index, double nc_value_um, TimeNs now_ns) override;
  /// Trim handover (core/engine/engine.hpp): a channel register's target moves by delta_um at
  /// once (the register's total stays). The laser measures the tool's whole wear, so the part
  /// of the new trims that predicts it (ToolWearTrimSource::tool_wear_trim_um(), a model's
  /// tool_wear terms) must not be added to it a second time: the channel's residual shift (saved
  /// with the state) becomes minus those trims, at once and for good. The rest of delta_um (the
  /// change of trims the laser does not see, e.g. contour terms) moves the compensator's output and
  /// fades out along the creep profile over one creep span from the current creep clock, as an
  /// adopted value does (AdoptedOutputs): such a trim comes in without a step. That fade is only
  /// needed while a surface is being cut: between parts (a part start or end since the last
  /// cutting sample, the tool not cutting), what is left of it comes in at once, as fast as the
  /// creep's limiter lets it (finish_handover_fade()); within a part (cutting, between passes,
  /// at the laser) it goes on along the creep. Started without state and not yet measured: that
  /// part is held until the next measurement. The kinematics re-anchor on the next axis sample (one
  /// cycle's cut path is not counted). False for a flag register or a value beyond max_abs_um.
  /// Real-time safe.
  bool rebase_output(std::uint16_t register_index, double delta_um,
                     TimeNs now_ns) noexcept override;
  /// The modules whose trims predict the tool's wear (engine::ToolWearTrimSource). At each
  /// accepted measurement the residual shift of a channel is set to minus their trims then in
  /// force on its register, so that the register holds the measured wear plus what the trims
  /// predict since (the model predicts, the creep learns the residual); the change enters
  /// without a step, fading in along the creep profile over one creep span. At a tool change it
  /// is set at once (the new tool's wear and trims replace the old ones). Without such trims it
  /// stays 0.
  void bind_tool_wear_trims(std::vector<const engine::ToolWearTrimSource*> sources) override {
    wear_sources_ = std::move(sources);
  }
  /// A reload carries the tool's motion into the next engine's creep (WearCompensator::
  /// save_motion()). Real-time safe.
  std::size_t save_motion(std::span<std::byte> buf) const noexcept override {
    return comp_.save_motion(buf);
  }
  bool load_motion(std::span<const std::byte> bytes) noexcept override {
    return comp_.load_motion(bytes);
  }

  /// Operator acknowledgement (`nccomp acknowledge`: an OperatorCommand kAcknowledge in step(),
  /// taken before the cycle's other events): WearCompensator::clear_alarm() (halt, alarm and
  /// warning flags, the hold of the measurement request), counted, remembered as
  /// last_acknowledgement(); the flag registers fall to 0 in the same step. Also when nothing is
  /// latched (counted, nothing changes). Real-time safe.
  void clear_alarm() noexcept;
  /// Start-up only (before the loop steps the engine): WearCompensator::rearm_request().
  void rearm_request() noexcept { comp_.rearm_request(); }
  [[nodiscard]] const WearCompensator& compensator() const noexcept { return comp_; }

  /// What one acknowledgement found latched (and cleared).
  struct Acknowledgement {
    bool halted{false};
    bool alarm_flag{false};
    bool warning_flag{false};
    bool request_held{false};
    /// The alarm that raised the alarm flag (see latched_alarm_code()), and the warning that
    /// raised the warning flag (0 = none, -1 = not known in this process).
    std::int32_t alarm_code{0};
    std::int32_t warning_code{0};
  };
  /// Acknowledgements taken since the module was created (a count of this process).
  [[nodiscard]] std::uint64_t acknowledged() const noexcept { return acknowledged_; }
  [[nodiscard]] const Acknowledgement& last_acknowledgement() const noexcept { return last_ack_; }
  /// The alarm code (core::AlarmCode) holding the alarm flag: 0 = the flag is low; -1 = it is
  /// high but was raised before this process started or while the tool was out of the spindle
  /// (the state keeps the flag, not its cause: the daemon's log has it).
  [[nodiscard]] std::int32_t latched_alarm_code() const noexcept;
  /// The same for the warning flag.
  [[nodiscard]] std::int32_t latched_warning_code() const noexcept;

 private:
  /// A state of an older layout (LayoutV1, LayoutV2 in creep_module.cpp), converted.
  template <class Layout>
  bool load_state_old(std::span<const std::byte> bytes) noexcept;
  /// True if p holds a ResidualShift of this version within the limiter's bound (copied to out).
  bool residual_loadable(const std::byte* p, ResidualShift& out) const noexcept;
  /// Moves channel ch's output by delta_um at once (its value and limiter with it), the shift
  /// fading out along the creep profile over one creep span from the current creep clock, as an
  /// adopted value does (AdoptedOutputs). Not yet measured after a start without state: held at
  /// the shifted value until the next measurement. handover: the shift is a trim handover's
  /// (rebase_output()), counted in handover_fade_um_; else a residual sync's, which pairs with
  /// the creep of the measurement and must fade. False beyond max_abs_um.
  bool fade_out_shift(std::size_t ch, double delta_um, bool handover) noexcept;
  /// Between parts (WearCompensator::between_parts(), the last axis sample not cutting): takes
  /// what is left of the handovers' share of the fade (handover_fade_um_) out of the fade, so
  /// that it is in force at once, by at most half of what the creep's limiter lets through in
  /// one cycle (max_step_um, max_rate_um_per_s over the last cycle's time) per channel and step:
  /// the write is never slewed. Real-time safe.
  void finish_handover_fade(TimeNs now_ns) noexcept;
  /// Sets the residual shifts to minus the tool wear trims in force (bind_tool_wear_trims()),
  /// faded in, or at once (direct: after a tool change).
  void sync_residual(bool direct, TimeNs now_ns, StepOutput& out) noexcept;
  /// Σ of the sources' tool wear trims on a register [µm].
  [[nodiscard]] double wear_trim_um(std::int32_t register_index) const noexcept;

  CreepModuleConfig config_;
  WearCompensator comp_;
  /// The profile table of the creeps (for a handover's fade, rebase_output()).
  ProfileTable fade_table_{};
  /// Where load_state() decodes the tool memory (56 kB: not on the loop thread's stack).
  ToolMemory scratch_memory_{};
  std::vector<const engine::ToolWearTrimSource*> wear_sources_;
  ResidualShift residual_{};
  /// The trim handovers' share of the adoption's fade_um per channel (fade_out_shift(); the rest
  /// is the residual syncs'). Not saved: after a restart what is left of it fades out along the
  /// creep as before (the saved fade_um holds it once; nothing is applied twice).
  std::array<double, kChannelCount> handover_fade_um_{};
  /// The time of the last step (the cycle's length for finish_handover_fade()).
  TimeNs last_step_ns_{0};
  bool have_last_step_{false};
  /// Steps still to sync the residual after a measurement or tool change (the trimming module
  /// may step after this one: its new trim is seen one step later).
  int sync_steps_{0};
  bool sync_direct_{false};
  std::uint64_t last_accepted_{0};
  std::uint64_t generation_{0};
  std::uint64_t last_events_{0};
  std::int32_t last_tool_{0};
  bool last_halted_{false};
  double last_path_mm_{0.0};
  std::array<double, 3> last_normal_{};
  bool last_normal_held_{false};
  // Operator acknowledgements, and the causes of the latched flags (not saved).
  std::uint64_t acknowledged_{0};
  Acknowledgement last_ack_{};
  AlarmCode alarm_cause_{AlarmCode::kNone};
  std::int32_t alarm_cause_tool_{0};
  AlarmCode warning_cause_{AlarmCode::kNone};
  std::int32_t warning_cause_tool_{0};
};

}  // namespace nccomp::core::creep
