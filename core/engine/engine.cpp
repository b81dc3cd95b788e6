#include "core/engine/engine.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <set>
#include <stdexcept>
#include <type_traits>
#include <utility>

#include "core/engine/tool_wear_trims.hpp"

namespace nccomp::core::engine {

namespace {

constexpr std::uint32_t kStateMagic = 0x4e45434eU;  // "NCEN"
constexpr std::uint32_t kStateVersion = 1;
constexpr std::size_t kMaxNameLength = 255;
/// The machine context's entry among the modules' states (no module name starts with '@').
constexpr std::string_view kContextEntry = "@context";
/// Every register's hold, by name: u32 count, then name and u8 RegisterHold per register (a fixed
/// size: state_capacity() stays exact). Only kWithoutState is restored from it: a hold beyond
/// the limit follows from the saved output (what the NC holds).
constexpr std::string_view kHoldsEntry = "@holds";
/// A read-back this close to 0 [µm] is no offset a module without state would lose (the
/// reference map's resolution is 0.1 µm): nothing to report, nothing to hold.
constexpr double kNoOffsetUm = 0.1;
/// The event cursors' entry (cursors.hpp); an engine without cursors skips it as unknown.
constexpr std::string_view kCursorsEntry = "@cursors";
/// The derived lag inputs (input_lag.hpp). A state without it (an older daemon): each lag
/// starts at its input's next value; an older engine skips it as unknown.
constexpr std::string_view kLagsEntry = "@lags";
/// Registers whose write was in flight (write receipts), by name: u32 count, then name and u8
/// (1 = in flight) per register, a fixed size like "@holds". An older engine skips it.
constexpr std::string_view kInFlightEntry = "@inflight";
/// Trim handover: u32 version, u32 count, then per register its name, the f64 sum of its trims
/// (0 without any) and the u64 identity of what computed them (0: no trim). An older engine
/// skips it; a state without it hands nothing over.
constexpr std::string_view kTrimsEntry = "@trims";
constexpr std::uint32_t kTrimsVersion = 1;

/// splitmix64's finaliser: spreads a module's name hash and trim identity over 64 bits.
std::uint64_t mix64(std::uint64_t x) noexcept {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30U)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27U)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31U);
}

std::uint64_t fnv1a(std::string_view s) noexcept {
  std::uint64_t h = 0xcbf29ce484222325ULL;
  for (const char c : s) {
    h = (h ^ static_cast<unsigned char>(c)) * 0x100000001b3ULL;
  }
  return h;
}

// Little helpers for the state bytes. Native byte order: the state never leaves the machine.
class Writer {
 public:
  explicit Writer(std::span<std::byte> buf) noexcept : buf_(buf) {}
  template <typename T>
  void put(const T& v) noexcept {
    static_assert(std::is_trivially_copyable_v<T>);
    if (ok_ && pos_ + sizeof(T) <= buf_.size()) {
      std::memcpy(buf_.data() + pos_, &v, sizeof(T));
      pos_ += sizeof(T);
    } else {
      ok_ = false;
    }
  }
  void put_bytes(const void* p, std::size_t n) noexcept {
    if (ok_ && pos_ + n <= buf_.size()) {
      if (n > 0) {
        std::memcpy(buf_.data() + pos_, p, n);
      }
      pos_ += n;
    } else {
      ok_ = false;
    }
  }
  void put_name(std::string_view s) noexcept {
    put(static_cast<std::uint16_t>(s.size()));
    put_bytes(s.data(), s.size());
  }
  [[nodiscard]] std::span<std::byte> rest() const noexcept { return buf_.subspan(pos_); }
  void skip(std::size_t n) noexcept {
    if (ok_ && pos_ + n <= buf_.size()) {
      pos_ += n;
    } else {
      ok_ = false;
    }
  }
  [[nodiscard]] bool ok() const noexcept { return ok_; }
  [[nodiscard]] std::size_t size() const noexcept { return pos_; }

 private:
  std::span<std::byte> buf_;
  std::size_t pos_{0};
  bool ok_{true};
};

class Reader {
 public:
  explicit Reader(std::span<const std::byte> bytes) noexcept : bytes_(bytes) {}
  template <typename T>
  bool get(T& v) noexcept {
    static_assert(std::is_trivially_copyable_v<T>);
    if (pos_ + sizeof(T) > bytes_.size()) {
      return false;
    }
    std::memcpy(&v, bytes_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return true;
  }
  bool get_span(std::size_t n, std::span<const std::byte>& out) noexcept {
    if (n > bytes_.size() - pos_) {
      return false;
    }
    out = bytes_.subspan(pos_, n);
    pos_ += n;
    return true;
  }
  bool get_name(std::string_view& out) noexcept {
    std::uint16_t n = 0;
    std::span<const std::byte> s;
    if (!get(n) || !get_span(n, s)) {
      return false;
    }
    out = std::string_view(reinterpret_cast<const char*>(s.data()), s.size());
    return true;
  }
  [[nodiscard]] bool at_end() const noexcept { return pos_ == bytes_.size(); }

 private:
  std::span<const std::byte> bytes_;
  std::size_t pos_{0};
};

bool finite_or_nan(double v) { return std::isfinite(v) || std::isnan(v); }

template <std::size_t N>
bool all_finite(const std::array<double, N>& a, std::size_t n) {
  for (std::size_t i = 0; i < n && i < N; ++i) {
    if (!std::isfinite(a[i])) {
      return false;
    }
  }
  return true;
}

bool valid_fault(InputFault f) { return static_cast<std::uint8_t>(f) <= 2; }

}  // namespace

std::string_view to_string(RegisterKind kind) noexcept {
  switch (kind) {
    case RegisterKind::kToolLengthWear:
      return "tool_length_wear";
    case RegisterKind::kToolRadiusWear:
      return "tool_radius_wear";
    case RegisterKind::kCheckpoint:
      return "checkpoint";
    case RegisterKind::kAxisOffset:
      return "axis_offset";
    case RegisterKind::kFlag:
      return "flag";
  }
  return "unknown";
}

bool parse_register_kind(std::string_view name, RegisterKind& out) noexcept {
  for (auto k : {RegisterKind::kToolLengthWear, RegisterKind::kToolRadiusWear,
                 RegisterKind::kCheckpoint, RegisterKind::kAxisOffset, RegisterKind::kFlag}) {
    if (to_string(k) == name) {
      out = k;
      return true;
    }
  }
  return false;
}

std::string_view to_string(RegisterHold hold) noexcept {
  switch (hold) {
    case RegisterHold::kNone:
      return "none";
    case RegisterHold::kBeyondLimit:
      return "beyond_limit";
    case RegisterHold::kWithoutState:
      return "without_state";
  }
  return "unknown";
}

int RegisterTable::find(std::string_view name) const noexcept {
  for (std::size_t i = 0; i < specs_->size(); ++i) {
    if ((*specs_)[i].name == name) {
      return static_cast<int>(i);
    }
  }
  return -1;
}

void Engine::configure(std::vector<RegisterSpec> registers,
                       std::vector<std::unique_ptr<Module>> modules, EngineOptions options) {
  if (registers.size() > 0xFFFFU) {
    throw std::invalid_argument("engine: more than 65535 registers");
  }
  if (options.max_events_per_step == 0) {
    throw std::invalid_argument("engine: max_events_per_step must be at least 1");
  }
  std::set<std::string, std::less<>> names;
  std::vector<Reg> regs(registers.size());
  for (std::size_t i = 0; i < registers.size(); ++i) {
    const auto& r = registers[i];
    if (r.name.empty() || r.name.size() > kMaxNameLength) {
      throw std::invalid_argument("engine: register " + std::to_string(i) +
                                  ": name must have 1 to 255 characters");
    }
    if (!names.insert(r.name).second) {
      throw std::invalid_argument("engine: register name '" + r.name + "' is used twice");
    }
    try {
      regs[i].limiter.configure(r.limits);
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("engine: register '" + r.name + "': " + e.what());
    }
  }
  specs_ = std::move(registers);
  const RegisterTable table(specs_);
  std::set<std::string, std::less<>> module_names;
  std::size_t capacity = sizeof(std::uint32_t) * 3;
  for (const auto& s : specs_) {
    capacity += sizeof(std::uint16_t) + s.name.size() + 2 * sizeof(double) + 1;
  }
  capacity += sizeof(std::uint32_t);
  for (auto& m : modules) {
    if (!m) {
      throw std::invalid_argument("engine: null module");
    }
    const std::string name(m->name());
    if (name.empty() || name.size() > kMaxNameLength) {
      throw std::invalid_argument("engine: module name must have 1 to 255 characters");
    }
    if (!module_names.insert(name).second) {
      throw std::invalid_argument("engine: module name '" + name + "' is used twice");
    }
    if (name.front() == '@') {
      throw std::invalid_argument("engine: module name '" + name + "' may not start with '@'");
    }
    m->attach(table);
    capacity += sizeof(std::uint16_t) + name.size() + sizeof(std::uint32_t) + m->state_capacity();
  }
  capacity += sizeof(std::uint16_t) + kContextEntry.size() + sizeof(std::uint32_t) +
              MachineContext::kStateBytes;
  capacity += sizeof(std::uint16_t) + kHoldsEntry.size() + 2 * sizeof(std::uint32_t);
  for (const auto& r : specs_) {
    capacity += sizeof(std::uint16_t) + r.name.size() + sizeof(std::uint8_t);
  }
  capacity += sizeof(std::uint16_t) + kCursorsEntry.size() + sizeof(std::uint32_t) +
              EventCursors::kStateBytes;
  capacity +=
      sizeof(std::uint16_t) + kLagsEntry.size() + sizeof(std::uint32_t) + InputLags::kStateBytes;
  capacity += sizeof(std::uint16_t) + kInFlightEntry.size() + 2 * sizeof(std::uint32_t);
  for (const auto& r : specs_) {
    capacity += sizeof(std::uint16_t) + r.name.size() + sizeof(std::uint8_t);
  }
  capacity += sizeof(std::uint16_t) + kTrimsEntry.size() + 3 * sizeof(std::uint32_t);
  for (const auto& r : specs_) {
    capacity += sizeof(std::uint16_t) + r.name.size() + sizeof(double) + sizeof(std::uint64_t);
  }
  // The context's options: from the one module that sets them (the daemon's
  // [measurement_context] section), else from the engine options.
  ContextOptions context_options = options.context;
  const Module* options_from = nullptr;
  for (const auto& m : modules) {
    if (const ContextOptions* o = m->context_options()) {
      if (options_from != nullptr) {
        throw std::invalid_argument("engine: modules '" + std::string(options_from->name()) +
                                    "' and '" + std::string(m->name()) +
                                    "' both set the measurement context options");
      }
      options_from = m.get();
      context_options = *o;
    }
  }
  MachineContext context;
  try {
    context.configure(context_options);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("engine: measurement context: ") + e.what());
  }
  InputLags lags;
  try {
    lags.configure(options.lags);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("engine: input ") + e.what());
  }
  InputSums sums;
  try {
    sums.configure(options.sums, options.lags);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("engine: input ") + e.what());
  }
  // One writer per register: two modules on one register would overwrite each other's target
  // every cycle (an oscillating offset on the machine).
  std::vector<int> writer(specs_.size(), -1);
  for (std::size_t k = 0; k < modules.size(); ++k) {
    for (const std::uint16_t r : modules[k]->written_registers()) {
      if (r >= writer.size()) {
        continue;  // attach() already refused unknown registers
      }
      if (writer[r] >= 0 && static_cast<std::size_t>(writer[r]) != k) {
        throw std::invalid_argument(
            "engine: register '" + specs_[r].name + "' is written by module '" +
            std::string(modules[static_cast<std::size_t>(writer[r])]->name()) + "' and by '" +
            std::string(modules[k]->name()) + "'; give each module its own registers");
      }
      writer[r] = static_cast<int>(k);
    }
  }
  regs_ = std::move(regs);
  writer_ = std::move(writer);
  module_state_.assign(modules.size(), ModuleStateSource::kFresh);
  modules_ = std::move(modules);
  options_ = options;
  context_ = context;
  cursors_ = EventCursors{};
  for (auto& m : modules_) m->bind_context(context_);
  valid_.clear();
  lags_ = lags;
  sums_ = sums;
  valid_.reserve(options.max_events_per_step + kMaxInputLags + kMaxInputSums);
  trims_.assign(modules_.size() * regs_.size(), std::numeric_limits<double>::quiet_NaN());
  // The tool wear some trims predict, for the module that learns it from the tool measurement.
  std::vector<const ToolWearTrimSource*> wear_sources;
  wear_source_of_.assign(modules_.size(), nullptr);
  for (std::size_t k = 0; k < modules_.size(); ++k) {
    if (auto* s = dynamic_cast<ToolWearTrimSource*>(modules_[k].get())) {
      wear_sources.push_back(s);
      wear_source_of_[k] = s;
    }
  }
  for (auto& m : modules_) {
    if (auto* u = dynamic_cast<ToolWearTrimUser*>(m.get())) u->bind_tool_wear_trims(wear_sources);
  }
  handover_trim_um_.assign(regs_.size(), 0.0);
  handover_identity_.assign(regs_.size(), 0);
  handover_known_.assign(regs_.size(), 0);
  handover_pending_ = false;
  state_capacity_ = capacity;
  counters_ = {};
  write_cursor_ = 0;
  register_generation_ = 0;
  notices_pending_ = 0;
}

bool Engine::validate(const Event& e) const noexcept {
  return std::visit(
      [this](const auto& ev) -> bool {
        using T = std::decay_t<decltype(ev)>;
        if constexpr (std::is_same_v<T, AxisSample>) {
          if (ev.axis_count > kMaxAxes || !all_finite(ev.position_mm, ev.axis_count) ||
              !finite_or_nan(ev.program_path_mm)) {
            return false;
          }
          return !ev.has_normal || all_finite(ev.normal, 3);
        } else if constexpr (std::is_same_v<T, ToolMeasurement>) {
          if (!valid_fault(ev.fault)) {
            return false;
          }
          if (ev.broken) {
            return true;  // the wear values of a broken-tool report are meaningless
          }
          return ev.point_count >= 1 && ev.point_count <= kMaxEdgePoints &&
                 all_finite(ev.wear_um, ev.point_count);
        } else if constexpr (std::is_same_v<T, ProbeMeasurement>) {
          return valid_fault(ev.fault) && std::isfinite(ev.raw_deviation_um) &&
                 std::isfinite(ev.wall_angle_deg) && std::isfinite(ev.ball_radius_mm) &&
                 ev.ball_radius_mm >= 0.0 && all_finite(ev.position_mm, 3);
        } else if constexpr (std::is_same_v<T, CalibrationTouch>) {
          return valid_fault(ev.fault) && std::isfinite(ev.trigger_position_mm) && ev.axis <= 2 &&
                 (ev.direction == 1 || ev.direction == -1) &&
                 static_cast<std::uint8_t>(ev.probe) <= 1;
        } else if constexpr (std::is_same_v<T, ProgramEvent>) {
          return static_cast<std::uint8_t>(ev.kind) <= 3;
        } else if constexpr (std::is_same_v<T, TemperatureSample>) {
          return std::isfinite(ev.temperature_c);
        } else if constexpr (std::is_same_v<T, OperatorCommand>) {
          // The machine context's own command (the other kinds are checked by the module that
          // takes them): code[0] = 0 (warm start now) or 1 (at the next motion), nothing else.
          if (ev.kind == OperatorCommandKind::kWarmStart) {
            return (ev.code[0] == 0 || ev.code[0] == 1) && ev.code[1] == 0 && ev.code[2] == 0 &&
                   ev.code[3] == 0 && ev.sequence > 0;
          }
          // The operator's acknowledgement of latched alarms (every module): all codes 0.
          if (ev.kind == OperatorCommandKind::kAcknowledge) {
            return ev.code[0] == 0 && ev.code[1] == 0 && ev.code[2] == 0 && ev.code[3] == 0 &&
                   ev.sequence > 0;
          }
          // The release of a held register: value[0] = its index (an integer), or -1 = all.
          if (ev.kind == OperatorCommandKind::kRegisterRelease) {
            const double r = ev.value[0];
            return ev.code[0] == 0 && ev.code[1] == 0 && ev.code[2] == 0 && ev.code[3] == 0 &&
                   ev.sequence > 0 && std::fabs(ev.value[1]) <= 0.0 && std::isfinite(r) &&
                   std::fabs(r - std::trunc(r)) <= 0.0 && r >= -1.0 &&
                   r < static_cast<double>(regs_.size());
          }
          return true;
        } else {
          return true;  // ToolChange: every field is valid
        }
      },
      e);
}

void Engine::accept_target(const OffsetWrite& w, TimeNs now_ns, StepOutput& out) noexcept {
  if (w.register_index >= regs_.size()) {
    ++counters_.writes_unknown_register;
    out.alarm(now_ns, Severity::kAlarm, AlarmCode::kRegisterUnknown, w.register_index, w.value_um);
    return;
  }
  Reg& r = regs_[w.register_index];
  // The register is sent target + trims: the sum is what must be admissible.
  if (!r.limiter.admissible(w.value_um + r.trim_um)) {
    ++counters_.writes_rejected;
    const AlarmCode code = std::isfinite(w.value_um) ? AlarmCode::kOffsetBeyondAbsoluteLimit
                                                     : AlarmCode::kOffsetNonFinite;
    out.alarm(now_ns, Severity::kAlarm, code, w.register_index, w.value_um);
    return;
  }
  if (!r.has_target || std::memcmp(&r.target_um, &w.value_um, sizeof(double)) != 0) {
    ++register_generation_;
  }
  r.target_um = w.value_um;
  r.has_target = true;
}

void Engine::accept_trim(std::size_t module, const OffsetWrite& w, TimeNs now_ns,
                         StepOutput& out) noexcept {
  if (w.register_index >= regs_.size()) {
    ++counters_.writes_unknown_register;
    out.alarm(now_ns, Severity::kAlarm, AlarmCode::kRegisterUnknown, w.register_index, w.value_um);
    return;
  }
  const std::size_t n = regs_.size();
  Reg& r = regs_[w.register_index];
  // The new sum from every module's trim (exact, no running total that drifts).
  double sum_um = 0.0;
  for (std::size_t m = 0; m < modules_.size(); ++m) {
    const double t = m == module ? w.value_um : trims_[m * n + w.register_index];
    if (!std::isnan(t) || m == module) {
      sum_um += t;
    }
  }
  const double base_um = r.has_target ? r.target_um : 0.0;
  if (!std::isfinite(w.value_um) || !r.limiter.admissible(base_um + sum_um) ||
      specs_[w.register_index].kind == RegisterKind::kFlag) {
    ++counters_.writes_rejected;
    const AlarmCode code = std::isfinite(w.value_um) ? AlarmCode::kOffsetBeyondAbsoluteLimit
                                                     : AlarmCode::kOffsetNonFinite;
    out.alarm(now_ns, Severity::kAlarm, code, w.register_index, base_um + sum_um);
    return;
  }
  double& slot = trims_[module * n + w.register_index];
  if (std::isnan(slot) || std::memcmp(&slot, &w.value_um, sizeof(double)) != 0) {
    ++register_generation_;
  }
  slot = w.value_um;
  r.trim_um = sum_um;
  r.has_trim = true;
  if (wear_source_of_[module] != nullptr) wear_source_of_[module]->trim_in_force(w.register_index);
}

void Engine::step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept {
  out.clear();
  ++counters_.steps;
  if (notices_pending_ > 0) {
    // The start-up holds and adoptions (and a reload's), once each.
    for (std::size_t i = 0; i < regs_.size(); ++i) {
      Reg& r = regs_[i];
      if (r.notice == AlarmCode::kNone) continue;
      const Severity sev =
          r.notice == AlarmCode::kRegisterBeyondLimit ? Severity::kAlarm : Severity::kWarning;
      out.alarm(now_ns, sev, r.notice, static_cast<std::int32_t>(i), r.notice_value);
      r.notice = AlarmCode::kNone;
    }
    notices_pending_ = 0;
  }
  valid_.clear();
  for (const Event& in : events) {
    // Taken, whatever becomes of it: a restart must not deliver it again.
    cursors_.take(in);
    if (const EventOrigin* o = origin_of(in); o != nullptr && o->counter_only) {
      continue;
    }
    // A faulted measurement reaches the modules with every value 0, whatever the driver left.
    Event e = in;
    set_fault(e, fault_of(e));
    if (!validate(e)) {
      ++counters_.events_invalid;
      out.alarm(now_ns, Severity::kWarning, AlarmCode::kEventInvalid,
                static_cast<std::int32_t>(e.index()), 0.0);
      continue;
    }
    if (valid_.size() == options_.max_events_per_step) {
      ++counters_.events_overflow;
      continue;
    }
    valid_.push_back(e);  // capacity reserved in configure(): no allocation
    ++counters_.events_accepted;
    if (const auto* c = std::get_if<OperatorCommand>(&e);
        c != nullptr && c->kind == OperatorCommandKind::kAcknowledge) {
      // Every module steps with it below, in this cycle: the sender waits for this sequence.
      ++counters_.acknowledge_commands;
      counters_.last_acknowledge_sequence = c->sequence;
    } else if (c != nullptr && c->kind == OperatorCommandKind::kRegisterRelease) {
      // Before the modules step: the released registers are written in this cycle.
      std::uint32_t released = 0;
      if (c->value[0] < 0.0) {
        for (std::size_t i = 0; i < regs_.size(); ++i) {
          released += release_register(i, now_ns) ? 1U : 0U;
        }
      } else {
        released = release_register(static_cast<std::size_t>(c->value[0]), now_ns) ? 1U : 0U;
      }
      ++counters_.release_commands;
      counters_.last_release_sequence = c->sequence;
      counters_.last_release_count = released;
    }
  }
  {
    // The lags' samples after the cycle's events (capacity reserved in configure()).
    const std::size_t n = valid_.size();
    valid_.resize(n + lags_.size());
    valid_.resize(lags_.update(now_ns, std::span<const Event>(valid_.data(), n), valid_, n));
    // The sums' samples after the lags': a sum of a lag's output takes its value of this cycle.
    const std::size_t m = valid_.size();
    valid_.resize(m + sums_.size());
    valid_.resize(sums_.update(now_ns, std::span<const Event>(valid_.data(), m), valid_, m));
  }
  const std::span<const Event> accepted(valid_.data(), valid_.size());
  // The context first: modules that evaluate it see this cycle's samples.
  context_.update(now_ns, accepted);
  counters_.warm_start_commands = context_.warm_start_commands();
  counters_.last_warm_start_sequence = context_.last_command_sequence();
  counters_.warm_starts = context_.warm_starts();

  for (std::size_t k = 0; k < modules_.size(); ++k) {
    scratch_.clear();
    modules_[k]->step(now_ns, accepted, scratch_);
    for (const auto& w : scratch_.writes) {
      accept_target(w, now_ns, out);
    }
    for (const auto& t : scratch_.trims) {
      accept_trim(k, t, now_ns, out);
    }
    for (const auto& a : scratch_.alarms) {
      out.alarms.push(a);
    }
    for (MeasurementRecord rec : scratch_.records) {
      context_.annotate(rec);
      out.records.push(rec);
    }
  }

  for (const MeasurementRecord& rec : out.records) {
    for (auto& m : modules_) m->observe_record(rec);
  }

  if (handover_pending_) {
    hand_over_trims(now_ns);
  }

  // Every register with a target converges through its limiter, whether or not a module wrote
  // this cycle: a slewed target keeps moving without the module repeating it. The scan starts
  // where the last full cycle stopped, so with more pending registers than one StepOutput holds
  // (a large S1 table slewing) every register gets its turn instead of the first 128 forever.
  const std::size_t n = regs_.size();
  std::size_t first_deferred = n;
  for (std::size_t k = 0; k < n; ++k) {
    const std::size_t i = (write_cursor_ + k) % n;
    Reg& r = regs_[i];
    if (!r.has_target && !r.has_trim && !r.resend_as_is) {
      continue;
    }
    const double goal_um = (r.has_target ? r.target_um : 0.0) + r.trim_um;
    const bool at_target = r.sent && std::memcmp(&r.sent_um, &goal_um, sizeof(double)) == 0;
    if (at_target && !r.resend_as_is) {
      continue;
    }
    if (r.hold != RegisterHold::kNone) {
      ++counters_.writes_blocked;
      continue;
    }
    if (hold_) {
      ++counters_.writes_held;
      continue;
    }
    const bool flag = specs_[i].kind == RegisterKind::kFlag;
    if (r.in_flight != 0 && !flag) {
      // The bus may still replace the write in flight by this one: the NC would see both steps
      // as one. The next write waits, and is limited from what the NC then holds.
      ++counters_.writes_awaiting_nc;
      continue;
    }
    if (out.writes.size() == out.writes.capacity()) {
      // Full: this register waits for the next cycle (its limiter has not moved).
      if (first_deferred == n) {
        first_deferred = i;
      }
      ++counters_.writes_deferred;
      continue;
    }
    LimitResult res{};
    if (r.resend_as_is) {
      // The NC holds this value or the one before it, both within max_step_um of it: the same
      // value again, not a step further.
      res.value_um = r.sent_um;
    } else if (flag) {
      // Written as asked (admissible() was checked when the target was accepted); the limiter
      // is reset to it so status and state show the value in force.
      r.limiter.reset(goal_um, now_ns);
      res.value_um = goal_um;
      res.verdict = LimitVerdict::kPassed;
    } else {
      res = r.limiter.apply(goal_um, now_ns);
      const bool slewed = res.verdict == LimitVerdict::kSlewed;
      if (slewed && !r.slewing) {
        // One warning when slewing starts, not one per cycle.
        out.alarm(now_ns, Severity::kWarning, AlarmCode::kOffsetSlewLimited,
                  static_cast<std::int32_t>(i), goal_um);
      }
      r.slewing = slewed;
    }
    if (r.sent && !r.resend_as_is && std::memcmp(&r.sent_um, &res.value_um, sizeof(double)) == 0) {
      continue;  // the rate limit allows no movement yet this cycle
    }
    if (!r.limiter.admissible(res.value_um)) {
      // A rejected goal holds an origin beyond the limit: never sent, whatever the NC held.
      ++counters_.writes_rejected;
      r.resend_as_is = false;
      continue;
    }
    const std::uint64_t sequence = write_sequence_ + 1;
    if (out.writes.push(
            OffsetWrite{now_ns, static_cast<std::uint16_t>(i), res.value_um, sequence})) {
      write_sequence_ = sequence;
      r.sent_um = res.value_um;
      r.sent = true;
      r.as_is_in_flight = r.resend_as_is;
      r.resend_as_is = false;
      if (receipts_) {
        r.in_flight = sequence;
      } else {
        r.nc_um = res.value_um;
        r.nc_sent = true;
      }
      ++counters_.writes_forwarded;
      ++register_generation_;
    }
  }
  if (first_deferred != n) {
    write_cursor_ = first_deferred;
  }
  counters_.output_overflows = out.writes.overflows() + out.alarms.overflows() +
                               out.records.overflows() + out.trims.overflows() +
                               scratch_.trims.overflows() + scratch_.writes.overflows() +
                               scratch_.alarms.overflows() + scratch_.records.overflows();
}

std::uint64_t Engine::trim_identity(std::size_t i) const noexcept {
  const std::size_t n = regs_.size();
  std::uint64_t id = 0;
  for (std::size_t m = 0; m < modules_.size(); ++m) {
    if (!std::isnan(trims_[m * n + i])) {
      id ^= mix64(fnv1a(modules_[m]->name()) ^ modules_[m]->trim_identity());
    }
  }
  return id;
}

namespace {
/// Register i's trims now, evaluated at other inputs, and as they were at the switch.
class RegisterTrimChange final : public TrimChange {
 public:
  RegisterTrimChange(const std::vector<std::unique_ptr<Module>>& modules,
                     const std::vector<double>& trims, std::size_t registers, std::size_t i,
                     double old_um) noexcept
      : modules_(modules), trims_(trims), n_(registers), i_(i), old_um_(old_um) {}
  [[nodiscard]] double new_at(const InputSnapshot& inputs) const noexcept override {
    double sum_um = 0.0;
    for (std::size_t m = 0; m < modules_.size(); ++m) {
      if (std::isnan(trims_[m * n_ + i_])) continue;
      const double t = modules_[m]->trim_at_inputs(static_cast<std::uint16_t>(i_), inputs);
      if (!std::isfinite(t)) return kNaN;
      sum_um += t;
    }
    return sum_um;
  }
  [[nodiscard]] double old_at_switch_um() const noexcept override { return old_um_; }

 private:
  const std::vector<std::unique_ptr<Module>>& modules_;
  const std::vector<double>& trims_;
  std::size_t n_;
  std::size_t i_;
  double old_um_;
};
}  // namespace

void Engine::hand_over_trims(TimeNs now_ns) noexcept {
  handover_pending_ = false;
  bool any = false;
  double largest_um = 0.0;
  double unabsorbed_um = 0.0;
  for (std::size_t i = 0; i < regs_.size(); ++i) {
    if (handover_known_[i] == 0) {
      continue;
    }
    handover_known_[i] = 0;
    Reg& r = regs_[i];
    const double now_trim_um = r.has_trim ? r.trim_um : 0.0;
    const double delta_um = now_trim_um - handover_trim_um_[i];
    if (trim_identity(i) == handover_identity_[i] || !std::isfinite(delta_um) ||
        !(std::fabs(delta_um) > 0.0)) {
      continue;
    }
    any = true;
    largest_um = std::max(largest_um, std::fabs(delta_um));
    const int w = writer_[i];
    if (w >= 0 && specs_[i].kind != RegisterKind::kFlag &&
        modules_[static_cast<std::size_t>(w)]->rebase_output_along(
            static_cast<std::uint16_t>(i), -delta_um,
            RegisterTrimChange(modules_, trims_, regs_.size(), i, handover_trim_um_[i]), now_ns)) {
      r.target_um = (r.has_target ? r.target_um : 0.0) - delta_um;
      r.has_target = true;
      ++register_generation_;
      ++counters_.handover_rebases;
    } else {
      ++counters_.handover_unabsorbed;
      unabsorbed_um = std::max(unabsorbed_um, std::fabs(delta_um));
    }
  }
  if (any) {
    ++counters_.handovers;
    counters_.last_handover_trim_change_um = largest_um;
    counters_.last_handover_unabsorbed_um = unabsorbed_um;
  }
}

void Engine::resend_all() noexcept {
  for (auto& r : regs_) {
    if (r.sent && r.hold == RegisterHold::kNone) {
      // Forget what was sent; the next step writes the limiter's output (or the target) again.
      r.sent = false;
      if (!r.has_target) {
        // The output includes the trims, which are added again on top of the target.
        r.target_um = r.limiter.output_um() - r.trim_um;
        r.has_target = true;
      }
    }
  }
}

void Engine::nc_holds(Reg& r, double value_um) noexcept {
  r.nc_um = value_um;
  r.nc_sent = true;
  r.in_flight = 0;
  r.resend_as_is = false;
  r.as_is_in_flight = false;
}

void Engine::write_receipt(std::size_t i, WriteReceipt receipt, TimeNs now_ns) noexcept {
  if (i >= regs_.size()) {
    return;
  }
  Reg& r = regs_[i];
  // Sequences count up: a receipt of an older write says nothing about the one in flight.
  if (r.in_flight == 0 || receipt.sequence < r.in_flight ||
      receipt.outcome == WriteOutcome::kPending) {
    return;
  }
  r.in_flight = 0;
  switch (receipt.outcome) {
    case WriteOutcome::kReached:
      r.nc_um = r.sent_um;
      r.nc_sent = true;
      break;
    case WriteOutcome::kRefused:
      if (r.as_is_in_flight) {
        // Still unsure which of the two values the NC holds: the same value again.
        r.resend_as_is = true;
        break;
      }
      // The NC keeps what it held: the limiter moves from there again.
      r.limiter.reset(r.nc_um, now_ns);
      r.sent_um = r.nc_um;
      r.sent = r.nc_sent;
      ++register_generation_;
      break;
    case WriteOutcome::kUnknown:
    case WriteOutcome::kPending:
      r.resend_as_is = true;
      break;
  }
}

AnchorResult Engine::anchor_register(std::size_t i, double nc_value_um, TimeNs now_ns) noexcept {
  AnchorResult res;
  if (i >= regs_.size() || !std::isfinite(nc_value_um)) {
    return res;
  }
  Reg& r = regs_[i];
  res.known = r.sent;
  res.before_um = r.limiter.output_um();
  res.beyond_limit = std::fabs(nc_value_um) > r.limiter.config().max_abs_um;
  // The NC holds it: it is what was "sent". The next step compares the goal with it and writes
  // only if they differ, through the limiter that now starts here.
  r.limiter.reset(nc_value_um, now_ns);
  r.sent_um = nc_value_um;
  r.sent = true;
  r.slewing = false;
  nc_holds(r, nc_value_um);
  if (res.beyond_limit) {
    hold_register(i, RegisterHold::kBeyondLimit, AlarmCode::kRegisterBeyondLimit, nc_value_um);
  } else if (r.hold == RegisterHold::kBeyondLimit) {
    // The state said beyond, the NC holds a value within the limits now (corrected by hand).
    hold_register(i, RegisterHold::kNone, AlarmCode::kNone, 0.0);
  }
  ++register_generation_;  // the state file gets the NC's value
  res.anchored = true;
  return res;
}

void Engine::hold_register(std::size_t i, RegisterHold hold, AlarmCode notice,
                           double value) noexcept {
  Reg& r = regs_[i];
  r.hold = hold;
  r.slewing = false;
  if (r.notice == AlarmCode::kNone && notice != AlarmCode::kNone) ++notices_pending_;
  if (r.notice != AlarmCode::kNone && notice == AlarmCode::kNone && notices_pending_ > 0) {
    --notices_pending_;
  }
  r.notice = notice;
  r.notice_value = value;
}

bool Engine::release_register(std::size_t i, TimeNs now_ns) noexcept {
  if (i >= regs_.size() || regs_[i].hold == RegisterHold::kNone) {
    return false;
  }
  Reg& r = regs_[i];
  if (r.hold == RegisterHold::kBeyondLimit) {
    // Any write moves the register from beyond the limit into it: the operator's release makes
    // it one move, to the goal itself if the limits admit it, else to the bound from where the
    // limiter slews toward later targets.
    const double goal_um = (r.has_target ? r.target_um : 0.0) + r.trim_um;
    const double bound = r.limiter.config().max_abs_um;
    r.resend_as_is = false;
    if ((r.has_target || r.has_trim) && r.limiter.admissible(goal_um)) {
      r.limiter.reset(goal_um, now_ns);
    } else {
      const double at_bound = std::clamp(r.limiter.output_um(), -bound, bound);
      r.limiter.reset(at_bound, now_ns);
      // A restored target beyond a narrowed limit may equal what was last sent: the NC still
      // holds it, so the bound is written once all the same. Without a target nothing is
      // written until a module asks for a value (then it slews from the bound).
      if (r.has_target || r.has_trim) {
        r.sent_um = at_bound;
        r.sent = true;
        r.resend_as_is = true;
      }
    }
  } else {
    // Without state the limiter starts from what the NC holds (anchored): it slews as usual.
    r.resend_as_is = false;
  }
  hold_register(i, RegisterHold::kNone, AlarmCode::kNone, 0.0);
  ++register_generation_;
  return true;
}

StartupAdoption Engine::adopt_without_state(std::size_t i, std::optional<double> nc_value_um,
                                            bool readable, TimeNs now_ns) {
  if (i >= regs_.size() || writer_[i] < 0 || regs_[i].hold == RegisterHold::kBeyondLimit) {
    return StartupAdoption::kNotNeeded;
  }
  const auto k = static_cast<std::size_t>(writer_[i]);
  // A restored module needs nothing, unless the register is still held from a start without
  // state (the NC did not answer then): it is offered what the NC holds now.
  if (module_state_[k] == ModuleStateSource::kRestored &&
      regs_[i].hold != RegisterHold::kWithoutState) {
    return StartupAdoption::kNotNeeded;
  }
  if (!readable) {
    return regs_[i].hold == RegisterHold::kWithoutState ? StartupAdoption::kHeld
                                                        : StartupAdoption::kNotReadable;
  }
  const bool flag = specs_[i].kind == RegisterKind::kFlag;
  const bool adopted =
      nc_value_um && modules_[k]->adopt_output(static_cast<std::uint16_t>(i), *nc_value_um, now_ns);
  if (flag) {
    return StartupAdoption::kFlag;
  }
  if (adopted) {
    (void)adopt_register(i, *nc_value_um, now_ns);
    const bool notice = std::fabs(*nc_value_um) > kNoOffsetUm;
    hold_register(i, RegisterHold::kNone, notice ? AlarmCode::kRegisterAdopted : AlarmCode::kNone,
                  *nc_value_um);
    return StartupAdoption::kAdopted;
  }
  if (nc_value_um && std::fabs(*nc_value_um) <= kNoOffsetUm) {
    // Nothing in the NC to lose: the module writes.
    hold_register(i, RegisterHold::kNone, AlarmCode::kNone, 0.0);
    return StartupAdoption::kNotNeeded;
  }
  hold_register(i, RegisterHold::kWithoutState, AlarmCode::kRegisterHeldWithoutState,
                nc_value_um ? *nc_value_um : kNaN);
  ++register_generation_;
  return StartupAdoption::kHeld;
}

AnchorResult Engine::adopt_register(std::size_t i, double nc_value_um, TimeNs now_ns) noexcept {
  AnchorResult res = anchor_register(i, nc_value_um, now_ns);
  if (!res.anchored || res.beyond_limit) {
    return res;
  }
  Reg& r = regs_[i];
  r.target_um = nc_value_um - r.trim_um;
  r.has_target = true;
  res.adopted = true;
  return res;
}

RegisterState Engine::register_state(std::size_t i) const noexcept {
  const Reg& r = regs_[i];
  const bool awaiting = r.in_flight != 0 && specs_[i].kind != RegisterKind::kFlag;
  return RegisterState{r.limiter.output_um(),
                       r.target_um,
                       r.has_target,
                       r.slewing,
                       r.trim_um,
                       r.has_trim,
                       r.hold,
                       awaiting};
}

std::uint64_t Engine::state_generation() const noexcept {
  std::uint64_t g = register_generation_;
  for (const auto& m : modules_) {
    g += m->state_generation();
  }
  return g + context_.generation() + cursors_.generation();
}

namespace {
// Engine::export_motion(): records of [u64 key (fnv1a of the module's name, or of "@context")]
// [u64 size][size bytes].
constexpr std::size_t kMotionHeader = 16;
}  // namespace

std::size_t Engine::export_motion(std::span<std::byte> buf) const noexcept {
  std::size_t at = 0;
  const auto put = [&](std::uint64_t key, auto&& save) {
    if (buf.size() < at + kMotionHeader) return false;
    const std::uint64_t n = save(buf.subspan(at + kMotionHeader));
    std::memcpy(buf.data() + at, &key, 8);
    std::memcpy(buf.data() + at + 8, &n, 8);
    at += kMotionHeader + n;
    return true;
  };
  if (!put(fnv1a("@context"),
           [&](std::span<std::byte> b) { return std::uint64_t{context_.save_motion(b)}; })) {
    return 0;
  }
  for (const auto& m : modules_) {
    if (!put(fnv1a(m->name()),
             [&](std::span<std::byte> b) { return std::uint64_t{m->save_motion(b)}; })) {
      return 0;
    }
  }
  return at;
}

std::size_t Engine::import_motion(std::span<const std::byte> bytes) noexcept {
  std::size_t at = 0;
  std::size_t continued = 0;
  const std::uint64_t context_key = fnv1a("@context");
  while (bytes.size() >= at + kMotionHeader) {
    std::uint64_t key = 0;
    std::uint64_t n = 0;
    std::memcpy(&key, bytes.data() + at, 8);
    std::memcpy(&n, bytes.data() + at + 8, 8);
    if (n > bytes.size() - at - kMotionHeader) break;
    const auto part = bytes.subspan(at + kMotionHeader, static_cast<std::size_t>(n));
    at += kMotionHeader + static_cast<std::size_t>(n);
    if (n == 0) continue;
    if (key == context_key) {
      if (context_.load_motion(part)) ++continued;
      continue;
    }
    for (auto& m : modules_) {
      if (fnv1a(m->name()) == key) {
        if (m->load_motion(part)) ++continued;
        break;
      }
    }
  }
  return continued;
}

std::size_t Engine::export_state(std::span<std::byte> buf) const noexcept {
  Writer w(buf);
  w.put(kStateMagic);
  w.put(kStateVersion);
  w.put(static_cast<std::uint32_t>(regs_.size()));
  for (std::size_t i = 0; i < regs_.size(); ++i) {
    const Reg& r = regs_[i];
    w.put_name(specs_[i].name);
    w.put(r.limiter.output_um());
    w.put(r.target_um);
    w.put(static_cast<std::uint8_t>(r.has_target ? 1 : 0));
  }
  w.put(static_cast<std::uint32_t>(modules_.size() + 6));
  w.put_name(kContextEntry);
  w.put(static_cast<std::uint32_t>(MachineContext::kStateBytes));
  if (!w.ok() || w.rest().size() < MachineContext::kStateBytes) {
    return 0;
  }
  w.skip(context_.save(w.rest()));
  {
    w.put_name(kHoldsEntry);
    const std::span<std::byte> len_at = w.rest();
    w.put(std::uint32_t{0});
    const std::size_t begin = w.size();
    w.put(static_cast<std::uint32_t>(regs_.size()));
    for (std::size_t i = 0; i < regs_.size(); ++i) {
      w.put_name(specs_[i].name);
      w.put(static_cast<std::uint8_t>(regs_[i].hold));
    }
    if (!w.ok()) {
      return 0;
    }
    const auto n32 = static_cast<std::uint32_t>(w.size() - begin);
    std::memcpy(len_at.data(), &n32, sizeof(n32));
  }
  {
    w.put_name(kInFlightEntry);
    const std::span<std::byte> len_at = w.rest();
    w.put(std::uint32_t{0});
    const std::size_t begin = w.size();
    w.put(static_cast<std::uint32_t>(regs_.size()));
    for (std::size_t i = 0; i < regs_.size(); ++i) {
      const Reg& r = regs_[i];
      const bool unsure =
          (r.in_flight != 0 && specs_[i].kind != RegisterKind::kFlag) || r.resend_as_is;
      w.put_name(specs_[i].name);
      w.put(static_cast<std::uint8_t>(unsure ? 1 : 0));
    }
    if (!w.ok()) {
      return 0;
    }
    const auto n32 = static_cast<std::uint32_t>(w.size() - begin);
    std::memcpy(len_at.data(), &n32, sizeof(n32));
  }
  {
    w.put_name(kTrimsEntry);
    const std::span<std::byte> len_at = w.rest();
    w.put(std::uint32_t{0});
    const std::size_t begin = w.size();
    w.put(kTrimsVersion);
    w.put(static_cast<std::uint32_t>(regs_.size()));
    for (std::size_t i = 0; i < regs_.size(); ++i) {
      // Imported but not stepped yet (a reload before the first cycle): the trims in force are
      // still the imported ones; the next engine hands them over.
      const bool imported = handover_pending_ && handover_known_[i] != 0;
      w.put_name(specs_[i].name);
      w.put(imported ? handover_trim_um_[i] : (regs_[i].has_trim ? regs_[i].trim_um : 0.0));
      w.put(imported ? handover_identity_[i] : trim_identity(i));
    }
    if (!w.ok()) {
      return 0;
    }
    const auto n32 = static_cast<std::uint32_t>(w.size() - begin);
    std::memcpy(len_at.data(), &n32, sizeof(n32));
  }
  w.put_name(kCursorsEntry);
  w.put(static_cast<std::uint32_t>(EventCursors::kStateBytes));
  if (!w.ok() || w.rest().size() < EventCursors::kStateBytes) {
    return 0;
  }
  w.skip(cursors_.save(w.rest()));
  w.put_name(kLagsEntry);
  w.put(static_cast<std::uint32_t>(InputLags::kStateBytes));
  if (!w.ok() || w.rest().size() < InputLags::kStateBytes) {
    return 0;
  }
  w.skip(lags_.save(w.rest()));
  for (const auto& m : modules_) {
    w.put_name(m->name());
    const std::span<std::byte> len_at = w.rest();
    w.put(std::uint32_t{0});
    if (!w.ok()) {
      return 0;
    }
    const std::span<std::byte> room = w.rest();
    if (room.size() < m->state_capacity()) {
      return 0;  // a module must never be handed less than it declared
    }
    const std::size_t n = m->save_state(room);
    if (n > room.size()) {
      return 0;
    }
    const auto n32 = static_cast<std::uint32_t>(n);
    std::memcpy(len_at.data(), &n32, sizeof(n32));
    w.skip(n);
  }
  return w.ok() ? w.size() : 0;
}

bool Engine::import_state(std::span<const std::byte> bytes, TimeNs now_ns,
                          std::size_t* skipped) noexcept {
  // Pass 1 validates the structure without touching anything; pass 2 applies. A module may still
  // refuse its bytes in pass 2: it then keeps its fresh state and the refusal is counted.
  for (int pass = 0; pass < 2; ++pass) {
    Reader rd(bytes);
    std::uint32_t magic = 0;
    std::uint32_t version = 0;
    std::uint32_t nregs = 0;
    if (!rd.get(magic) || magic != kStateMagic || !rd.get(version) || version != kStateVersion ||
        !rd.get(nregs)) {
      return false;
    }
    std::size_t skip_count = 0;
    for (std::uint32_t k = 0; k < nregs; ++k) {
      std::string_view name;
      double output_um = 0.0;
      double target_um = 0.0;
      std::uint8_t has_target = 0;
      if (!rd.get_name(name) || !rd.get(output_um) || !rd.get(target_um) || !rd.get(has_target) ||
          has_target > 1 || !std::isfinite(output_um) || !std::isfinite(target_um)) {
        return false;
      }
      const int idx = RegisterTable(specs_).find(name);
      if (idx < 0) {
        ++skip_count;
        continue;
      }
      if (pass == 1) {
        const auto i = static_cast<std::size_t>(idx);
        Reg& r = regs_[i];
        r.limiter.reset(output_um, now_ns);
        r.sent_um = output_um;
        r.sent = true;
        nc_holds(r, output_um);
        r.target_um = target_um;
        r.has_target = has_target == 1;
        r.slewing = false;
        // What the NC holds lies beyond the limit (saved so, or a reload narrowed the limit):
        // held until the operator releases it, like a value read back beyond it.
        if (std::fabs(output_um) > r.limiter.config().max_abs_um) {
          hold_register(i, RegisterHold::kBeyondLimit, AlarmCode::kRegisterBeyondLimit, output_um);
        } else {
          hold_register(i, RegisterHold::kNone, AlarmCode::kNone, 0.0);
        }
      }
    }
    std::uint32_t nmods = 0;
    if (!rd.get(nmods)) {
      return false;
    }
    for (std::uint32_t k = 0; k < nmods; ++k) {
      std::string_view name;
      std::uint32_t len = 0;
      std::span<const std::byte> blob;
      if (!rd.get_name(name) || !rd.get(len) || !rd.get_span(len, blob)) {
        return false;
      }
      if (name == kContextEntry) {
        if (pass == 1 && !context_.load(blob, now_ns)) {
          ++skip_count;
        }
        continue;
      }
      if (name == kCursorsEntry) {
        if (pass == 1 && !cursors_.load(blob)) {
          ++skip_count;
        }
        continue;
      }
      if (name == kLagsEntry) {
        if (pass == 1 && !lags_.load(blob, now_ns)) {
          ++skip_count;
        }
        continue;
      }
      if (name == kHoldsEntry) {
        Reader hr(blob);
        std::uint32_t held = 0;
        if (!hr.get(held)) {
          return false;
        }
        for (std::uint32_t h = 0; h < held; ++h) {
          std::string_view reg;
          std::uint8_t hold = 0;
          if (!hr.get_name(reg) || !hr.get(hold) ||
              hold > static_cast<std::uint8_t>(RegisterHold::kWithoutState)) {
            return false;
          }
          const int idx = RegisterTable(specs_).find(reg);
          if (pass == 1 && idx >= 0 &&
              hold == static_cast<std::uint8_t>(RegisterHold::kWithoutState) &&
              regs_[static_cast<std::size_t>(idx)].hold == RegisterHold::kNone) {
            const auto i = static_cast<std::size_t>(idx);
            hold_register(i, RegisterHold::kWithoutState, AlarmCode::kRegisterHeldWithoutState,
                          regs_[i].limiter.output_um());
          }
        }
        if (!hr.at_end()) {
          return false;
        }
        continue;
      }
      if (name == kInFlightEntry) {
        Reader fr(blob);
        std::uint32_t count = 0;
        if (!fr.get(count)) {
          return false;
        }
        for (std::uint32_t k2 = 0; k2 < count; ++k2) {
          std::string_view reg;
          std::uint8_t in_flight = 0;
          if (!fr.get_name(reg) || !fr.get(in_flight) || in_flight > 1) {
            return false;
          }
          const int idx = RegisterTable(specs_).find(reg);
          if (pass == 1 && idx >= 0 && in_flight == 1) {
            // Saved while the bus had not confirmed it: the NC holds it or the value before.
            Reg& r = regs_[static_cast<std::size_t>(idx)];
            r.resend_as_is =
                r.sent && specs_[static_cast<std::size_t>(idx)].kind != RegisterKind::kFlag;
          }
        }
        if (!fr.at_end()) {
          return false;
        }
        continue;
      }
      if (name == kTrimsEntry) {
        Reader tr(blob);
        std::uint32_t tversion = 0;
        std::uint32_t count = 0;
        if (!tr.get(tversion) || tversion != kTrimsVersion || !tr.get(count)) {
          return false;
        }
        for (std::uint32_t k2 = 0; k2 < count; ++k2) {
          std::string_view reg;
          double trim_um = 0.0;
          std::uint64_t identity = 0;
          if (!tr.get_name(reg) || !tr.get(trim_um) || !tr.get(identity) ||
              !std::isfinite(trim_um)) {
            return false;
          }
          const int idx = RegisterTable(specs_).find(reg);
          if (pass == 1 && idx >= 0) {
            const auto i = static_cast<std::size_t>(idx);
            handover_trim_um_[i] = trim_um;
            handover_identity_[i] = identity;
            handover_known_[i] = 1;
            handover_pending_ = true;
          }
        }
        if (!tr.at_end()) {
          return false;
        }
        continue;
      }
      std::size_t target = modules_.size();
      for (std::size_t m = 0; m < modules_.size(); ++m) {
        if (modules_[m]->name() == name) {
          target = m;
        }
      }
      if (target == modules_.size()) {
        ++skip_count;
        continue;
      }
      if (pass == 1) {
        const bool loaded = modules_[target]->load_state(blob);
        module_state_[target] =
            loaded ? ModuleStateSource::kRestored : ModuleStateSource::kUnreadable;
        if (!loaded) {
          ++skip_count;
        }
      }
    }
    if (!rd.at_end()) {
      return false;
    }
    if (pass == 1) {
      ++register_generation_;
      if (skipped != nullptr) {
        *skipped = skip_count;
      }
    }
  }
  return true;
}

}  // namespace nccomp::core::engine
