#include "core/engine/context.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <variant>

namespace nccomp::core::engine {

namespace {

constexpr std::uint32_t kMagic = 0x5458434eU;  // "NCXT"
constexpr std::uint32_t kVersion = 1;
constexpr std::uint32_t kFlagCold = 1U;
constexpr std::uint32_t kFlagPart = 2U;
constexpr std::uint32_t kFlagClock = 4U;
/// Axis motion below this is no activity (servo jitter, a published position's last digit).
constexpr double kMotionMm = 1e-3;
/// The generation advances every this much cut path and activity (state saved now and then).
constexpr double kPathPersistMm = 10.0;
constexpr TimeNs kActivityPersistNs = 60'000'000'000;

/// a − b, saturated (times from a saved state or a caller's clock never overflow).
TimeNs sub(TimeNs a, TimeNs b) noexcept {
  TimeNs d = 0;
  if (__builtin_sub_overflow(a, b, &d)) {
    return b < 0 ? std::numeric_limits<TimeNs>::max() : std::numeric_limits<TimeNs>::min();
  }
  return d;
}
/// Saved durations and clock readings beyond this (about 146 years) are not a valid state.
constexpr TimeNs kMaxStateNs = TimeNs{1} << 62;

template <typename T>
void put(std::byte* p, std::size_t& at, const T& v) noexcept {
  std::memcpy(p + at, &v, sizeof(T));
  at += sizeof(T);
}
template <typename T>
T get(const std::byte* p, std::size_t& at) noexcept {
  T v{};
  std::memcpy(&v, p + at, sizeof(T));
  at += sizeof(T);
  return v;
}

}  // namespace

MachineContext::MachineContext() {
  position_mm_.fill(kNaN);
  temperature_c_.fill(kNaN);
  configure(ContextOptions{});
}

void MachineContext::configure(const ContextOptions& options) {
  if (options.temperature_sensor < -1 ||
      options.temperature_sensor >= static_cast<int>(kTemperatureSensors)) {
    throw std::invalid_argument("temperature_sensor: must be -1 (none) or a sensor 0 … 255, not " +
                                std::to_string(options.temperature_sensor));
  }
  if (!(options.warm_start_idle_s >= 60.0 && options.warm_start_idle_s <= 7.0 * 86400.0)) {
    throw std::invalid_argument("warm_start_idle_s: must be 60 … 604800 s, not " +
                                std::to_string(options.warm_start_idle_s));
  }
  options_ = options;
  idle_limit_ns_ = from_seconds(options.warm_start_idle_s);
}

std::int32_t MachineContext::tool() const noexcept {
  return current_ >= 0 ? tools_[static_cast<std::size_t>(current_)].tool : 0;
}

double MachineContext::cut_path_mm() const noexcept {
  return current_ >= 0 ? tools_[static_cast<std::size_t>(current_)].path_mm : 0.0;
}

double MachineContext::cut_path_mm(std::int32_t tool) const noexcept {
  const int k = find_slot(tool);
  return k >= 0 ? tools_[static_cast<std::size_t>(k)].path_mm : kNaN;
}

double MachineContext::temperature_c(int sensor) const noexcept {
  if (sensor < 0 || sensor >= static_cast<int>(kTemperatureSensors)) return kNaN;
  return temperature_c_[static_cast<std::size_t>(sensor)];
}

double MachineContext::machine_time_s(TimeNs t_ns) const noexcept {
  return t_ns > origin_ns_ ? seconds(sub(t_ns, origin_ns_)) : 0.0;
}

double MachineContext::idle_s() const noexcept {
  return last_step_ns_ > last_activity_ns_ ? seconds(sub(last_step_ns_, last_activity_ns_)) : 0.0;
}

int MachineContext::find_slot(std::int32_t tool) const noexcept {
  for (std::size_t k = 0; k < tools_.size(); ++k) {
    if (tools_[k].used && tools_[k].tool == tool) return static_cast<int>(k);
  }
  return -1;
}

int MachineContext::take_slot(std::int32_t tool) noexcept {
  int k = find_slot(tool);
  if (k < 0) {
    // A free slot, else the least recently used one that is not in the spindle.
    for (std::size_t j = 0; j < tools_.size() && k < 0; ++j) {
      if (!tools_[j].used) k = static_cast<int>(j);
    }
    if (k < 0) {
      for (std::size_t j = 0; j < tools_.size(); ++j) {
        if (static_cast<int>(j) == current_) continue;
        if (k < 0 || tools_[j].last_use < tools_[static_cast<std::size_t>(k)].last_use) {
          k = static_cast<int>(j);
        }
      }
    }
    tools_[static_cast<std::size_t>(k)] = ToolSlot{tool, true, 0.0, 0};
  }
  tools_[static_cast<std::size_t>(k)].last_use = ++use_counter_;
  return k;
}

void MachineContext::on_tool_change(std::int32_t tool, bool sister) noexcept {
  // As the creep module: the same tool back (no sister) keeps its path; another tool continues
  // the path it had when it left; a sister is a fresh tool (path 0) and the tool it replaces is
  // forgotten.
  if (current_ >= 0 && tools_[static_cast<std::size_t>(current_)].tool == tool && !sister) return;
  if (sister && current_ >= 0) tools_[static_cast<std::size_t>(current_)].used = false;
  const int k = take_slot(tool);
  // Tool 0 (none named) is never remembered: a fresh count, as creep's fresh state.
  if (sister || tool == 0) tools_[static_cast<std::size_t>(k)].path_mm = 0.0;
  current_ = k;
  path_saved_mm_ = tools_[static_cast<std::size_t>(k)].path_mm;
  ++generation_;
}

void MachineContext::on_axis_sample(TimeNs now_ns, const AxisSample& a) noexcept {
  if (a.tool != 0 && current_ >= 0 && tools_[static_cast<std::size_t>(current_)].tool == 0 &&
      find_slot(a.tool) < 0) {
    // The first tool number the NC names: the path counted so far was this tool's (creep keeps
    // its state for it too).
    tools_[static_cast<std::size_t>(current_)].tool = a.tool;
    ++generation_;
  } else if (a.tool != 0 &&
             (current_ < 0 || tools_[static_cast<std::size_t>(current_)].tool != a.tool)) {
    on_tool_change(a.tool, false);  // another tool without a tool-change event
  } else if (current_ < 0) {
    on_tool_change(a.tool, false);  // the NC names no tool: one unnamed tool (0)
  }
  // Activity and the warm start: axis motion since the previous sample.
  bool moved = false;
  if (have_sample_) {
    const std::size_t n =
        std::min<std::size_t>({static_cast<std::size_t>(a.axis_count),
                               static_cast<std::size_t>(last_sample_.axis_count), std::size_t{3}});
    for (std::size_t k = 0; k < n; ++k) {
      moved = moved || std::fabs(a.position_mm[k] - last_sample_.position_mm[k]) > kMotionMm;
    }
    if (std::isfinite(a.program_path_mm) && std::isfinite(last_sample_.program_path_mm)) {
      moved = moved || std::fabs(a.program_path_mm - last_sample_.program_path_mm) > kMotionMm;
    }
  }
  if (moved) {
    if (cold_ || sub(now_ns, last_activity_ns_) >= idle_limit_ns_) {
      origin_ns_ = now_ns;
      cold_ = false;
      ++warm_starts_;
      ++generation_;
      activity_saved_ns_ = now_ns;
    }
    last_activity_ns_ = now_ns;
    if (sub(now_ns, activity_saved_ns_) >= kActivityPersistNs) {
      activity_saved_ns_ = now_ns;
      ++generation_;
    }
  }
  // Cut path, exactly as creep counts it.
  const bool cut = a.cutting && !interrupted_;
  if (have_sample_ && cut && cutting_ && current_ >= 0) {
    double d = 0.0;
    if (std::isfinite(a.program_path_mm) && std::isfinite(last_sample_.program_path_mm)) {
      d = a.program_path_mm - last_sample_.program_path_mm;
    } else {
      const std::size_t n = std::min<std::size_t>(
          {static_cast<std::size_t>(a.axis_count),
           static_cast<std::size_t>(last_sample_.axis_count), std::size_t{3}});
      double sq = 0.0;
      for (std::size_t k = 0; k < n; ++k) {
        const double dk = a.position_mm[k] - last_sample_.position_mm[k];
        sq += dk * dk;
      }
      d = std::sqrt(sq);
    }
    ToolSlot& s = tools_[static_cast<std::size_t>(current_)];
    if (std::isfinite(d) && d > 0.0) s.path_mm += d;
    if (s.path_mm - path_saved_mm_ >= kPathPersistMm) {
      path_saved_mm_ = s.path_mm;
      ++generation_;
    }
  }
  const std::size_t n = std::min<std::size_t>(a.axis_count, position_mm_.size());
  for (std::size_t k = 0; k < n; ++k) position_mm_[k] = a.position_mm[k];
  last_sample_ = a;
  have_sample_ = true;
  cutting_ = cut;
}

void MachineContext::on_command(TimeNs now_ns, const OperatorCommand& c) noexcept {
  if (c.kind != OperatorCommandKind::kWarmStart || (c.code[0] != 0 && c.code[0] != 1)) {
    return;
  }
  if (c.code[0] == 0) {
    // Declared now: the origin of time_s is this cycle, and the cycle counts as activity (the
    // machine is running now; the idle rule starts counting from here).
    origin_ns_ = now_ns;
    last_activity_ns_ = now_ns;
    activity_saved_ns_ = now_ns;
    cold_ = false;
    ++warm_starts_;
  } else {
    cold_ = true;  // the next axis motion is the warm start
  }
  ++commands_;
  last_sequence_ = c.sequence;
  ++generation_;
}

void MachineContext::update(TimeNs now_ns, std::span<const Event> events) noexcept {
  if (!has_step_) {
    // A fresh context: time counts from the first cycle until the first warm start.
    origin_ns_ = now_ns;
    last_activity_ns_ = now_ns;
    has_step_ = true;
  }
  last_step_ns_ = now_ns;
  for (const Event& e : events) {
    if (const auto* a = std::get_if<AxisSample>(&e)) {
      on_axis_sample(now_ns, *a);
    } else if (const auto* c = std::get_if<ToolChange>(&e)) {
      on_tool_change(c->tool, c->sister);
    } else if (const auto* p = std::get_if<ProgramEvent>(&e)) {
      switch (p->kind) {
        case ProgramEventKind::kPartStart:
          if (!has_part_ || p->part != part_) ++generation_;
          part_ = p->part;
          has_part_ = true;
          break;
        case ProgramEventKind::kPartEnd:
          break;
        case ProgramEventKind::kInterruption:
          interrupted_ = true;
          cutting_ = false;
          break;
        case ProgramEventKind::kResume:
          interrupted_ = false;
          break;
      }
    } else if (const auto* t = std::get_if<TemperatureSample>(&e)) {
      temperature_c_[t->sensor] = t->temperature_c;
    } else if (const auto* o = std::get_if<OperatorCommand>(&e)) {
      on_command(now_ns, *o);
    }
  }
}

void MachineContext::annotate(MeasurementRecord& r) const noexcept {
  if (std::isnan(r.path_mm)) {
    double p = cut_path_mm(r.tool);
    // An NC that names no tool: the path of the one unnamed tool is the only one there is.
    if (std::isnan(p) && current_ >= 0 && tools_[static_cast<std::size_t>(current_)].tool == 0) {
      p = cut_path_mm();
    }
    r.path_mm = p;
  }
  if (std::isnan(r.temp_c)) r.temp_c = temp_c();
  r.session = warm_starts_;
  r.clock_ns = r.time_ns;
  r.time_ns = r.time_ns > origin_ns_ ? sub(r.time_ns, origin_ns_) : 0;
}

std::size_t MachineContext::save(std::span<std::byte> buf) const noexcept {
  if (buf.size() < kStateBytes) return 0;
  std::byte* p = buf.data();
  std::size_t at = 0;
  const std::uint32_t flags =
      (cold_ ? kFlagCold : 0U) | (has_part_ ? kFlagPart : 0U) | (has_step_ ? kFlagClock : 0U);
  put(p, at, kMagic);
  put(p, at, kVersion);
  put(p, at, flags);
  put(p, at, part_);
  put(p, at, warm_starts_);
  put(p, at, has_step_ ? std::max(TimeNs{0}, sub(last_step_ns_, origin_ns_)) : TimeNs{0});
  put(p, at, has_step_ ? std::max(TimeNs{0}, sub(last_step_ns_, last_activity_ns_)) : TimeNs{0});
  put(p, at, last_step_ns_);
  put(p, at, static_cast<std::int32_t>(current_));
  put(p, at, static_cast<std::uint32_t>(kContextTools));
  for (const ToolSlot& s : tools_) {
    put(p, at, s.tool);
    put(p, at, static_cast<std::uint32_t>(s.used ? 1U : 0U));
    put(p, at, s.path_mm);
    put(p, at, s.last_use);
  }
  return at;
}

bool MachineContext::load(std::span<const std::byte> bytes, TimeNs now_ns) noexcept {
  if (bytes.size() != kStateBytes) return false;
  const std::byte* p = bytes.data();
  std::size_t at = 0;
  const auto magic = get<std::uint32_t>(p, at);
  const auto version = get<std::uint32_t>(p, at);
  const auto flags = get<std::uint32_t>(p, at);
  const auto part = get<std::int32_t>(p, at);
  const auto warm_starts = get<std::uint64_t>(p, at);
  const auto machine_ns = get<TimeNs>(p, at);
  const auto idle_ns = get<TimeNs>(p, at);
  const auto saved_step_ns = get<TimeNs>(p, at);
  const auto current = get<std::int32_t>(p, at);
  const auto slots = get<std::uint32_t>(p, at);
  if (magic != kMagic || version != kVersion || flags > 7U || machine_ns < 0 || idle_ns < 0 ||
      machine_ns > kMaxStateNs || idle_ns > kMaxStateNs || saved_step_ns > kMaxStateNs ||
      saved_step_ns < -kMaxStateNs || now_ns > kMaxStateNs || now_ns < -kMaxStateNs ||
      slots != kContextTools || current < -1 || current >= static_cast<std::int32_t>(slots)) {
    return false;
  }
  std::array<ToolSlot, kContextTools> tools{};
  std::uint64_t max_use = 0;
  for (std::size_t k = 0; k < kContextTools; ++k) {
    ToolSlot& s = tools[k];
    s.tool = get<std::int32_t>(p, at);
    const auto used = get<std::uint32_t>(p, at);
    s.path_mm = get<double>(p, at);
    s.last_use = get<std::uint64_t>(p, at);
    if (used > 1U || !std::isfinite(s.path_mm) || s.path_mm < 0.0) return false;
    s.used = used == 1U;
    if (!s.used) s = ToolSlot{};
    for (std::size_t j = 0; j < k; ++j) {
      if (s.used && tools[j].used && tools[j].tool == s.tool) return false;
    }
    max_use = std::max(max_use, s.last_use);
  }
  if (current >= 0 && !tools[static_cast<std::size_t>(current)].used) return false;
  tools_ = tools;
  use_counter_ = max_use;
  current_ = current;
  path_saved_mm_ = cut_path_mm();
  part_ = part;
  has_part_ = (flags & kFlagPart) != 0U;
  warm_starts_ = warm_starts;
  cold_ = (flags & kFlagCold) != 0U;
  has_step_ = (flags & kFlagClock) != 0U;
  if (has_step_ && now_ns >= saved_step_ns) {
    // The same clock (a restart within one boot): the origin and the last activity are where
    // they were; the downtime counts as idle time.
    origin_ns_ = sub(saved_step_ns, machine_ns);
    last_activity_ns_ = sub(saved_step_ns, idle_ns);
  } else if (has_step_) {
    // The clock went back (a reboot): the downtime is unknown. The time goes on from where it
    // was, and the machine is taken as cold.
    origin_ns_ = sub(now_ns, machine_ns);
    last_activity_ns_ = sub(now_ns, idle_ns);
    cold_ = true;
  }
  last_step_ns_ = has_step_ ? now_ns : 0;
  activity_saved_ns_ = last_activity_ns_;
  // Motion is judged between samples of this run; cutting restarts with the next two samples.
  have_sample_ = false;
  cutting_ = false;
  interrupted_ = false;
  ++generation_;
  return true;
}

std::size_t MachineContext::save_motion(std::span<std::byte> buf) const noexcept {
  if (buf.size() < kMotionSize) return 0;
  std::memcpy(buf.data(), &last_sample_, sizeof(AxisSample));
  const std::array<std::uint8_t, 8> flags{have_sample_ ? std::uint8_t{1} : std::uint8_t{0},
                                          cutting_ ? std::uint8_t{1} : std::uint8_t{0},
                                          interrupted_ ? std::uint8_t{1} : std::uint8_t{0}};
  std::memcpy(buf.data() + sizeof(AxisSample), flags.data(), flags.size());
  return kMotionSize;
}

bool MachineContext::load_motion(std::span<const std::byte> bytes) noexcept {
  if (bytes.size() != kMotionSize) return false;
  std::array<std::uint8_t, 8> flags{};
  std::memcpy(flags.data(), bytes.data() + sizeof(AxisSample), flags.size());
  if (flags[0] > 1 || flags[1] > 1 || flags[2] > 1) return false;
  std::memcpy(&last_sample_, bytes.data(), sizeof(AxisSample));
  have_sample_ = flags[0] == 1;
  cutting_ = flags[1] == 1;
  interrupted_ = flags[2] == 1;
  return true;
}

}  // namespace nccomp::core::engine
