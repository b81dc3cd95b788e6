#include "core/model/model_module.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>
#include <utility>

namespace nccomp::core::model {

namespace {
constexpr std::uint32_t kLegacyMagic = 0x4D4F444CU;   // "MODL": the state before the context
constexpr std::uint32_t kSessionMagic = 0x4D534553U;  // "MSES": what a session term learned
constexpr std::uint32_t kSessionVersion = 1;
constexpr std::size_t kSessionStateBytes = 8 + 3 * sizeof(double);
constexpr std::size_t col(Column c) { return static_cast<std::size_t>(c); }

/// FNV-1a over the bytes of what the trims are computed from.
class Fnv {
 public:
  void bytes(const void* p, std::size_t n) noexcept {
    const auto* b = static_cast<const unsigned char*>(p);
    for (std::size_t i = 0; i < n; ++i) h_ = (h_ ^ b[i]) * 0x100000001b3ULL;
  }
  template <typename T>
  void value(const T& v) noexcept {
    bytes(&v, sizeof v);
  }
  void text(const std::string& s) noexcept {
    value(s.size());
    bytes(s.data(), s.size());
  }
  [[nodiscard]] std::uint64_t get() const noexcept { return h_ == 0 ? 1 : h_; }

 private:
  std::uint64_t h_{0xcbf29ce484222325ULL};
};

std::uint64_t identity_of(const Model& model, const std::vector<ModelApply>& applies,
                          const std::vector<ModelInput>& inputs, bool each_cycle) {
  Fnv f;
  for (const std::string& e : model.extra_columns()) f.text(e);
  for (const Term& t : model.terms()) {
    const TermSpec& s = t.spec;
    f.text(s.name);
    f.value(s.form);
    f.value(s.column);
    f.value(s.per);
    f.value(s.kind_mask);
    f.value(s.degree);
    f.value(s.center);
    f.value(s.scale);
    if (has_column_b(s.form)) {  // only here: other models keep their identity
      f.value(s.column_b);
      f.value(s.center_b);
    }
    for (const auto& g : t.groups) f.value(g);
    for (const double c : t.coef) f.value(c);
  }
  for (const ModelApply& a : applies) {
    f.value(a.term_index);
    f.value(a.register_index);
    f.value(a.gain);
    f.value(a.kind);
    f.value(a.point);
    f.value(a.tool);
    f.value(a.angle_deg);
  }
  for (const ModelInput& in : inputs) {
    f.value(in.column);
    f.value(in.sensor);
  }
  f.value(each_cycle);
  return f.get();
}
}  // namespace

ModelModule::ModelModule(Model model, std::vector<ModelApply> applies, bool update_each_cycle,
                         std::vector<ModelInput> inputs)
    : model_(std::move(model)),
      applies_(std::move(applies)),
      inputs_(std::move(inputs)),
      trims_um_(applies_.size(), 0.0),
      state_(model_.make_state()),
      each_cycle_(update_each_cycle),
      identity_(identity_of(model_, applies_, inputs_, each_cycle_)) {
  for (const auto& a : applies_) {
    if (a.term_index >= model_.terms().size()) {
      throw std::invalid_argument("model: term index " + std::to_string(a.term_index) +
                                  " beyond the model's " + std::to_string(model_.terms().size()) +
                                  " terms");
    }
  }
  for (const auto& in : inputs_) {
    if (in.column < static_cast<int>(kStandardColumns) ||
        in.column >= static_cast<int>(kStandardColumns + model_.extra_columns().size()) ||
        in.sensor < 0 || in.sensor >= static_cast<int>(core::engine::kTemperatureSensors)) {
      throw std::invalid_argument("model: input column " + std::to_string(in.column) +
                                  " / sensor " + std::to_string(in.sensor) + " out of range");
    }
  }
}

void ModelModule::attach(const core::engine::RegisterTable& registers) {
  for (const auto& a : applies_) {
    if (a.register_index >= registers.size()) {
      throw std::invalid_argument("model: register index " + std::to_string(a.register_index) +
                                  " does not exist (" + std::to_string(registers.size()) +
                                  " registers)");
    }
    if (registers[a.register_index].kind == core::engine::RegisterKind::kFlag) {
      throw std::invalid_argument("model: register '" + registers[a.register_index].name +
                                  "' is a flag; a model trim needs an offset register");
    }
  }
  wear_in_force_um_.assign(registers.size(), 0.0);
  in_force_um_.assign(registers.size(), 0.0);
}

void ModelModule::bind_context(const core::engine::MachineContext& context) {
  context_ = &context;
  bound_ = true;
}

void ModelModule::step(core::TimeNs now_ns, std::span<const core::Event> events,
                       core::StepOutput& out) noexcept {
  if (!bound_) own_context_.update(now_ns, events);
  const core::engine::MachineContext& c = *context_;
  const std::int32_t tool = c.has_tool() ? c.tool() : -1;
  const bool changed = c.has_part() != seen_part_ || (c.has_part() && c.part() != last_part_) ||
                       tool != last_tool_ || c.warm_starts() != last_warm_starts_;
  if (dirty_ || each_cycle_ || changed) {
    seen_part_ = c.has_part();
    last_part_ = c.part();
    last_tool_ = tool;
    last_warm_starts_ = c.warm_starts();
    evaluate(now_ns, out);
    dirty_ = false;
  }
}

Row ModelModule::context_row(double time_s) const noexcept {
  // The context of "now"; unknown columns are NaN, and a term whose column is unknown
  // contributes nothing (e.g. part_trend before the first part start).
  const core::engine::MachineContext& c = *context_;
  Row row = unknown_row();
  row[col(Column::kTime)] = time_s;
  if (c.has_part()) {
    row[col(Column::kPart)] = c.part();
  } else if (has_restored_part_) {
    row[col(Column::kPart)] = restored_part_;
  }
  row[col(Column::kTemp)] = c.temp_c();
  row[col(Column::kX)] = c.position_mm()[0];
  row[col(Column::kY)] = c.position_mm()[1];
  row[col(Column::kZ)] = c.position_mm()[2];
  row[kSessionColumn] = static_cast<double>(c.warm_starts());
  for (const ModelInput& in : inputs_) {
    row[static_cast<std::size_t>(in.column)] = c.temperature_c(in.sensor);
  }
  return row;
}

double ModelModule::apply_trim_um(std::size_t i, Row& row, double tool,
                                  double path_mm) const noexcept {
  const ModelApply& a = applies_[i];
  row[col(Column::kKind)] = a.kind;
  row[col(Column::kPoint)] = a.point;
  row[col(Column::kAngle)] = a.angle_deg;
  if (!std::isnan(a.tool) && (std::isnan(tool) || std::islessgreater(a.tool, tool))) {
    // A term of one tool: its number and its own cut path (NaN until the context knows it).
    row[col(Column::kTool)] = a.tool;
    row[col(Column::kPath)] = context_->cut_path_mm(static_cast<std::int32_t>(a.tool));
  } else {
    row[col(Column::kTool)] = tool;
    row[col(Column::kPath)] = path_mm;
  }
  return a.gain * model_.evaluate_term(a.term_index, row, state_);
}

double ModelModule::trim_at_inputs(std::uint16_t register_index,
                                   const core::engine::InputSnapshot& inputs) const noexcept {
  const core::engine::MachineContext& c = *context_;
  const auto known = [](double held, double now) { return std::isnan(held) ? now : held; };
  Row row = context_row(known(inputs.time_s, c.machine_time_s()));
  row[col(Column::kPart)] = known(inputs.part, row[col(Column::kPart)]);
  row[col(Column::kTemp)] = known(inputs.temp_c, row[col(Column::kTemp)]);
  for (std::size_t k = 0; k < 3; ++k) {
    row[col(Column::kX) + k] = known(inputs.position_mm[k], row[col(Column::kX) + k]);
  }
  row[kSessionColumn] = known(inputs.session, row[kSessionColumn]);
  for (const ModelInput& in : inputs_) {
    const auto i = static_cast<std::size_t>(in.column);
    row[i] = known(inputs.temperature_c(in.sensor), row[i]);
  }
  const bool has_tool = !std::isnan(inputs.tool);
  const double tool = has_tool ? inputs.tool : c.has_tool() ? c.tool() : kUnknown;
  const double path_mm = has_tool ? inputs.path_mm : c.has_tool() ? c.cut_path_mm() : kUnknown;
  bool any = false;
  double sum_um = 0.0;
  for (std::size_t i = 0; i < applies_.size(); ++i) {
    if (applies_[i].register_index != register_index) continue;
    any = true;
    sum_um += apply_trim_um(i, row, tool, path_mm);
  }
  return any ? sum_um : kUnknown;
}

double ModelModule::trim_in_force_um(std::uint16_t register_index) const noexcept {
  return register_index < in_force_um_.size() ? in_force_um_[register_index] : 0.0;
}

void ModelModule::evaluate(core::TimeNs now_ns, core::StepOutput& out) noexcept {
  const core::engine::MachineContext& c = *context_;
  Row row = context_row(c.machine_time_s(now_ns));
  advance_state(model_.specs(), row, state_);
  const double tool = c.has_tool() ? static_cast<double>(c.tool()) : kUnknown;
  const double path_mm = c.has_tool() ? c.cut_path_mm() : kUnknown;
  for (std::size_t i = 0; i < applies_.size(); ++i) {
    trims_um_[i] = apply_trim_um(i, row, tool, path_mm);
  }
  // One trim per register: the engine keeps one trim per module and register, so entries on
  // the same register are summed. A non-finite sum goes to the engine, which refuses it with
  // an alarm.
  for (std::size_t i = 0; i < applies_.size(); ++i) {
    const std::uint16_t reg = applies_[i].register_index;
    bool first = true;
    for (std::size_t j = 0; j < i && first; ++j) first = applies_[j].register_index != reg;
    if (!first) continue;
    double sum_um = 0.0;
    for (std::size_t j = i; j < applies_.size(); ++j) {
      if (applies_[j].register_index == reg) sum_um += trims_um_[j];
    }
    out.trims.push(core::OffsetWrite{now_ns, reg, sum_um});
  }
}

double ModelModule::tool_wear_trim_um(std::uint16_t register_index) const noexcept {
  return register_index < wear_in_force_um_.size() ? wear_in_force_um_[register_index] : 0.0;
}

void ModelModule::trim_in_force(std::uint16_t register_index) noexcept {
  if (register_index >= wear_in_force_um_.size()) return;
  double wear_um = 0.0;
  double sum_um = 0.0;
  for (std::size_t i = 0; i < applies_.size(); ++i) {
    if (applies_[i].register_index != register_index) continue;
    sum_um += trims_um_[i];
    if (!(std::fabs(applies_[i].kind) > 0.0)) wear_um += trims_um_[i];
  }
  wear_in_force_um_[register_index] = wear_um;
  in_force_um_[register_index] = sum_um;
}

void ModelModule::observe_record(const core::MeasurementRecord& record) noexcept {
  if (model_.session_term() < 0) return;
  // The record's row as the log has it (time since the warm start, its session), the extra
  // columns from their sensors now.
  Row row = unknown_row();
  row[col(Column::kTime)] = static_cast<double>(record.time_ns) * 1e-9;
  row[col(Column::kPart)] = record.part;
  row[col(Column::kTool)] = record.tool;
  row[col(Column::kKind)] = static_cast<double>(record.kind);
  row[col(Column::kPoint)] = record.point;
  row[col(Column::kX)] = record.position_mm[0];
  row[col(Column::kY)] = record.position_mm[1];
  row[col(Column::kZ)] = record.position_mm[2];
  row[col(Column::kAngle)] = record.angle_deg;
  row[col(Column::kPath)] = record.path_mm;
  row[col(Column::kTemp)] = record.temp_c;
  row[kSessionColumn] = static_cast<double>(record.session);
  for (const ModelInput& in : inputs_) {
    row[static_cast<std::size_t>(in.column)] = context_->temperature_c(in.sensor);
  }
  const double before = state_.session.count;
  const double session_before = state_.session.session;
  model_.observe(row, record.measured_um + record.applied_um, state_);
  if (state_.session.count > before ||
      std::memcmp(&state_.session.session, &session_before, sizeof(double)) != 0) {
    ++generation_;
    dirty_ = true;  // the trims change with the offset
  }
}

double ModelModule::session_offset_um() const noexcept {
  const int k = model_.session_term();
  if (k < 0) return 0.0;
  const TermSpec& s = model_.specs()[static_cast<std::size_t>(k)];
  return session_posterior_um(state_.session.count, state_.session.sum_um, s.scale, s.center);
}

std::size_t ModelModule::state_capacity() const noexcept {
  return model_.session_term() < 0 ? 0 : kSessionStateBytes;
}

std::size_t ModelModule::save_state(std::span<std::byte> buf) const noexcept {
  if (model_.session_term() < 0 || buf.size() < kSessionStateBytes) return 0;
  std::byte* p = buf.data();
  std::memcpy(p, &kSessionMagic, 4);
  std::memcpy(p + 4, &kSessionVersion, 4);
  std::memcpy(p + 8, &state_.session.session, sizeof(double));
  std::memcpy(p + 16, &state_.session.count, sizeof(double));
  std::memcpy(p + 24, &state_.session.sum_um, sizeof(double));
  return kSessionStateBytes;
}

bool ModelModule::load_state(std::span<const std::byte> bytes) noexcept {
  if (bytes.empty()) {
    dirty_ = true;  // the engine does not save trims: publish them again on the next step
    return true;
  }
  if (bytes.size() == kSessionStateBytes) {
    std::uint32_t magic = 0;
    std::uint32_t version = 0;
    SessionLearning l;
    std::memcpy(&magic, bytes.data(), 4);
    std::memcpy(&version, bytes.data() + 4, 4);
    std::memcpy(&l.session, bytes.data() + 8, sizeof(double));
    std::memcpy(&l.count, bytes.data() + 16, sizeof(double));
    std::memcpy(&l.sum_um, bytes.data() + 24, sizeof(double));
    if (magic != kSessionMagic || version != kSessionVersion || !(l.count >= 0.0) ||
        !std::isfinite(l.count) || !std::isfinite(l.sum_um)) {
      return false;
    }
    // A model without a session term (a reload that dropped it) has nothing to continue.
    if (model_.session_term() >= 0) state_.session = l;
    dirty_ = true;
    return true;
  }
  // An earlier version's state: magic, part, tool, flags (16 bytes), then the cut path (24).
  if (bytes.size() != 16 && bytes.size() != 24) return false;
  std::uint32_t magic = 0;
  std::uint32_t flags = 0;
  std::int32_t part = 0;
  std::memcpy(&magic, bytes.data(), 4);
  std::memcpy(&part, bytes.data() + 4, 4);
  std::memcpy(&flags, bytes.data() + 12, 4);
  if (magic != kLegacyMagic || flags > 3U) return false;
  has_restored_part_ = (flags & 1U) != 0;
  restored_part_ = part;
  dirty_ = true;
  return true;
}

std::size_t ModelModule::status(std::span<core::engine::StatusValue> out) const noexcept {
  std::size_t n = 0;
  auto put = [&](const char* key, double v) {
    if (n < out.size()) out[n++] = core::engine::StatusValue{key, v, nullptr};
  };
  const core::engine::MachineContext& c = *context_;
  const double part = c.has_part()         ? static_cast<double>(c.part())
                      : has_restored_part_ ? static_cast<double>(restored_part_)
                                           : -1.0;  // -1: no part start seen yet
  put("part", part);
  put("applied_terms", static_cast<double>(applies_.size()));
  put("machine_time_s", c.machine_time_s());
  put("cut_path_mm", c.cut_path_mm());
  if (!trims_um_.empty()) put("first_trim_um", trims_um_[0]);
  if (model_.session_term() >= 0) {
    put("session_offset_um", session_offset_um());
    put("session_measurements", state_.session.count);
  }
  return n;
}

}  // namespace nccomp::core::model
