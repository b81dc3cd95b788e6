#include "drivers/modbus/decoder.hpp"

#include <cmath>
#include <limits>

namespace nccomp::drivers::modbus {
namespace {

/// An integral value within [lo, hi], else false.
bool to_int(double v, double lo, double hi, std::int32_t& out) noexcept {
  if (!std::isfinite(v) || v < lo || v > hi) {
    return false;
  }
  const double r = std::nearbyint(v);
  if (std::fabs(v - r) > 1e-6) {
    return false;
  }
  out = static_cast<std::int32_t>(r);
  return true;
}

constexpr double kIntMin = std::numeric_limits<std::int32_t>::min();
constexpr double kIntMax = std::numeric_limits<std::int32_t>::max();

}  // namespace

PollDecoder::PollDecoder(const ModbusConfig& config) : config_(config) {
  blocks_.reserve(config.blocks.size());
  for (const ReadBlock& b : config.blocks) {
    blocks_.emplace_back(b.count, std::uint16_t{0});
  }
  out_.reserve(1 + kGroupCount + config.temperatures.size());
  last_temperature_.assign(config.temperatures.size(), core::kNaN);
}

double PollDecoder::value(const SignalMap& s) const noexcept {
  const std::vector<std::uint16_t>& b = blocks_[s.block];
  return modbus::decode(
      std::span<const std::uint16_t>(b.data() + s.block_offset, width(s.encoding.type)),
      s.encoding);
}

bool PollDecoder::in_range(const GroupMap& g, std::size_t n) const noexcept {
  for (std::size_t f = 0; f < n; ++f) {
    const SignalMap& s = g.fields[f];
    if (!s.mapped || (std::isinf(s.min) && std::isinf(s.max))) {
      continue;
    }
    const std::vector<std::uint16_t>& b = blocks_[s.block];
    const std::size_t w = width(s.encoding.type);
    for (std::size_t i = 0; i < s.count; ++i) {
      const double v = modbus::decode(
          std::span<const std::uint16_t>(b.data() + s.block_offset + i * w, w), s.encoding);
      // NaN / inf are not a range question: the callers refuse them (or take NaN as "unknown").
      if (std::isfinite(v) && (v < s.min || v > s.max)) {
        return false;
      }
    }
  }
  return true;
}

void PollDecoder::note_reconnect() noexcept {
  for (SeqState& st : seq_) {
    st.reconnected = true;
  }
}

void PollDecoder::resume(const core::EventCursorSet& cursors) noexcept {
  for (std::size_t gi = 1; gi < kGroupCount; ++gi) {
    // The groups after kAxis are in the order of the numbered kinds. Like a reconnect: an NC
    // that restarted meanwhile and counted up to the cursor again cannot be told apart.
    const core::EventCursor& c = cursors[gi - 1];
    if (c.known) {
      seq_[gi] = SeqState{true, true, true, c.sequence};
    }
  }
}

void PollDecoder::emit_counter(Group g, core::TimeNs t_ns, std::uint32_t seq) noexcept {
  const core::EventOrigin origin{seq, 0, true, true};
  switch (g) {
    case Group::kToolMeasurement:
      emit(core::ToolMeasurement{.time_ns = t_ns, .origin = origin});
      break;
    case Group::kProbeMeasurement:
      emit(core::ProbeMeasurement{.time_ns = t_ns, .origin = origin});
      break;
    case Group::kCalibrationTouch:
      emit(core::CalibrationTouch{.time_ns = t_ns, .origin = origin});
      break;
    case Group::kToolChange:
      emit(core::ToolChange{.time_ns = t_ns, .origin = origin});
      break;
    case Group::kProgramEvent:
      emit(core::ProgramEvent{.time_ns = t_ns, .origin = origin});
      break;
    case Group::kAxis:
      break;
  }
}

void PollDecoder::emit(const core::Event& e) noexcept {
  // Capacity reserved in the constructor for every group and sensor: never reallocates.
  if (out_.size() < out_.capacity()) {
    out_.push_back(e);
  }
}

std::span<const core::Event> PollDecoder::decode(core::TimeNs t_ns,
                                                 std::span<const std::uint8_t> block_ok) {
  out_.clear();
  const auto group_read = [&](const GroupMap& g, std::size_t n) {
    for (std::size_t f = 0; f < n; ++f) {
      if (g.fields[f].mapped && block_ok[g.fields[f].block] == 0) {
        return false;
      }
    }
    return true;
  };
  for (std::size_t gi = 0; gi < kGroupCount; ++gi) {
    const auto g = static_cast<Group>(gi);
    const GroupMap& gm = config_.groups[gi];
    if (!gm.present || !group_read(gm, field_count(g))) {
      continue;
    }
    if (g == Group::kAxis) {
      decode_axis(t_ns);
    } else {
      decode_event(g, t_ns);
    }
  }
  decode_temperatures(t_ns, block_ok);
  return out_;
}

void PollDecoder::decode_axis(core::TimeNs t_ns) {
  const GroupMap& g = config_.groups[static_cast<std::size_t>(Group::kAxis)];
  if (!in_range(g, axis_field::kCount)) {
    ++counters_.values_out_of_range;
    return;
  }
  core::AxisSample s;
  s.time_ns = t_ns;
  s.axis_count = 0;
  bool ok = true;
  for (std::size_t a = axis_field::kX; a <= axis_field::kC; ++a) {
    if (!g.fields[a].mapped) {
      break;
    }
    const double v = value(g.fields[a]);
    ok = ok && std::isfinite(v);
    s.position_mm[a] = v;
    ++s.axis_count;
  }
  if (g.fields[axis_field::kPath].mapped) {
    // NaN is the core's "path unknown" (e.g. no program active); inf is garbage.
    s.program_path_mm = value(g.fields[axis_field::kPath]);
    ok = ok && !std::isinf(s.program_path_mm);
  }
  if (g.fields[axis_field::kTool].mapped) {
    ok = ok && to_int(value(g.fields[axis_field::kTool]), 0, kIntMax, s.tool);
  }
  if (g.fields[axis_field::kNormalX].mapped) {
    const double nx = value(g.fields[axis_field::kNormalX]);
    const double ny = value(g.fields[axis_field::kNormalY]);
    const double nz = value(g.fields[axis_field::kNormalZ]);
    const double norm = std::sqrt(nx * nx + ny * ny + nz * nz);
    // Scaled integers carry a little rounding; anything far from unit length is not a normal.
    // All three exactly 0 is the NC's "no normal known" (not cutting, no surface under the
    // tool): a valid sample without a normal, as a zero normal over CAN.
    const auto zero = [](double v) { return std::fpclassify(v) == FP_ZERO; };
    if (zero(nx) && zero(ny) && zero(nz)) {
      s.has_normal = false;
    } else if (std::isfinite(norm) && std::fabs(norm - 1.0) < 0.01) {
      s.has_normal = true;
      s.normal = {nx / norm, ny / norm, nz / norm};
    } else {
      ok = false;
    }
  }
  if (g.fields[axis_field::kCutting].mapped) {
    s.cutting = value(g.fields[axis_field::kCutting]) > 0.5;
  }
  if (!ok) {
    ++counters_.values_invalid;
    return;
  }
  emit(s);
}

void PollDecoder::decode_event(Group g, core::TimeNs t_ns) {
  const auto gi = static_cast<std::size_t>(g);
  const GroupMap& gm = config_.groups[gi];
  const SignalMap& seq_map = gm.fields[0];
  const bool wide = seq_map.encoding.type == ValueType::kUint32;
  // The counter is read raw: scale and offset make no sense for it.
  const std::vector<std::uint16_t>& b = blocks_[seq_map.block];
  const auto seq = static_cast<std::uint32_t>(
      decode_raw(std::span<const std::uint16_t>(b.data() + seq_map.block_offset, wide ? 2U : 1U),
                 seq_map.encoding));
  SeqState& st = seq_[gi];
  if (!st.baseline) {
    st.baseline = true;
    st.reconnected = false;
    st.last = seq;
    emit_counter(g, t_ns, seq);  // the engine's cursor from now on, also after a restart
    return;
  }
  const bool first_after_reconnect = st.reconnected;
  st.reconnected = false;
  // The first read after a start with the engine's cursor: what it finds is reported.
  const bool resumed = st.resumed;
  st.resumed = false;
  if (resumed) {
    resume_[gi] = ResumeReport{true, st.last, seq, false, 0, false};
  }
  if (seq == st.last) {
    // After a reconnect this is also what an NC shows that restarted and produced exactly as
    // many events as it had before: its newest would be missed, and nothing here can tell.
    if (first_after_reconnect && seq != kSequenceStart) {
      ++counters_.sequence_unchanged_after_reconnect;
    }
    return;
  }
  // Events since the last read, as far as the counter tells.
  std::uint32_t events = seq - st.last;
  if (seq < st.last) {
    const std::uint32_t mask = wide ? 0xFFFFFFFFU : 0xFFFFU;
    events = (seq - st.last) & mask;  // on through the top of the range
    if (events > kMaxWrapEvents) {
      // Not a wrap: the NC restarted and counted again from its start value.
      ++counters_.sequence_resets;
      events = seq - kSequenceStart;
      resume_[gi].nc_restarted = resumed;
    }
  }
  st.last = seq;
  if (resumed) {
    resume_[gi].events = events;
  }
  if (events == 0) {
    emit_counter(g, t_ns, seq);
    return;  // restarted, no event since: the value registers hold none
  }
  (resumed ? counters_.events_lost_while_down : counters_.events_lost) += events - 1U;
  const std::size_t emitted_before = out_.size();
  // The counter is consumed either way: an event with an implausible value is dropped once (a
  // measurement is delivered once, marked faulted), never re-read.
  const bool range_ok = in_range(gm, field_count(g));
  if (!range_ok) {
    ++counters_.values_out_of_range;
    if (g != Group::kToolMeasurement && g != Group::kProbeMeasurement &&
        g != Group::kCalibrationTouch) {
      return;
    }
  }

  const core::EventOrigin origin{seq, 0, true};  // the engine's cursor once it takes the event
  const auto f = [&](std::size_t i, double dflt) {
    return gm.fields[i].mapped ? value(gm.fields[i]) : dflt;
  };
  bool ok = true;
  switch (g) {
    case Group::kToolMeasurement: {
      core::ToolMeasurement e;
      e.time_ns = t_ns;
      e.origin = origin;
      ok = to_int(f(tool_meas_field::kTool, 0), 0, kIntMax, e.tool);
      const SignalMap& wear = gm.fields[tool_meas_field::kWear];
      e.point_count = wear.count;
      const std::vector<std::uint16_t>& wb = blocks_[wear.block];
      for (std::size_t i = 0; i < wear.count; ++i) {
        const std::size_t at = wear.block_offset + i * width(wear.encoding.type);
        e.wear_um[i] = modbus::decode(
            std::span<const std::uint16_t>(wb.data() + at, width(wear.encoding.type)),
            wear.encoding);
        ok = ok && std::isfinite(e.wear_um[i]);
      }
      e.broken = f(tool_meas_field::kBroken, 0.0) > 0.5;
      emit_measurement(e, range_ok, ok);
      break;
    }
    case Group::kProbeMeasurement: {
      core::ProbeMeasurement e;
      e.time_ns = t_ns;
      e.origin = origin;
      e.checkpoint = -1;  // unknown, unless it decodes
      const bool part_ok = to_int(f(probe_field::kPart, 0), kIntMin, kIntMax, e.part);
      ok = to_int(f(probe_field::kCheckpoint, 0), kIntMin, kIntMax, e.checkpoint) && part_ok;
      e.raw_deviation_um = f(probe_field::kDeviation, 0.0);
      e.wall_angle_deg = f(probe_field::kAngle, 0.0);
      e.ball_radius_mm = f(probe_field::kBallRadius, 0.0);
      e.position_mm = {f(probe_field::kX, 0.0), f(probe_field::kY, 0.0), f(probe_field::kZ, 0.0)};
      ok = ok && std::isfinite(e.raw_deviation_um) && std::isfinite(e.wall_angle_deg) &&
           std::isfinite(e.ball_radius_mm) && std::isfinite(e.position_mm[0]) &&
           std::isfinite(e.position_mm[1]) && std::isfinite(e.position_mm[2]);
      emit_measurement(e, range_ok, ok);
      break;
    }
    case Group::kCalibrationTouch: {
      core::CalibrationTouch e;
      e.time_ns = t_ns;
      e.origin = origin;
      std::int32_t probe = 0;
      std::int32_t axis = 0;
      std::int32_t dir = 1;
      std::int32_t variant = 0;
      ok = to_int(f(touch_field::kProbe, 0), 0, 1, probe) &&
           to_int(f(touch_field::kAxis, 0), 0, 2, axis) &&
           to_int(f(touch_field::kDirection, 0), -1, 1, dir) && dir != 0 &&
           to_int(f(touch_field::kVariant, 0), 0, 1, variant);
      dir = dir == 0 ? 1 : dir;  // a faulted touch still carries a valid direction
      e.probe = static_cast<core::ProbeKind>(probe);
      e.axis = static_cast<std::uint8_t>(axis);
      e.direction = static_cast<std::int8_t>(dir);
      e.variant = static_cast<std::uint8_t>(variant);
      e.trigger_position_mm = f(touch_field::kPosition, 0.0);
      ok = ok && std::isfinite(e.trigger_position_mm);
      emit_measurement(e, range_ok, ok);
      break;
    }
    case Group::kToolChange: {
      core::ToolChange e;
      e.time_ns = t_ns;
      e.origin = origin;
      ok = to_int(f(tool_change_field::kTool, 0), 0, kIntMax, e.tool);
      e.sister = f(tool_change_field::kSister, 0.0) > 0.5;
      if (ok) {
        emit(e);
      }
      break;
    }
    case Group::kProgramEvent: {
      core::ProgramEvent e;
      e.time_ns = t_ns;
      e.origin = origin;
      std::int32_t kind = 0;
      ok = to_int(f(program_field::kKind, 0), 0, 3, kind) &&
           to_int(f(program_field::kPart, 0), kIntMin, kIntMax, e.part);
      e.kind = static_cast<core::ProgramEventKind>(kind);
      if (ok) {
        emit(e);
      }
      break;
    }
    case Group::kAxis:
      break;
  }
  if (!ok && g != Group::kToolMeasurement && g != Group::kProbeMeasurement &&
      g != Group::kCalibrationTouch) {
    ++counters_.values_invalid;
  }
  if (resumed && out_.size() > emitted_before) {
    resume_[gi].delivered = true;
    ++counters_.events_recovered_after_start;
  }
}

void PollDecoder::emit_measurement(core::Event e, bool range_ok, bool ok) noexcept {
  if (range_ok && !ok) {
    ++counters_.values_invalid;
  }
  if (!range_ok || !ok) {
    core::set_fault(e, range_ok ? core::InputFault::kInvalid : core::InputFault::kOutOfRange);
  }
  emit(e);
}

void PollDecoder::decode_temperatures(core::TimeNs t_ns, std::span<const std::uint8_t> block_ok) {
  // Temperatures change slowly: a sample is emitted when the value changed, not every poll.
  for (std::size_t i = 0; i < config_.temperatures.size(); ++i) {
    const TemperatureMap& tm = config_.temperatures[i];
    if (block_ok[tm.value.block] == 0) {
      continue;
    }
    const double v = value(tm.value);
    if (!std::isfinite(v)) {
      ++counters_.values_invalid;
      continue;
    }
    if (v < tm.value.min || v > tm.value.max) {
      ++counters_.values_out_of_range;
      continue;
    }
    const double last = last_temperature_[i];
    if (!std::isnan(last) && !(v < last) && !(v > last)) {
      continue;
    }
    last_temperature_[i] = v;
    core::TemperatureSample e;
    e.time_ns = t_ns;
    e.sensor = tm.sensor;
    e.temperature_c = v;
    emit(e);
  }
}

}  // namespace nccomp::drivers::modbus
