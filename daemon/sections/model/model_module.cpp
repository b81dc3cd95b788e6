#include "daemon/sections/model/model_module.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>

namespace nccomp::daemon::sections {

namespace {
constexpr std::uint32_t kMagic = 0x4D4F444CU;  // "MODL"
namespace cm = core::model;
}  // namespace

ModelModule::ModelModule(cm::Model model, std::vector<ModelApply> applies, bool update_each_cycle,
                         int temperature_sensor)
    : model_(std::move(model)),
      applies_(std::move(applies)),
      trims_um_(applies_.size(), 0.0),
      state_(model_.make_state()),
      each_cycle_(update_each_cycle),
      temperature_sensor_(temperature_sensor) {
  for (const auto& a : applies_) {
    if (a.term_index >= model_.terms().size()) {
      throw std::invalid_argument("model: term index " + std::to_string(a.term_index) +
                                  " beyond the model's " +
                                  std::to_string(model_.terms().size()) + " terms");
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
}

void ModelModule::on_tool(std::int32_t tool) noexcept {
  if (has_tool_ && tool == tool_) return;
  if (has_tool_) {
    cut_path_mm_ = 0.0;  // another tool: its own path since it was loaded
    saved_path_mm_ = 0.0;
  }
  tool_ = tool;
  has_tool_ = true;
  dirty_ = true;
  ++generation_;
}

void ModelModule::on_axis_sample(const core::AxisSample& a) noexcept {
  if (a.tool != 0) on_tool(a.tool);  // a tool change the bus did not report as an event
  const std::size_t n = std::min<std::size_t>(a.axis_count, position_mm_.size());
  for (std::size_t k = 0; k < n; ++k) {
    if (std::isfinite(a.position_mm[k])) position_mm_[k] = a.position_mm[k];
  }
  if (have_sample_ && a.cutting && last_sample_.cutting) {
    double d = 0.0;
    if (std::isfinite(a.program_path_mm) && std::isfinite(last_sample_.program_path_mm)) {
      d = a.program_path_mm - last_sample_.program_path_mm;
    } else {
      const std::size_t m =
          std::min<std::size_t>({a.axis_count, last_sample_.axis_count, std::size_t{3}});
      double sq = 0.0;
      for (std::size_t k = 0; k < m; ++k) {
        const double dk = a.position_mm[k] - last_sample_.position_mm[k];
        sq += dk * dk;
      }
      d = std::sqrt(sq);
    }
    if (std::isfinite(d) && d > 0.0) cut_path_mm_ += d;
    // Persist the path now and then (the state is saved when the generation advances).
    if (std::fabs(cut_path_mm_ - saved_path_mm_) >= 1.0) {
      saved_path_mm_ = cut_path_mm_;
      ++generation_;
    }
  }
  last_sample_ = a;
  have_sample_ = true;
}

void ModelModule::step(core::TimeNs now_ns, std::span<const core::Event> events,
                       core::StepOutput& out) noexcept {
  for (const core::Event& e : events) {
    if (const auto* as = std::get_if<core::AxisSample>(&e)) {
      on_axis_sample(*as);
    } else if (const auto* pe = std::get_if<core::ProgramEvent>(&e)) {
      if (pe->kind == core::ProgramEventKind::kPartStart && (!has_part_ || pe->part != part_)) {
        part_ = pe->part;
        has_part_ = true;
        dirty_ = true;
        ++generation_;
      }
    } else if (const auto* tc = std::get_if<core::ToolChange>(&e)) {
      on_tool(tc->tool);
    } else if (const auto* ts = std::get_if<core::TemperatureSample>(&e)) {
      if (static_cast<int>(ts->sensor) == temperature_sensor_) {
        temp_c_ = ts->temperature_c;
      }
    }
  }
  if (dirty_ || each_cycle_) {
    evaluate(now_ns, out);
    dirty_ = false;
  }
}

void ModelModule::evaluate(core::TimeNs now_ns, core::StepOutput& out) noexcept {
  // The context of "now": what the loop knows; unknown columns are NaN, and a term whose column
  // is unknown contributes nothing (e.g. part_trend before the first part start).
  cm::Row row = cm::unknown_row();
  row[static_cast<std::size_t>(cm::Column::kTime)] = static_cast<double>(now_ns) * 1e-9;
  if (has_part_) row[static_cast<std::size_t>(cm::Column::kPart)] = part_;
  if (has_tool_) row[static_cast<std::size_t>(cm::Column::kTool)] = tool_;
  row[static_cast<std::size_t>(cm::Column::kTemp)] = temp_c_;
  row[static_cast<std::size_t>(cm::Column::kX)] = position_mm_[0];
  row[static_cast<std::size_t>(cm::Column::kY)] = position_mm_[1];
  row[static_cast<std::size_t>(cm::Column::kZ)] = position_mm_[2];
  if (has_tool_ || have_sample_) row[static_cast<std::size_t>(cm::Column::kPath)] = cut_path_mm_;
  cm::advance_state(model_.specs(), row, state_);
  for (std::size_t i = 0; i < applies_.size(); ++i) {
    const ModelApply& a = applies_[i];
    row[static_cast<std::size_t>(cm::Column::kKind)] = a.kind;
    row[static_cast<std::size_t>(cm::Column::kPoint)] = a.point;
    if (!std::isnan(a.tool)) {
      row[static_cast<std::size_t>(cm::Column::kTool)] = a.tool;
    } else {
      row[static_cast<std::size_t>(cm::Column::kTool)] =
          has_tool_ ? static_cast<double>(tool_) : cm::kUnknown;
    }
    const double trim = a.gain * model_.evaluate_term(a.term_index, row, state_);
    // A non-finite trim goes to the engine, which refuses it with an alarm.
    trims_um_[i] = trim;
    out.trims.push(core::OffsetWrite{now_ns, a.register_index, trim});
  }
}

std::size_t ModelModule::save_state(std::span<std::byte> buf) const noexcept {
  if (buf.size() < kStateBytes) return 0;
  const std::uint32_t flags = (has_part_ ? 1U : 0U) | (has_tool_ ? 2U : 0U);
  std::memcpy(buf.data(), &kMagic, 4);
  std::memcpy(buf.data() + 4, &part_, 4);
  std::memcpy(buf.data() + 8, &tool_, 4);
  std::memcpy(buf.data() + 12, &flags, 4);
  std::memcpy(buf.data() + 16, &cut_path_mm_, 8);
  return kStateBytes;
}

bool ModelModule::load_state(std::span<const std::byte> bytes) noexcept {
  if (bytes.size() != kStateBytes && bytes.size() != kLegacyStateBytes) return false;
  std::uint32_t magic = 0;
  std::uint32_t flags = 0;
  std::int32_t part = 0;
  std::int32_t tool = 0;
  double path_mm = 0.0;
  std::memcpy(&magic, bytes.data(), 4);
  std::memcpy(&part, bytes.data() + 4, 4);
  std::memcpy(&tool, bytes.data() + 8, 4);
  std::memcpy(&flags, bytes.data() + 12, 4);
  if (bytes.size() == kStateBytes) std::memcpy(&path_mm, bytes.data() + 16, 8);
  if (magic != kMagic || flags > 3U || !std::isfinite(path_mm) || path_mm < 0.0) return false;
  part_ = part;
  tool_ = tool;
  has_part_ = (flags & 1U) != 0;
  has_tool_ = (flags & 2U) != 0;
  cut_path_mm_ = path_mm;
  saved_path_mm_ = path_mm;
  // The engine does not save trims: publish them again on the next step.
  dirty_ = true;
  return true;
}

std::size_t ModelModule::status(std::span<core::engine::StatusValue> out) const noexcept {
  std::size_t n = 0;
  auto put = [&](const char* key, double v) {
    if (n < out.size()) out[n++] = core::engine::StatusValue{key, v, nullptr};
  };
  put("part", has_part_ ? static_cast<double>(part_) : -1.0);  // -1: no part start seen yet
  put("applied_terms", static_cast<double>(applies_.size()));
  put("cut_path_mm", cut_path_mm_);
  if (!trims_um_.empty()) put("first_trim_um", trims_um_[0]);
  return n;
}

}  // namespace nccomp::daemon::sections
