#include "core/creep/creep_module.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>

#include "core/common/config_issue.hpp"
#include "core/creep/state_v1.hpp"
#include "core/creep/state_v2.hpp"
#include "core/creep/state_v3.hpp"
#include "core/creep/state_v4.hpp"
#include "core/creep/state_v5.hpp"

namespace nccomp::core::creep {

namespace {

/// cos(1°): the held normal is saved again when it turned further.
constexpr double kCosOneDegree = 0.9998476951563913;

constexpr std::array<const char*, kChannelCount> kChannelKeys{
    "creep.output.x_register", "creep.output.y_register", "creep.output.z_register",
    "creep.output.radius_register", "creep.output.length_register"};

// Status keys of remembered tools: string literals in static storage (the loop publishes the
// pointers, the status thread reads them later), built at compile time for tools 1..kKeyedTools.
// Plain arrays and pointers: with std::array's operator[] calls clang's constexpr evaluation
// runs out of steps (its default limit) before tool 9999.
constexpr std::size_t kKeyedTools = 9999;
constexpr std::size_t kToolKeyLength = 16;  // "T9999_wear_um" + NUL
struct ToolKeys {
  char key[kKeyedTools + 1][kToolKeyLength]{};
};
constexpr ToolKeys make_tool_keys() {
  ToolKeys k{};
  for (std::size_t t = 1; t <= kKeyedTools; ++t) {
    char* s = k.key[t];
    *s++ = 'T';
    std::size_t p = 1000;
    while (p > t) p /= 10;
    for (; p > 0; p /= 10) *s++ = static_cast<char>('0' + t / p % 10);
    for (const char c : "_wear_um") *s++ = c;  // with its NUL
  }
  return k;
}
constexpr ToolKeys kToolKeys = make_tool_keys();
static_assert(std::string_view(kToolKeys.key[1]) == "T1_wear_um");
static_assert(std::string_view(kToolKeys.key[907]) == "T907_wear_um");
static_assert(std::string_view(kToolKeys.key[9999]) == "T9999_wear_um");
/// Tools outside 1..kKeyedTools: by their slot in the tool memory.
constexpr std::array<const char*, kMaxToolMemory> kSlotKeys{
    "memory_slot_1_wear_um", "memory_slot_2_wear_um", "memory_slot_3_wear_um",
    "memory_slot_4_wear_um", "memory_slot_5_wear_um", "memory_slot_6_wear_um",
    "memory_slot_7_wear_um", "memory_slot_8_wear_um"};

/// The largest measured wear of a state over its support points [µm].
double max_measured_um(const CreepState& s) {
  const std::size_t n = std::clamp<std::size_t>(s.edge_points, 1, kMaxEdgePoints);
  double w = s.measured_um[0];
  for (std::size_t i = 1; i < n; ++i) w = std::max(w, s.measured_um[i]);
  return w;
}

/// What an acknowledgement cleared, as `nccomp status` shows it (static strings: the status
/// thread reads the pointer later).
const char* ack_text(std::uint64_t count, const CreepModule::Acknowledgement& a) {
  if (count == 0) return "none yet";
  constexpr std::array<const char*, 8> kText{"nothing latched",
                                             "warning flag cleared",
                                             "alarm flag cleared",
                                             "alarm and warning flags cleared",
                                             "halt cleared",
                                             "halt and warning flag cleared",
                                             "halt and alarm flag cleared",
                                             "halt, alarm and warning flags cleared"};
  const std::size_t k =
      (a.halted ? 4U : 0U) | (a.alarm_flag ? 2U : 0U) | (a.warning_flag ? 1U : 0U);
  if (k == 0 && a.request_held) return "measurement request released";
  return kText[k];
}

/// Its code: the alarm it cleared, else the warning, 0 = none (-1 = a flag of unknown cause).
std::int32_t ack_code(const CreepModule::Acknowledgement& a) {
  return a.alarm_flag ? a.alarm_code : a.warning_flag ? a.warning_code : 0;
}

engine::RegisterKind kind_for(std::size_t channel) {
  switch (static_cast<Channel>(channel)) {
    case Channel::kX:
    case Channel::kY:
    case Channel::kZ:
      return engine::RegisterKind::kAxisOffset;
    case Channel::kRadius:
      return engine::RegisterKind::kToolRadiusWear;
    case Channel::kLength:
      break;
  }
  return engine::RegisterKind::kToolLengthWear;
}

void check_index(std::int32_t index, const char* key, const engine::RegisterTable& t) {
  if (index >= 0 && static_cast<std::size_t>(index) >= t.size()) {
    throw ConfigInvalid(key, "register index " + std::to_string(index) + " does not exist (" +
                                 std::to_string(t.size()) + " [[registers]] configured)");
  }
}

void resolve(const std::string& name, std::int32_t& index, const char* key,
             const engine::RegisterTable& t) {
  if (name.empty()) return;
  const int i = t.find(name);
  if (i < 0) {
    throw ConfigInvalid(key, "no register named '" + name + "' in [[registers]]");
  }
  index = i;
}

}  // namespace

CreepModule::CreepModule(CreepModuleConfig config) : config_(std::move(config)) {
  if (config_.name.empty()) throw std::invalid_argument("creep: module name must not be empty");
}

void CreepModule::attach(const engine::RegisterTable& registers) {
  CreepConfig c = config_.creep;
  const auto& n = config_.registers;
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    resolve(n.channel[ch], c.output.channel_register[ch], kChannelKeys[ch], registers);
  }
  resolve(n.warning, c.output.warning_register, "creep.output.warning_register", registers);
  resolve(n.alarm, c.output.alarm_register, "creep.output.alarm_register", registers);
  resolve(n.measurement_due, c.output.measurement_due_register,
          "creep.output.measurement_due_register", registers);
  resolve(n.tool_change, c.output.tool_change_register, "creep.output.tool_change_register",
          registers);
  resolve(n.restart_path, c.output.restart_path_register, "creep.output.restart_path_register",
          registers);
  bool first = true;
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    const std::int32_t r = c.output.channel_register[ch];
    check_index(r, kChannelKeys[ch], registers);
    if (r < 0) continue;
    const auto& spec = registers[static_cast<std::size_t>(r)];
    if (spec.kind != kind_for(ch)) {
      throw ConfigInvalid(kChannelKeys[ch], "register '" + spec.name + "' is of kind " +
                                                std::string(engine::to_string(spec.kind)) +
                                                ", expected " +
                                                std::string(engine::to_string(kind_for(ch))));
    }
    if (first) {
      c.limiter = spec.limits;
      first = false;
    } else {
      c.limiter.max_abs_um = std::min(c.limiter.max_abs_um, spec.limits.max_abs_um);
      c.limiter.max_step_um = std::min(c.limiter.max_step_um, spec.limits.max_step_um);
      c.limiter.max_rate_um_per_s =
          std::min(c.limiter.max_rate_um_per_s, spec.limits.max_rate_um_per_s);
    }
  }
  // Flags and the restart path are not offsets: a flag must switch at once and a path position
  // of metres is no correction, so they need registers of kind flag (written as asked, only
  // the absolute bound applies), never an offset register that the limiter would slew.
  const std::array<std::pair<std::int32_t, const char*>, 5> flags{
      {{c.output.warning_register, "creep.output.warning_register"},
       {c.output.alarm_register, "creep.output.alarm_register"},
       {c.output.measurement_due_register, "creep.output.measurement_due_register"},
       {c.output.tool_change_register, "creep.output.tool_change_register"},
       {c.output.restart_path_register, "creep.output.restart_path_register"}}};
  for (const auto& [index, key] : flags) {
    check_index(index, key, registers);
    if (index < 0) continue;
    const auto& spec = registers[static_cast<std::size_t>(index)];
    if (spec.kind != engine::RegisterKind::kFlag) {
      throw ConfigInvalid(key, "register '" + spec.name + "' is of kind " +
                                   std::string(engine::to_string(spec.kind)) + ", expected flag");
    }
  }
  comp_.configure(c);  // validates: core::ConfigInvalid naming the keys
  handover_fade_um_.fill(0.0);
  fade_table_ = ProfileTable{};
  if (c.profile == ProfileShape::kTable) {
    std::copy(c.profile_table.begin(), c.profile_table.end(), fade_table_.f.begin());
    fade_table_.n = c.profile_table.size();
  }
  ++generation_;
}

bool CreepModule::rebase_output(std::uint16_t register_index, double delta_um,
                                TimeNs /*now_ns*/) noexcept {
  const auto& c = comp_.config();
  std::size_t ch = kChannelCount;
  for (std::size_t k = 0; k < kChannelCount; ++k) {
    if (c.output.channel_register[k] >= 0 && c.output.channel_register[k] == register_index) {
      ch = k;
    }
  }
  if (ch == kChannelCount || !std::isfinite(delta_um)) return false;
  // The tool_wear trims now in force take the residual shift at once and for good (the laser
  // sees what they predict); the rest of the change fades out as before (what it does not see).
  const double wear_um = wear_trim_um(register_index);
  if (!std::isfinite(wear_um)) return false;
  const double shift_um = -wear_um;
  const double fade_um = delta_um - (shift_um - residual_.shift_um[ch]);
  if (!(std::fabs(comp_.state().channel_output_um[ch] + fade_um + shift_um) <=
        c.limiter.max_abs_um)) {
    return false;
  }
  if (std::fabs(fade_um) > 1e-12 && !fade_out_shift(ch, fade_um, true)) return false;
  residual_.shift_um[ch] = shift_um;
  ++generation_;
  return true;
}

double CreepModule::wear_trim_um(std::int32_t register_index) const noexcept {
  double sum_um = 0.0;
  for (const auto* s : wear_sources_) {
    sum_um += s->tool_wear_trim_um(static_cast<std::uint16_t>(register_index));
  }
  return sum_um;
}

void CreepModule::sync_residual(bool direct, TimeNs now_ns, StepOutput& out) noexcept {
  const auto& o = comp_.config().output;
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    const std::int32_t reg = o.channel_register[ch];
    if (reg < 0) continue;
    const double target_um = -wear_trim_um(reg);
    const double d_um = target_um - residual_.shift_um[ch];
    if (!std::isfinite(target_um) || !(std::fabs(d_um) > 0.0)) continue;
    if (direct) {
      // The register takes the new tool's value now (through the engine's limiter).
      residual_.shift_um[ch] = target_um;
      out.writes.push(OffsetWrite{now_ns, static_cast<std::uint16_t>(reg),
                                  comp_.state().channel_output_um[ch] + target_um});
      ++generation_;
    } else if (fade_out_shift(ch, -d_um, false)) {
      // The total stays where it is now and reaches the new shift along the creep profile.
      residual_.shift_um[ch] = target_um;
      ++generation_;
    }
  }
}

bool CreepModule::fade_out_shift(std::size_t ch, double delta_um, bool handover) noexcept {
  const auto& c = comp_.config();
  CreepState s = comp_.export_state();
  const double output_um = s.channel_output_um[ch] + delta_um;
  if (!(std::fabs(output_um) <= c.limiter.max_abs_um)) return false;
  // The change enters the channel as an adoption's difference does: in force at once, then
  // fading along the creep profile (the creep's way to bring in a change without a step in the
  // surface). The fade is part of the saved state (AdoptedOutputs), so a restart continues it.
  AdoptedOutputs a = comp_.adoption();
  bool held = false;
  for (const auto h : a.held) held = held || h != 0;
  if (held) {
    // Started without state, no measurement since: the channels stay where they are until the
    // next one, from which the whole difference fades out.
    a.held[ch] = 1;
    a.held_um[ch] = output_um;
  } else {
    const bool path = c.creep_basis == CreepBasis::kPath || c.creep_basis == CreepBasis::kRatePath;
    const double clock = path ? s.creep_path_mm : s.creep_time_s;
    // A fade in progress goes on from what is left of it, over a new span with this change.
    double rest = 0.0;
    if (a.fading != 0) {
      const double u = a.fade_span > 0.0 ? (clock - a.fade_start) / a.fade_span : 1.0;
      rest = 1.0 - profile_fraction(c.profile, u, &fade_table_);
    }
    double largest = 0.0;
    for (std::size_t k = 0; k < kChannelCount; ++k) {
      a.fade_um[k] = (a.fading != 0 ? rest * a.fade_um[k] : 0.0) + (k == ch ? delta_um : 0.0);
      largest = std::max(largest, std::fabs(a.fade_um[k]));
      // The handovers' share goes on with the same rest (the sum of the shares is fade_um).
      handover_fade_um_[k] = (a.fading != 0 ? rest * handover_fade_um_[k] : 0.0) +
                             (handover && k == ch ? delta_um : 0.0);
    }
    double span = c.creep_length_mm;
    if (c.creep_basis == CreepBasis::kTime) span = c.creep_time_s;
    if (c.creep_basis == CreepBasis::kRateTime) span = largest / c.creep_rate_um_per_min * 60.0;
    if (c.creep_basis == CreepBasis::kRatePath) span = largest / c.creep_rate_um_per_mm;
    a.fading = largest > 0.0 ? 1 : 0;
    a.fade_path_based = path ? 1 : 0;
    a.fade_start = clock;
    a.fade_span = span;
  }
  // The channel's value and its limiter move with the target (no slew of the creep's own): the
  // register's total does not move.
  s.channel_output_um[ch] = output_um;
  const bool rearming = comp_.rearming();
  const bool between_parts = comp_.between_parts();
  // The kinematics re-anchor on the next axis sample: keeping the tool's motion through the
  // rebase made the CAN VM's handover step 1.7-2.0 um between two frames
  // (NccompdCan.ModelLoadAndRollbackHandOverOnTheCreepsRegisterWithoutAStep).
  if (!comp_.restore_state(s)) return false;
  comp_.restore_adoption(a);
  if (rearming) comp_.rearm_request();
  comp_.restore_between_parts(between_parts);
  return true;
}

void CreepModule::finish_handover_fade(TimeNs now_ns) noexcept {
  bool any = false;
  for (const double h : handover_fade_um_) any = any || std::fabs(h) > 0.0;
  if (!any) return;
  AdoptedOutputs a = comp_.adoption();
  if (a.fading == 0) {
    handover_fade_um_.fill(0.0);  // over (or cleared by a tool change)
    return;
  }
  // Between two parts (a part ended, or one started and its first cut has not come yet) no
  // surface is being cut: the fade has nothing to keep free of steps. Between two passes or at
  // the laser within a part it has: the passes side by side are one surface, and a change
  // between them is a ridge (what the creep avoids by spreading its changes over passes). Not
  // known (no part event since a restore), the tool cutting or its motion not known (no sample
  // since a restore), halted (the creep holds what the NC has), held (the fade has not started):
  // it goes on as it is.
  bool held = false;
  for (const auto h : a.held) held = held || h != 0;
  if (!comp_.between_parts() || !comp_.motion_known() || comp_.cutting() || comp_.halted() ||
      held || !have_last_step_ || now_ns <= last_step_ns_) {
    return;
  }
  const auto& c = comp_.config();
  const CreepState& s = comp_.state();
  const double clock = a.fade_path_based != 0 ? s.creep_path_mm : s.creep_time_s;
  const double u = a.fade_span > 0.0 ? (clock - a.fade_start) / a.fade_span : 1.0;
  const double rest = 1.0 - profile_fraction(c.profile, u, &fade_table_);
  if (!(rest > 0.0)) return;  // apply_adoption() ends it in this step
  // The creep's limiter lets min(max_step_um, max_rate_um_per_s · Δt) through in one write
  // (Δt this step's cycle): half of it per step, so that the write passes as it is even if the
  // rest of the target moves too (the register's own limits are at least the creep's).
  const double allowed_um =
      0.5 * std::min(c.limiter.max_step_um,
                     c.limiter.max_rate_um_per_s * seconds(now_ns - last_step_ns_));
  if (!(allowed_um > 0.0)) return;
  bool fading = false;
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    const double h = handover_fade_um_[ch];
    if (std::fabs(h) > 0.0) {
      // In force now: rest · h of the channel's target; take up to allowed_um of it out.
      const double in_fade_um = rest * h;
      const double left_um = std::fabs(in_fade_um) <= allowed_um
                                 ? 0.0
                                 : in_fade_um - std::copysign(allowed_um, in_fade_um);
      const double h_new = left_um / rest;
      a.fade_um[ch] += h_new - h;
      handover_fade_um_[ch] = h_new;
    }
    fading = fading || std::fabs(a.fade_um[ch]) > 0.0;
  }
  if (!fading) a.fading = 0;
  comp_.restore_adoption(a);
  ++generation_;  // the state file gets the fade as it is now
}

void CreepModule::clear_alarm() noexcept {
  const auto& s = comp_.state();
  last_ack_.halted = s.halted;
  last_ack_.alarm_flag = s.alarm_flag;
  last_ack_.warning_flag = s.warning_flag;
  last_ack_.request_held = s.request_held;
  last_ack_.alarm_code = latched_alarm_code();
  last_ack_.warning_code = latched_warning_code();
  comp_.clear_alarm();
  alarm_cause_ = AlarmCode::kNone;
  warning_cause_ = AlarmCode::kNone;
  ++acknowledged_;
  ++generation_;  // the state file gets the cleared flags
}

std::int32_t CreepModule::latched_alarm_code() const noexcept {
  const auto& s = comp_.state();
  if (!s.alarm_flag) return 0;
  return alarm_cause_ != AlarmCode::kNone && alarm_cause_tool_ == s.tool
             ? static_cast<std::int32_t>(alarm_cause_)
             : -1;
}

std::int32_t CreepModule::latched_warning_code() const noexcept {
  const auto& s = comp_.state();
  if (!s.warning_flag) return 0;
  return warning_cause_ != AlarmCode::kNone && warning_cause_tool_ == s.tool
             ? static_cast<std::int32_t>(warning_cause_)
             : -1;
}

void CreepModule::step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept {
  // The operator's acknowledgement first: a measurement in the same cycle is then judged by a
  // module that is no longer halted, and the flag registers written below are already 0. Any
  // code but 0 is refused by the engine before it gets here.
  for (const Event& e : events) {
    const auto* c = std::get_if<OperatorCommand>(&e);
    if (c != nullptr && c->kind == OperatorCommandKind::kAcknowledge && c->code[0] == 0) {
      clear_alarm();
    }
  }
  const bool alarm_before = comp_.state().alarm_flag;
  const bool warning_before = comp_.state().warning_flag;
  const std::size_t alarms_before = out.alarms.size();
  const std::size_t writes_before = out.writes.size();
  const std::int32_t tool_before = comp_.state().tool;
  // What is left of a trim handover's fade comes in at once between parts (as of the last step;
  // not if a sample of this step cuts), in this step's targets.
  bool cuts_now = false;
  for (const Event& e : events) {
    const auto* a = std::get_if<AxisSample>(&e);
    cuts_now = cuts_now || (a != nullptr && a->cutting);
  }
  if (!cuts_now) finish_handover_fade(now_ns);
  last_step_ns_ = now_ns;
  have_last_step_ = true;
  comp_.step(now_ns, events, out);
  // The channel registers get the residual shift on top of the compensator's output.
  const auto& reg = comp_.config().output.channel_register;
  for (std::size_t i = writes_before; i < out.writes.size(); ++i) {
    for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
      if (reg[ch] >= 0 && out.writes[i].register_index == static_cast<std::uint16_t>(reg[ch])) {
        out.writes[i].value_um += residual_.shift_um[ch];
      }
    }
  }
  const std::uint64_t accepted = comp_.counters().measurements_accepted;
  if (accepted != last_accepted_ || comp_.state().tool != tool_before) sync_steps_ = 2;
  // Another tool: its own wear and the model's trim for it replace the old ones at once, so the
  // shift does too (the old tool's share must not fade out over the new tool's cut).
  if (comp_.state().tool != tool_before) sync_direct_ = true;
  last_accepted_ = accepted;
  if (sync_steps_ > 0 && !wear_sources_.empty()) {
    --sync_steps_;
    sync_residual(sync_direct_, now_ns, out);
  }
  if (sync_steps_ == 0) sync_direct_ = false;
  // The cause of a flag that rose in this step: the first alarm (warning) the step raised (the
  // measurement's verdict comes before the limiter's alarms of the outputs). A flag restored
  // with a tool from the tool memory keeps the cause only if it is that tool's.
  const auto& st = comp_.state();
  if (st.alarm_flag && !alarm_before) {
    for (std::size_t i = alarms_before; i < out.alarms.size(); ++i) {
      if (out.alarms[i].severity == Severity::kAlarm) {
        alarm_cause_ = out.alarms[i].code;
        alarm_cause_tool_ = st.tool;
        break;
      }
    }
  }
  if (st.warning_flag && !warning_before) {
    for (std::size_t i = alarms_before; i < out.alarms.size(); ++i) {
      const auto& a = out.alarms[i];
      if (a.severity == Severity::kWarning && a.code != AlarmCode::kEventInvalid) {
        warning_cause_ = a.code;
        warning_cause_tool_ = st.tool;
        break;
      }
    }
  }
  const auto& k = comp_.counters();
  const std::uint64_t n = k.measurements_accepted + k.measurements_refused + k.events_invalid;
  const auto& s = comp_.state();
  const bool moving =
      comp_.creeps_in_progress() > 0 || s.entry.active || s.rate_known || comp_.adoption_active();
  // The held normal is saved when it turned by more than 1° (a restart then splits the
  // correction as the NC holds it, not as it was split long ago).
  const auto& hn = s.held_normal;
  const auto& ln = last_normal_;
  const bool normal_turned =
      s.normal_held != last_normal_held_ ||
      (s.normal_held && hn[0] * ln[0] + hn[1] * ln[1] + hn[2] * ln[2] < kCosOneDegree);
  if (n != last_events_ || s.tool != last_tool_ || s.halted != last_halted_ || normal_turned ||
      (moving && std::fabs(s.cut_path_mm - last_path_mm_) >= 1.0)) {
    ++generation_;
    last_events_ = n;
    last_tool_ = s.tool;
    last_halted_ = s.halted;
    last_path_mm_ = s.cut_path_mm;
    last_normal_ = s.held_normal;
    last_normal_held_ = s.normal_held;
  }
}

std::size_t CreepModule::save_state(std::span<std::byte> buf) const noexcept {
  if (buf.size() < state_capacity()) return 0;
  const CreepState st = comp_.export_state();
  std::memcpy(buf.data(), &st, sizeof(CreepState));
  std::memcpy(buf.data() + sizeof(CreepState), &comp_.tool_memory(), sizeof(ToolMemory));
  std::memcpy(buf.data() + sizeof(CreepState) + sizeof(ToolMemory), &comp_.adoption(),
              sizeof(AdoptedOutputs));
  std::memcpy(buf.data() + sizeof(CreepState) + sizeof(ToolMemory) + sizeof(AdoptedOutputs),
              &residual_, sizeof(ResidualShift));
  return state_capacity();
}

bool CreepModule::adopt_output(std::uint16_t register_index, double nc_value_um,
                               TimeNs /*now_ns*/) {
  const auto& o = comp_.config().output;
  bool adopted = false;
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    if (o.channel_register[ch] == register_index) {
      adopted = comp_.adopt_channel(static_cast<Channel>(ch), nc_value_um);
    }
  }
  const std::array<std::int32_t, 4> flags{o.warning_register, o.alarm_register,
                                          o.measurement_due_register, o.tool_change_register};
  for (std::size_t slot = 0; slot < flags.size(); ++slot) {
    if (flags[slot] == register_index) adopted = comp_.adopt_flag(slot, nc_value_um);
  }
  if (adopted) ++generation_;
  return adopted;
}

namespace {

/// The older layouts a state may come in: their structs, their bool check and their converter.
struct LayoutV1 {
  using State = v1::CreepState;
  using Memory = v1::ToolMemory;
  static constexpr std::size_t kBytes = v1::kModuleStateBytes;
  static bool loadable(const std::byte* p) noexcept { return v1::state_bytes_loadable(p); }
  static void upgrade(const State& o, double removal, CreepState& n) noexcept {
    v1::upgrade(o, removal, n);
  }
};
struct LayoutV2 {
  using State = v2::CreepState;
  using Memory = v2::ToolMemory;
  static constexpr std::size_t kBytes = v2::kModuleStateBytes;
  static bool loadable(const std::byte* p) noexcept { return v2::state_bytes_loadable(p); }
  static void upgrade(const State& o, double removal, CreepState& n) noexcept {
    v2::upgrade(o, removal, n);
  }
};
struct LayoutV3 {
  using State = v3::CreepState;
  using Memory = v3::ToolMemory;
  static constexpr std::size_t kBytes = v3::kModuleStateBytes;
  static bool loadable(const std::byte* p) noexcept { return v3::state_bytes_loadable(p); }
  static void upgrade(const State& o, double removal, CreepState& n) noexcept {
    v3::upgrade(o, removal, n);
  }
};
struct LayoutV4 {
  using State = v4::CreepState;
  using Memory = v4::ToolMemory;
  static constexpr std::size_t kBytes = v4::kModuleStateBytes;
  static bool loadable(const std::byte* p) noexcept { return v4::state_bytes_loadable(p); }
  static void upgrade(const State& o, double removal, CreepState& n) noexcept {
    v4::upgrade(o, removal, n);
  }
};
struct LayoutV5 {
  using State = v5::CreepState;
  using Memory = v5::ToolMemory;
  static constexpr std::size_t kBytes = v5::kModuleStateBytes;
  static bool loadable(const std::byte* p) noexcept { return v5::state_bytes_loadable(p); }
  static void upgrade(const State& o, double removal, CreepState& n) noexcept {
    v5::upgrade(o, removal, n);
  }
};
/// The current layout without the AdoptedOutputs (written before start-up adoption existed).
constexpr std::size_t kBytesWithoutAdoption = sizeof(CreepState) + sizeof(ToolMemory);
constexpr std::size_t kAdoption = sizeof(AdoptedOutputs);
// Every layout is told apart by its size (version 3 with or without the AdoptedOutputs).
static_assert(LayoutV1::kBytes != LayoutV2::kBytes && LayoutV1::kBytes != kBytesWithoutAdoption &&
              LayoutV2::kBytes != kBytesWithoutAdoption &&
              LayoutV1::kBytes != kBytesWithoutAdoption + kAdoption &&
              LayoutV2::kBytes != kBytesWithoutAdoption + kAdoption);
static_assert(LayoutV3::kBytes != LayoutV1::kBytes && LayoutV3::kBytes != LayoutV2::kBytes &&
              LayoutV3::kBytes + kAdoption != LayoutV1::kBytes &&
              LayoutV3::kBytes + kAdoption != LayoutV2::kBytes &&
              LayoutV3::kBytes != kBytesWithoutAdoption &&
              LayoutV3::kBytes != kBytesWithoutAdoption + kAdoption &&
              LayoutV3::kBytes + kAdoption != kBytesWithoutAdoption &&
              LayoutV3::kBytes + kAdoption != kBytesWithoutAdoption + kAdoption);
static_assert(LayoutV4::kBytes != LayoutV1::kBytes && LayoutV4::kBytes != LayoutV2::kBytes &&
              LayoutV4::kBytes != LayoutV3::kBytes &&
              LayoutV4::kBytes != LayoutV3::kBytes + kAdoption &&
              LayoutV4::kBytes + kAdoption != LayoutV1::kBytes &&
              LayoutV4::kBytes + kAdoption != LayoutV2::kBytes &&
              LayoutV4::kBytes + kAdoption != LayoutV3::kBytes &&
              LayoutV4::kBytes + kAdoption != LayoutV3::kBytes + kAdoption &&
              LayoutV4::kBytes != kBytesWithoutAdoption &&
              LayoutV4::kBytes != kBytesWithoutAdoption + kAdoption &&
              LayoutV4::kBytes + kAdoption != kBytesWithoutAdoption &&
              LayoutV4::kBytes + kAdoption != kBytesWithoutAdoption + kAdoption);

// With the residual shift: told apart from every older layout by its size too.
constexpr std::size_t kBytesWithResidual =
    kBytesWithoutAdoption + kAdoption + sizeof(CreepModule::ResidualShift);
static_assert(kBytesWithResidual != LayoutV1::kBytes && kBytesWithResidual != LayoutV2::kBytes &&
              kBytesWithResidual != LayoutV3::kBytes &&
              kBytesWithResidual != LayoutV3::kBytes + kAdoption &&
              kBytesWithResidual != LayoutV4::kBytes &&
              kBytesWithResidual != LayoutV4::kBytes + kAdoption);
// Version 5 (the learned process noise), with its AdoptedOutputs and residual shift or without.
constexpr std::size_t kV5WithResidual =
    LayoutV5::kBytes + kAdoption + sizeof(CreepModule::ResidualShift);
constexpr bool v5_sizes_distinct() {
  const std::array<std::size_t, 9> others{LayoutV1::kBytes,      LayoutV2::kBytes,
                                          LayoutV3::kBytes,      LayoutV3::kBytes + kAdoption,
                                          LayoutV4::kBytes,      LayoutV4::kBytes + kAdoption,
                                          kBytesWithoutAdoption, kBytesWithoutAdoption + kAdoption,
                                          kBytesWithResidual};
  for (const std::size_t v5 : {LayoutV5::kBytes, LayoutV5::kBytes + kAdoption, kV5WithResidual}) {
    for (const std::size_t o : others) {
      if (v5 == o) return false;
    }
  }
  return true;
}
static_assert(v5_sizes_distinct());

}  // namespace

template <class Layout>
bool CreepModule::load_state_old(std::span<const std::byte> bytes) noexcept {
  // A state written by an older layout: every state in it is checked and converted before
  // anything changes (both parts, or neither).
  using OldState = typename Layout::State;
  using OldMemory = typename Layout::Memory;
  const std::byte* p = bytes.data();
  if (!Layout::loadable(p)) return false;
  // Versions 3 and 4 may carry the AdoptedOutputs after its tool memory.
  AdoptedOutputs adoption{};
  if (bytes.size() == Layout::kBytes + kAdoption &&
      !adoption_bytes_loadable(p + Layout::kBytes, kAdoption, adoption)) {
    return false;
  }
  for (std::size_t k = 0; k < kMaxToolMemory; ++k) {
    const std::size_t at = sizeof(OldState) + offsetof(OldMemory, state) + k * sizeof(OldState);
    std::int32_t tool = 0;
    std::memcpy(&tool, p + sizeof(OldState) + offsetof(OldMemory, tool) + k * sizeof(std::int32_t),
                sizeof tool);
    if (tool != 0 && !Layout::loadable(p + at)) return false;
  }
  const double removal = comp_.config().interval.removal_mm3_per_mm;
  OldState old;
  std::memcpy(&old, p, sizeof old);
  CreepState st;
  Layout::upgrade(old, removal, st);
  if (comp_.check_state(st).field != nullptr) return false;
  const std::byte* mem = p + sizeof(OldState);
  std::memcpy(scratch_memory_.tool.data(), mem + offsetof(OldMemory, tool),
              sizeof(scratch_memory_.tool));
  std::memcpy(scratch_memory_.last_use.data(), mem + offsetof(OldMemory, last_use),
              sizeof(scratch_memory_.last_use));
  std::memcpy(&scratch_memory_.use_counter, mem + offsetof(OldMemory, use_counter),
              sizeof(scratch_memory_.use_counter));
  for (std::size_t k = 0; k < kMaxToolMemory; ++k) {
    if (scratch_memory_.tool[k] == 0) {
      scratch_memory_.state[k] = CreepState{};
      continue;
    }
    std::memcpy(&old, mem + offsetof(OldMemory, state) + k * sizeof(OldState), sizeof old);
    Layout::upgrade(old, removal, scratch_memory_.state[k]);
  }
  if (!comp_.restore_tool_memory(scratch_memory_)) return false;
  (void)comp_.restore_state(st);  // cannot fail: checked above
  comp_.restore_adoption(adoption);
  residual_ = ResidualShift{};
  handover_fade_um_.fill(0.0);
  last_accepted_ = comp_.counters().measurements_accepted;
  sync_steps_ = 0;
  alarm_cause_ = AlarmCode::kNone;
  warning_cause_ = AlarmCode::kNone;
  ++generation_;
  return true;
}

bool CreepModule::residual_loadable(const std::byte* p, ResidualShift& out) const noexcept {
  std::memcpy(&out, p, sizeof out);
  if (out.version != ResidualShift::kVersion) return false;
  for (const double v : out.shift_um) {
    if (!(std::fabs(v) <= comp_.config().limiter.max_abs_um)) return false;
  }
  return true;
}

bool CreepModule::load_state(std::span<const std::byte> bytes) noexcept {
  if (bytes.size() == LayoutV1::kBytes) return load_state_old<LayoutV1>(bytes);
  if (bytes.size() == LayoutV2::kBytes) return load_state_old<LayoutV2>(bytes);
  if (bytes.size() == LayoutV3::kBytes || bytes.size() == LayoutV3::kBytes + kAdoption) {
    return load_state_old<LayoutV3>(bytes);
  }
  if (bytes.size() == LayoutV4::kBytes || bytes.size() == LayoutV4::kBytes + kAdoption) {
    return load_state_old<LayoutV4>(bytes);
  }
  if (bytes.size() == LayoutV5::kBytes || bytes.size() == LayoutV5::kBytes + kAdoption) {
    return load_state_old<LayoutV5>(bytes);
  }
  ResidualShift residual{};
  if (bytes.size() == kV5WithResidual) {
    if (!residual_loadable(bytes.data() + LayoutV5::kBytes + kAdoption, residual)) return false;
    if (!load_state_old<LayoutV5>(bytes.first(LayoutV5::kBytes + kAdoption))) return false;
    residual_ = residual;
    return true;
  }
  // A state written before the residual shift ends with the AdoptedOutputs.
  if (bytes.size() == state_capacity()) {
    if (!residual_loadable(bytes.data() + kBytesWithoutAdoption + kAdoption, residual)) {
      return false;
    }
    bytes = bytes.first(kBytesWithoutAdoption + kAdoption);
  }
  AdoptedOutputs adoption{};
  if (bytes.size() == kBytesWithoutAdoption + kAdoption) {
    if (!adoption_bytes_loadable(bytes.data() + kBytesWithoutAdoption, sizeof(AdoptedOutputs),
                                 adoption)) {
      return false;
    }
  } else if (bytes.size() != kBytesWithoutAdoption) {
    return false;
  }
  if (!state_bytes_loadable(bytes.data(), sizeof(CreepState)) ||
      !memory_bytes_loadable(bytes.data() + sizeof(CreepState), sizeof(ToolMemory))) {
    return false;
  }
  // Checked in full before anything changes: both parts, or neither.
  CreepState st;
  std::memcpy(&st, bytes.data(), sizeof(CreepState));
  if (comp_.check_state(st).field != nullptr) return false;
  std::memcpy(&scratch_memory_, bytes.data() + sizeof(CreepState), sizeof(ToolMemory));
  if (!comp_.restore_tool_memory(scratch_memory_)) return false;
  (void)comp_.restore_state(st);  // cannot fail: checked above
  comp_.restore_adoption(adoption);
  residual_ = residual;
  handover_fade_um_.fill(0.0);
  last_accepted_ = comp_.counters().measurements_accepted;
  sync_steps_ = 0;
  // A flag of the restored state was raised by another process: its cause is not known here.
  alarm_cause_ = AlarmCode::kNone;
  warning_cause_ = AlarmCode::kNone;
  ++generation_;
  return true;
}

std::size_t CreepModule::status(std::span<engine::StatusValue> out) const noexcept {
  const auto& s = comp_.state();
  const auto& c = comp_.config();
  const auto& mem = comp_.tool_memory();
  const std::size_t n = std::max<std::size_t>(1, c.edge.edge_points);
  // The support point with the largest measured wear speaks for the tool.
  std::size_t k = 0;
  for (std::size_t i = 1; i < n; ++i) {
    if (s.measured_um[i] > s.measured_um[k]) k = i;
  }
  const double in_force_um = comp_.applied_wear_um(k);
  const bool est = c.estimator.enabled;
  const char* mode = c.profile == ProfileShape::kStep ? (est ? "step, estimator" : "step")
                     : c.predict.enabled
                         ? (est ? "predictive creeping, estimator" : "predictive creeping")
                         : (est ? "creeping, estimator" : "creeping");
  double estimate_um = kNaN;
  double sigma_um = kNaN;
  (void)comp_.wear_estimate(k, estimate_um, sigma_um);
  // Remembered tools, the most recently used first.
  std::array<std::size_t, kMaxToolMemory> order{};
  std::size_t remembered = 0;
  for (std::size_t m = 0; m < kMaxToolMemory; ++m) {
    if (mem.tool[m] != 0) order[remembered++] = m;
  }
  for (std::size_t i = 1; i < remembered; ++i) {  // insertion sort: at most 8 entries
    for (std::size_t j = i; j > 0 && mem.last_use[order[j]] > mem.last_use[order[j - 1]]; --j) {
      std::swap(order[j], order[j - 1]);
    }
  }
  const engine::StatusValue core_values[] = {
      {"mode", 0.0, mode},
      {"tool", static_cast<double>(s.tool), nullptr},
      {"wear_in_force_um", in_force_um, nullptr},
      {"wear_measured_um", s.measured_um[k], nullptr},
      {"creep_remaining_um", s.measured_um[k] - in_force_um, nullptr},
      {"creeps_in_progress", static_cast<double>(comp_.creeps_in_progress()), nullptr},
      {"correction_um", comp_.correction_um(), nullptr},
      {"cut_path_mm", s.cut_path_mm, nullptr},
      {"wear_rate_um_per_mm", s.rate_known ? s.rate_um_per_mm[k] : kNaN, nullptr},
      {"halted", s.halted ? 1.0 : 0.0, nullptr},
      {"latched_alarm", static_cast<double>(latched_alarm_code()), nullptr},
      {"acknowledged", static_cast<double>(acknowledged_), nullptr},
      {"last_acknowledge", static_cast<double>(ack_code(last_ack_)),
       ack_text(acknowledged_, last_ack_)},
      {"measurements_accepted", static_cast<double>(comp_.counters().measurements_accepted),
       nullptr},
      {"measurements_refused", static_cast<double>(comp_.counters().measurements_refused), nullptr},
      {"wear_estimate_um", estimate_um, nullptr},
      {"wear_sigma_um", sigma_um, nullptr},
      {"nis_mean", comp_.nis_mean(k), nullptr},
      {"measurement_sigma_estimate_um", comp_.measurement_sigma_estimate_um(k), nullptr},
      {"rate_noise_um_per_mm_per_sqrt_m", std::sqrt(comp_.rate_q() * 1000.0), nullptr},
  };
  // The estimator's values only when it is on.
  const std::size_t n_core = std::size(core_values) - (est ? 0U : 5U);
  // A status holds at most out.size() values (engine::kMaxStatusValues): every remembered tool
  // is shown; beyond five of them (none with the estimator) these make room, the first first.
  constexpr std::array<const char*, 9> kYield{"measurements_refused",
                                              "measurements_accepted",
                                              "wear_rate_um_per_mm",
                                              "cut_path_mm",
                                              "rate_noise_um_per_mm_per_sqrt_m",
                                              "measurement_sigma_estimate_um",
                                              "nis_mean",
                                              "wear_sigma_um",
                                              "wear_estimate_um"};
  const std::size_t total = n_core + remembered;
  const std::size_t drop =
      std::min(kYield.size(), total > out.size() ? total - out.size() : std::size_t{0});
  std::size_t w = 0;
  for (std::size_t j = 0; j < n_core; ++j) {
    const auto& v = core_values[j];
    bool dropped = false;
    for (std::size_t d = 0; d < drop; ++d)
      dropped = dropped || std::string_view(v.key) == kYield[d];
    if (dropped) continue;
    if (w == out.size()) return w;
    out[w++] = v;
  }
  for (std::size_t j = 0; j < remembered; ++j) {
    if (w == out.size()) break;
    const std::size_t m = order[j];
    const std::int32_t tool = mem.tool[m];
    const char* key = tool >= 1 && static_cast<std::size_t>(tool) <= kKeyedTools
                          ? kToolKeys.key[static_cast<std::size_t>(tool)]
                          : kSlotKeys[m];
    out[w++] = {key, max_measured_um(mem.state[m]), nullptr};
  }
  return w;
}

std::vector<std::uint16_t> CreepModule::written_registers() const {
  const auto& o = comp_.config().output;
  std::vector<std::uint16_t> out;
  for (const std::int32_t r : o.channel_register) {
    if (r >= 0) out.push_back(static_cast<std::uint16_t>(r));
  }
  for (const std::int32_t r : {o.warning_register, o.alarm_register, o.measurement_due_register,
                               o.tool_change_register, o.restart_path_register}) {
    if (r >= 0) out.push_back(static_cast<std::uint16_t>(r));
  }
  return out;
}

}  // namespace nccomp::core::creep
