#include "core/checkpoint/module.hpp"

#include <cmath>
#include <cstring>
#include <iterator>
#include <stdexcept>
#include <type_traits>
#include <utility>

#include "core/common/config_issue.hpp"

namespace nccomp::core::checkpoint {

namespace {

constexpr std::uint32_t kMagic = 0x31504B43;  // "CKP1"
// 4: the model inputs and the trims of each checkpoint's last cut; 3: its tool and cut path only;
// 2: the estimator's variance and filter count per checkpoint. 1 to 3 are converted when loaded.
constexpr std::uint32_t kVersion = 4;

struct Header {
  std::uint32_t magic;
  std::uint32_t version;
  std::uint32_t count;
  std::int32_t part;
  std::int64_t part_counter;
};

struct RecordV1 {
  double learned_um;
  double offset_um;
  double applied_um;
  std::uint32_t count;
  std::uint32_t history_n;
  double history[kHistoryDepth];
};

struct Record {
  RecordV1 v1;
  double variance_um2;
  std::uint32_t filter_n;
  std::uint32_t reserved;
};

struct RecordV3 {
  Record v2;
  double cut_path_mm;
  std::int32_t cut_tool;
  std::uint32_t reserved;
};

struct RecordV4 {
  Record v2;
  engine::InputSnapshot cut_inputs;
  double cut_trim_um;
};

static_assert(std::is_trivially_copyable_v<Header> && std::is_trivially_copyable_v<RecordV4>);
static_assert(sizeof(RecordV1) == 160 && sizeof(Record) == 176 && sizeof(RecordV3) == 192 &&
                  sizeof(engine::InputSnapshot) == 152 && sizeof(RecordV4) == 336,
              "the state file's layout");

std::size_t record_size(std::uint32_t version) {
  switch (version) {
    case 1:
      return sizeof(RecordV1);
    case 2:
      return sizeof(Record);
    case 3:
      return sizeof(RecordV3);
    case kVersion:
      return sizeof(RecordV4);
    default:
      return 0;
  }
}

}  // namespace

CheckpointModule::CheckpointModule(CompensatorConfig config, std::vector<Checkpoint> plan,
                                   std::string name)
    : config_(config), plan_(std::move(plan)), name_(std::move(name)) {}

void CheckpointModule::attach(const engine::RegisterTable& registers) {
  const std::size_t n = plan_.size();
  const std::size_t first = config_.register_base;
  if (n == 0 || first + n > registers.size()) {
    throw ConfigInvalid("checkpoints.register_base", "registers " + std::to_string(first) + ".." +
                                                         std::to_string(first + n - 1) +
                                                         " are needed for " + std::to_string(n) +
                                                         " checkpoints, the register table has " +
                                                         std::to_string(registers.size()));
  }
  for (std::size_t i = first; i < first + n; ++i) {
    if (registers[i].kind != engine::RegisterKind::kCheckpoint) {
      throw ConfigInvalid("checkpoints.register_base", "register " + std::to_string(i) + " (\"" +
                                                           registers[i].name +
                                                           "\") must be of kind checkpoint");
    }
  }
  LimiterConfig limits = registers[first].limits;
  if (config_.active_register >= 0) {
    const auto a = static_cast<std::size_t>(config_.active_register);
    if (a >= registers.size() || registers[a].kind != engine::RegisterKind::kToolRadiusWear) {
      throw ConfigInvalid("checkpoints.active_register",
                          "register " + std::to_string(a) + " must be of kind tool_radius_wear");
    }
    limits = registers[a].limits;
  }
  compensator_.configure(config_, plan_, limits);
}

void CheckpointModule::step(TimeNs now_ns, std::span<const Event> events,
                            StepOutput& out) noexcept {
  compensator_.step(now_ns, events, out);
  if (context_ == nullptr || compensator_.cut_first() == compensator_.cut_last()) {
    return;
  }
  const engine::InputSnapshot inputs = engine::snapshot(*context_);
  for (std::size_t i = compensator_.cut_first(); i < compensator_.cut_last(); ++i) {
    // The register the wall is cut with: the live one, else the checkpoint's own.
    const auto reg = static_cast<std::uint16_t>(
        config_.active_register >= 0 ? static_cast<std::size_t>(config_.active_register)
                                     : config_.register_base + i);
    double trim_um = 0.0;
    for (const engine::ToolWearTrimSource* src : trim_sources_) {
      trim_um += src->trim_in_force_um(reg);
    }
    compensator_.record_cut(i, inputs, trim_um);
  }
}

bool CheckpointModule::adopt_output(std::uint16_t register_index, double nc_value_um,
                                    TimeNs now_ns) {
  if (!std::isfinite(nc_value_um)) {
    return false;
  }
  if (config_.active_register >= 0 && register_index == config_.active_register) {
    compensator_.reset_live(nc_value_um, now_ns);
    return true;
  }
  if (register_index < config_.register_base) {
    return false;
  }
  return compensator_.adopt_register_value(
      static_cast<std::size_t>(register_index - config_.register_base), nc_value_um);
}

bool CheckpointModule::rebase_output(std::uint16_t register_index, double delta_um,
                                     TimeNs now_ns) noexcept {
  return rebase(register_index, delta_um, now_ns, nullptr);
}

bool CheckpointModule::rebase_output_along(std::uint16_t register_index, double delta_um,
                                           const engine::TrimChange& change,
                                           TimeNs now_ns) noexcept {
  return rebase(register_index, delta_um, now_ns, &change);
}

bool CheckpointModule::rebase(std::uint16_t register_index, double delta_um, TimeNs now_ns,
                              const engine::TrimChange* along) noexcept {
  const std::size_t n = compensator_.size();
  if (n == 0) {
    return false;
  }
  if (config_.active_register >= 0 && register_index == config_.active_register) {
    return compensator_.rebase(0, n - 1, delta_um, now_ns, along, true);
  }
  if (register_index < config_.register_base) {
    return false;
  }
  const auto i = static_cast<std::size_t>(register_index - config_.register_base);
  if (i >= n) {
    return false;
  }
  // A table register's trims cut the wall only without a live register.
  return compensator_.rebase(i, i, delta_um, now_ns, along, config_.active_register < 0);
}

std::size_t CheckpointModule::state_capacity() const noexcept {
  return sizeof(Header) + plan_.size() * sizeof(RecordV4);
}

std::size_t CheckpointModule::save_state(std::span<std::byte> buf) const noexcept {
  const std::size_t need = state_capacity();
  if (buf.size() < need || compensator_.size() != plan_.size()) {
    return 0;
  }
  // Records are copied field by field: export_state() would allocate.
  Header h{kMagic, kVersion, static_cast<std::uint32_t>(plan_.size()), compensator_.part(),
           compensator_.part_counter()};
  std::memcpy(buf.data(), &h, sizeof h);
  std::byte* p = buf.data() + sizeof h;
  for (std::size_t i = 0; i < plan_.size(); ++i) {
    const LearnedPoint& lp = compensator_.point(i);
    RecordV4 r{};
    r.v2.v1.learned_um = lp.learned_um;
    r.v2.v1.offset_um = lp.offset_um;
    r.v2.v1.applied_um = lp.applied_um;
    r.v2.v1.count = lp.count;
    r.v2.v1.history_n = lp.history_n;
    for (std::size_t k = 0; k < kHistoryDepth; ++k) r.v2.v1.history[k] = lp.history[k];
    r.v2.variance_um2 = lp.variance_um2;
    r.v2.filter_n = lp.filter_n;
    r.cut_inputs = lp.cut_inputs;
    r.cut_trim_um = lp.cut_trim_um;
    std::memcpy(p, &r, sizeof r);
    p += sizeof r;
  }
  return need;
}

bool CheckpointModule::load_state(std::span<const std::byte> bytes) noexcept {
  if (bytes.empty()) {
    return true;  // no state yet: start fresh
  }
  Header h{};
  if (bytes.size() < sizeof h) {
    return false;
  }
  std::memcpy(&h, bytes.data(), sizeof h);
  // Version 1 has no filter: its checkpoints start the filter at the next reading from M.
  // Versions 1 and 2 do not know where the last cuts were (NaN), version 3 only their tool and
  // cut path (the other inputs and the trims: NaN).
  const std::size_t size = record_size(h.version);
  if (h.magic != kMagic || size == 0 || h.count != plan_.size() ||
      bytes.size() != sizeof h + plan_.size() * size) {
    return false;
  }
  const auto record = [&](std::size_t i) {
    RecordV4 r{};
    r.cut_trim_um = kNaN;
    const std::byte* at = bytes.data() + sizeof h + i * size;
    if (h.version == 3) {
      RecordV3 v3{};
      std::memcpy(&v3, at, size);
      r.v2 = v3.v2;
      r.cut_inputs.path_mm = v3.cut_path_mm;
      if (std::isfinite(v3.cut_path_mm)) r.cut_inputs.tool = v3.cut_tool;
    } else {
      std::memcpy(&r, at, size);
    }
    LearnedPoint lp;
    lp.learned_um = r.v2.v1.learned_um;
    lp.offset_um = r.v2.v1.offset_um;
    lp.applied_um = r.v2.v1.applied_um;
    lp.count = r.v2.v1.count;
    lp.history_n = r.v2.v1.history_n;
    for (std::size_t k = 0; k < kHistoryDepth; ++k) lp.history[k] = r.v2.v1.history[k];
    lp.variance_um2 = r.v2.variance_um2;
    lp.filter_n = r.v2.filter_n;
    lp.cut_inputs = r.cut_inputs;
    lp.cut_trim_um = r.cut_trim_um;
    return lp;
  };
  // All or nothing: check every record before changing anything.
  for (std::size_t i = 0; i < plan_.size(); ++i) {
    if (compensator_.invalid_point_reason(record(i)) != nullptr) {
      return false;
    }
  }
  for (std::size_t i = 0; i < plan_.size(); ++i) {
    (void)compensator_.restore_point(i, record(i));
  }
  compensator_.restore_counters(h.part_counter, h.part);
  return true;
}

std::size_t CheckpointModule::status(std::span<engine::StatusValue> out) const noexcept {
  const auto& c = compensator_;
  // Bounded whatever the plan's size: counts, the range of the learned values over the whole
  // table, and every learned value of one checkpoint, the focus (the one last passed by the
  // finishing tool or last probed). Every checkpoint's offset is in the status's register list.
  std::size_t learned = 0;
  double lo = kNaN;
  double hi = kNaN;
  std::int32_t lo_id = -1;
  std::int32_t hi_id = -1;
  for (std::size_t i = 0; i < c.size(); ++i) {
    if (c.learned_count(i) == 0) continue;
    ++learned;
    const double v = c.learned_um(i);
    if (lo_id < 0 || v < lo) {
      lo = v;
      lo_id = static_cast<std::int32_t>(i);
    }
    if (hi_id < 0 || v > hi) {
      hi = v;
      hi_id = static_cast<std::int32_t>(i);
    }
  }
  const std::int32_t f = c.focus_checkpoint();
  const bool has_focus = f >= 0 && static_cast<std::size_t>(f) < c.size();
  const auto fi = static_cast<std::size_t>(has_focus ? f : 0);
  const auto& k = c.counters();
  const engine::StatusValue values[] = {
      {"checkpoints", static_cast<double>(c.size()), nullptr},
      {"learned", static_cast<double>(learned), nullptr},
      {"passed", static_cast<double>(c.passed()), nullptr},
      {"part", static_cast<double>(c.part()), nullptr},
      {"parts", static_cast<double>(c.part_counter()), nullptr},
      {"probe_readings", static_cast<double>(k.measurements), nullptr},
      {"implausible", static_cast<double>(k.implausible), nullptr},
      {"outliers", static_cast<double>(k.outliers), nullptr},
      {"learned_min_um", lo, nullptr},
      {"learned_min_checkpoint", static_cast<double>(lo_id), nullptr},
      {"learned_max_um", hi, nullptr},
      {"learned_max_checkpoint", static_cast<double>(hi_id), nullptr},
      {"checkpoint", static_cast<double>(has_focus ? f : -1), nullptr},
      {"checkpoint_learned_um", has_focus ? c.learned_um(fi) : kNaN, nullptr},
      {"checkpoint_count", has_focus ? static_cast<double>(c.learned_count(fi)) : kNaN, nullptr},
      {"checkpoint_offset_um", has_focus ? c.register_value_um(fi) : kNaN, nullptr},
  };
  std::size_t w = 0;
  for (const auto& v : values) {
    if (w == out.size()) break;
    out[w++] = v;
  }
  if (!c.config().estimator.enabled) {
    return w;
  }
  // The filter's uncertainty: the focus checkpoint's, and the largest over the table (a
  // <stem>_sigma_um key is the standard deviation of <stem>_estimate_um: a metric of its own).
  double sigma_max = kNaN;
  for (std::size_t i = 0; i < c.size(); ++i) {
    const double s = c.predicted_sigma_um(i);
    if (std::isfinite(s) && !(s <= sigma_max)) sigma_max = s;
  }
  const bool est_focus = has_focus && c.learned_count(fi) > 0;
  const engine::StatusValue est_values[] = {
      {"checkpoint_estimate_um", est_focus ? c.learned_um(fi) : kNaN, nullptr},
      {"checkpoint_sigma_um", has_focus ? c.predicted_sigma_um(fi) : kNaN, nullptr},
      {"checkpoint_gain", has_focus ? c.next_gain(fi) : kNaN, nullptr},
      {"sigma_max_um", sigma_max, nullptr},
  };
  static_assert(std::size(values) + std::size(est_values) <= engine::kMaxStatusValues);
  for (const auto& v : est_values) {
    if (w == out.size()) break;
    out[w++] = v;
  }
  return w;
}

std::vector<std::uint16_t> CheckpointModule::written_registers() const {
  std::vector<std::uint16_t> out;
  for (std::size_t i = 0; i < plan_.size(); ++i) {
    out.push_back(static_cast<std::uint16_t>(config_.register_base + i));
  }
  if (config_.active_register >= 0) {
    out.push_back(static_cast<std::uint16_t>(config_.active_register));
  }
  return out;
}

}  // namespace nccomp::core::checkpoint
