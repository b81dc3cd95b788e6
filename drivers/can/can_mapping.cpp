#include "drivers/can/can_mapping.hpp"

#include <algorithm>
#include <bit>
#include <bitset>
#include <cmath>
#include <cstring>
#include <limits>
#include <set>
#include <sstream>
#include <utility>

namespace nccomp::drivers::can {

namespace {

struct FieldInfo {
  EventKind kind;
  Field field;
  std::string_view name;
  // Integral fields: the physical value must be an integer in [lo, hi]. Others: any finite.
  bool integral;
  double lo;
  double hi;
};

constexpr double kInt32Lo = std::numeric_limits<std::int32_t>::min();
constexpr double kInt32Hi = std::numeric_limits<std::int32_t>::max();
constexpr double kAny = 1e300;

// The names an operator writes in the config, per event. Positions are per axis (mm / deg).
constexpr std::array<FieldInfo, 34> kFields{{
    {EventKind::kAxisSample, Field::kXmm, "x_mm", false, -kAny, kAny},
    {EventKind::kAxisSample, Field::kYmm, "y_mm", false, -kAny, kAny},
    {EventKind::kAxisSample, Field::kZmm, "z_mm", false, -kAny, kAny},
    {EventKind::kAxisSample, Field::kAdeg, "a_deg", false, -kAny, kAny},
    {EventKind::kAxisSample, Field::kBdeg, "b_deg", false, -kAny, kAny},
    {EventKind::kAxisSample, Field::kCdeg, "c_deg", false, -kAny, kAny},
    {EventKind::kAxisSample, Field::kProgramPathMm, "program_path_mm", false, -kAny, kAny},
    {EventKind::kAxisSample, Field::kTool, "tool", true, 0, kInt32Hi},
    {EventKind::kAxisSample, Field::kNormalX, "normal_x", false, -1.0, 1.0},
    {EventKind::kAxisSample, Field::kNormalY, "normal_y", false, -1.0, 1.0},
    {EventKind::kAxisSample, Field::kNormalZ, "normal_z", false, -1.0, 1.0},
    {EventKind::kAxisSample, Field::kCutting, "cutting", true, 0, 1},
    {EventKind::kToolMeasurement, Field::kTool, "tool", true, 0, kInt32Hi},
    {EventKind::kToolMeasurement, Field::kBroken, "broken", true, 0, 1},
    {EventKind::kToolMeasurement, Field::kWearUm, "wear_um", false, -kAny, kAny},
    {EventKind::kProbeMeasurement, Field::kPart, "part", true, kInt32Lo, kInt32Hi},
    {EventKind::kProbeMeasurement, Field::kCheckpoint, "checkpoint", true, kInt32Lo, kInt32Hi},
    {EventKind::kProbeMeasurement, Field::kRawDeviationUm, "raw_deviation_um", false, -kAny, kAny},
    {EventKind::kProbeMeasurement, Field::kWallAngleDeg, "wall_angle_deg", false, -kAny, kAny},
    {EventKind::kProbeMeasurement, Field::kBallRadiusMm, "ball_radius_mm", false, 0.0, kAny},
    {EventKind::kProbeMeasurement, Field::kXmm, "x_mm", false, -kAny, kAny},
    {EventKind::kProbeMeasurement, Field::kYmm, "y_mm", false, -kAny, kAny},
    {EventKind::kProbeMeasurement, Field::kZmm, "z_mm", false, -kAny, kAny},
    {EventKind::kCalibrationTouch, Field::kProbe, "probe", true, 0, 1},
    {EventKind::kCalibrationTouch, Field::kAxis, "axis", true, 0, 2},
    {EventKind::kCalibrationTouch, Field::kDirection, "direction", true, -1, 1},
    {EventKind::kCalibrationTouch, Field::kVariant, "variant", true, 0, 1},
    {EventKind::kCalibrationTouch, Field::kTriggerPositionMm, "trigger_position_mm", false, -kAny,
     kAny},
    {EventKind::kToolChange, Field::kTool, "tool", true, 0, kInt32Hi},
    {EventKind::kToolChange, Field::kSister, "sister", true, 0, 1},
    {EventKind::kProgramEvent, Field::kProgramKind, "kind", true, 0, 3},
    {EventKind::kProgramEvent, Field::kPart, "part", true, kInt32Lo, kInt32Hi},
    {EventKind::kTemperature, Field::kSensor, "sensor", true, 0, 255},
    {EventKind::kTemperature, Field::kTemperatureC, "temperature_c", false, -kAny, kAny},
}};

constexpr std::array<std::string_view, kEventKinds> kEventNames{
    "axis_sample", "tool_measurement", "probe_measurement", "calibration_touch",
    "tool_change", "program_event",    "temperature"};

const FieldInfo* field_info(EventKind kind, Field field) noexcept {
  for (const auto& f : kFields) {
    if (f.kind == kind && f.field == field) {
      return &f;
    }
  }
  return nullptr;
}

/// Reports a problem of the mapping element at `o`, about its key `key` ("" = the element).
class Reporter {
 public:
  Reporter(const CanMapping& m, formats::Diagnostics& diag, const formats::KeyPositions* positions)
      : m_(m), diag_(diag), positions_(positions) {}

  void error(const Origin& o, const std::string& key, std::string message) {
    const std::string path = key.empty() ? o.key_path : o.key_path + "." + key;
    Origin fallback = o;
    if (fallback.file.empty()) {
      fallback.file = m_.file;
    }
    formats::Where w =
        positions_ != nullptr ? formats::position_of(*positions_, path, fallback) : fallback;
    w.key_path = path;
    diag_.error(std::move(w), std::move(message));
    ++count_;
  }
  [[nodiscard]] std::size_t count() const noexcept { return count_; }

 private:
  const CanMapping& m_;
  formats::Diagnostics& diag_;
  const formats::KeyPositions* positions_;
  std::size_t count_{0};
};

std::string hex(std::uint32_t id) {
  std::ostringstream s;
  s << "0x" << std::hex << std::uppercase << id;
  return s.str();
}

/// Reports the first problem of a layout (the later checks depend on the earlier ones) and marks
/// its bits in `used`; false if it reported one.
bool check_layout(Reporter& rep, const Origin& o, const std::string& key, const SignalLayout& l,
                  std::size_t length_bytes, std::bitset<kMaxPayloadBytes * 8>* used) {
  const std::string k = key.empty() ? std::string() : key + ".";
  if (l.length_bits == 0 || l.length_bits > 64) {
    rep.error(o, k + "length_bits", "must be 1..64, got " + std::to_string(l.length_bits));
    return false;
  }
  if (l.type == ValueType::kFloat && l.length_bits != 32 && l.length_bits != 64) {
    rep.error(o, k + "length_bits",
              "a float signal is 32 or 64 bits, got " + std::to_string(l.length_bits));
    return false;
  }
  if (!std::isfinite(l.scale) || std::fabs(l.scale) < 1e-300) {
    rep.error(o, k + "scale", "must be finite and non-zero");
    return false;
  }
  if (!std::isfinite(l.offset)) {
    rep.error(o, k + "offset", "must be finite");
    return false;
  }
  std::array<std::uint16_t, 64> pos{};
  const std::size_t frame_bits = length_bytes * 8;
  if (signal_bit_positions(l, frame_bits, pos) == 0) {
    rep.error(o, k + "start_bit",
              "signal (start_bit " + std::to_string(l.start_bit) + ", length_bits " +
                  std::to_string(l.length_bits) + ") overflows the " +
                  std::to_string(length_bytes) + "-byte frame");
    return false;
  }
  if (used != nullptr) {
    for (std::size_t i = 0; i < l.length_bits; ++i) {
      if (used->test(pos[i])) {
        rep.error(o, k + "start_bit",
                  "overlaps another signal of the frame at bit " + std::to_string(pos[i]));
        return false;
      }
    }
    for (std::size_t i = 0; i < l.length_bits; ++i) {
      used->set(pos[i]);
    }
  }
  return true;
}

void check_id(Reporter& rep, const Origin& o, const std::string& key, std::uint32_t id,
              bool extended) {
  const std::uint32_t max = extended ? kMaxExtendedId : kMaxStandardId;
  if (id > max) {
    rep.error(o, key,
              hex(id) + " exceeds the " + std::string(extended ? "29" : "11") +
                  "-bit ID range (max " + hex(max) + ")");
  }
}

void check_length(Reporter& rep, const CanMapping& m, const Origin& o, std::size_t length_bytes) {
  if (!valid_payload_length(length_bytes, m.fd)) {
    rep.error(o, "length_bytes",
              std::to_string(length_bytes) +
                  (m.fd ? " is not a CAN FD payload length (0-8, 12, 16, 20, 24, 32, 48, 64)"
                        : " exceeds 8 bytes (classic CAN; set can.fd = true for CAN FD)"));
  }
}

std::int64_t sign_extend(std::uint64_t raw, unsigned bits) noexcept {
  if (bits >= 64) {
    return static_cast<std::int64_t>(raw);
  }
  const std::uint64_t m = std::uint64_t{1} << (bits - 1);
  return static_cast<std::int64_t>((raw ^ m) - m);
}

void apply(core::Event& ev, Field field, double v) noexcept {
  std::visit(
      [&](auto& e) {
        using E = std::decay_t<decltype(e)>;
        if constexpr (std::is_same_v<E, core::AxisSample>) {
          switch (field) {
            case Field::kXmm:
              e.position_mm[0] = v;
              break;
            case Field::kYmm:
              e.position_mm[1] = v;
              break;
            case Field::kZmm:
              e.position_mm[2] = v;
              break;
            case Field::kAdeg:
              e.position_mm[3] = v;
              break;
            case Field::kBdeg:
              e.position_mm[4] = v;
              break;
            case Field::kCdeg:
              e.position_mm[5] = v;
              break;
            case Field::kProgramPathMm:
              e.program_path_mm = v;
              break;
            case Field::kTool:
              e.tool = static_cast<std::int32_t>(v);
              break;
            case Field::kNormalX:
              e.normal[0] = v;
              break;
            case Field::kNormalY:
              e.normal[1] = v;
              break;
            case Field::kNormalZ:
              e.normal[2] = v;
              break;
            case Field::kCutting:
              e.cutting = v > 0.5;
              break;
            default:
              break;
          }
        } else if constexpr (std::is_same_v<E, core::ToolMeasurement>) {
          switch (field) {
            case Field::kTool:
              e.tool = static_cast<std::int32_t>(v);
              break;
            case Field::kBroken:
              e.broken = v > 0.5;
              break;
            case Field::kWearUm:
              e.wear_um[0] = v;
              break;
            default:
              break;
          }
        } else if constexpr (std::is_same_v<E, core::ProbeMeasurement>) {
          switch (field) {
            case Field::kPart:
              e.part = static_cast<std::int32_t>(v);
              break;
            case Field::kCheckpoint:
              e.checkpoint = static_cast<std::int32_t>(v);
              break;
            case Field::kRawDeviationUm:
              e.raw_deviation_um = v;
              break;
            case Field::kWallAngleDeg:
              e.wall_angle_deg = v;
              break;
            case Field::kBallRadiusMm:
              e.ball_radius_mm = v;
              break;
            case Field::kXmm:
              e.position_mm[0] = v;
              break;
            case Field::kYmm:
              e.position_mm[1] = v;
              break;
            case Field::kZmm:
              e.position_mm[2] = v;
              break;
            default:
              break;
          }
        } else if constexpr (std::is_same_v<E, core::CalibrationTouch>) {
          switch (field) {
            case Field::kProbe:
              e.probe = static_cast<core::ProbeKind>(static_cast<int>(v));
              break;
            case Field::kAxis:
              e.axis = static_cast<std::uint8_t>(v);
              break;
            case Field::kDirection:
              e.direction = static_cast<std::int8_t>(v);
              break;
            case Field::kVariant:
              e.variant = static_cast<std::uint8_t>(v);
              break;
            case Field::kTriggerPositionMm:
              e.trigger_position_mm = v;
              break;
            default:
              break;
          }
        } else if constexpr (std::is_same_v<E, core::ToolChange>) {
          switch (field) {
            case Field::kTool:
              e.tool = static_cast<std::int32_t>(v);
              break;
            case Field::kSister:
              e.sister = v > 0.5;
              break;
            default:
              break;
          }
        } else if constexpr (std::is_same_v<E, core::ProgramEvent>) {
          switch (field) {
            case Field::kProgramKind:
              e.kind = static_cast<core::ProgramEventKind>(static_cast<int>(v));
              break;
            case Field::kPart:
              e.part = static_cast<std::int32_t>(v);
              break;
            default:
              break;
          }
        } else if constexpr (std::is_same_v<E, core::TemperatureSample>) {
          switch (field) {
            case Field::kSensor:
              e.sensor = static_cast<std::uint8_t>(v);
              break;
            case Field::kTemperatureC:
              e.temperature_c = v;
              break;
            default:
              break;
          }
        }
      },
      ev);
}

void set_time(core::Event& ev, core::TimeNs t) noexcept {
  std::visit([t](auto& e) { e.time_ns = t; }, ev);
}

core::Event initial_event(EventKind kind, std::uint8_t axis_count, bool has_normal) {
  switch (kind) {
    case EventKind::kAxisSample: {
      core::AxisSample s{};
      s.axis_count = axis_count;
      s.has_normal = has_normal;
      return s;
    }
    case EventKind::kToolMeasurement:
      return core::ToolMeasurement{};
    case EventKind::kProbeMeasurement:
      return core::ProbeMeasurement{};
    case EventKind::kCalibrationTouch:
      return core::CalibrationTouch{};
    case EventKind::kToolChange:
      return core::ToolChange{};
    case EventKind::kProgramEvent:
      return core::ProgramEvent{};
    case EventKind::kTemperature:
      return core::TemperatureSample{};
  }
  return core::AxisSample{};
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Bit codec

std::size_t signal_bit_positions(const SignalLayout& layout, std::size_t frame_bits,
                                 std::array<std::uint16_t, 64>& positions) noexcept {
  const std::size_t n = layout.length_bits;
  if (n == 0 || n > 64 || frame_bits > kMaxPayloadBytes * 8) {
    return 0;
  }
  if (layout.byte_order == ByteOrder::kLittleEndian) {
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t p = layout.start_bit + i;
      if (p >= frame_bits) {
        return 0;
      }
      positions[i] = static_cast<std::uint16_t>(p);
    }
    return n;
  }
  // Motorola: start at the MSB, walk down within a byte, then to bit 7 of the next byte.
  std::size_t p = layout.start_bit;
  for (std::size_t j = 0; j < n; ++j) {
    if (p >= frame_bits) {
      return 0;
    }
    positions[n - 1 - j] = static_cast<std::uint16_t>(p);
    if (j + 1 < n) {
      p = (p % 8 == 0) ? p + 15 : p - 1;
    }
  }
  return n;
}

std::uint64_t extract_raw(const SignalLayout& layout, std::span<const std::uint8_t> data) noexcept {
  std::array<std::uint16_t, 64> pos{};
  const std::size_t n = signal_bit_positions(layout, data.size() * 8, pos);
  std::uint64_t raw = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const unsigned bit = (static_cast<unsigned>(data[pos[i] / 8U]) >> (pos[i] % 8U)) & 1U;
    raw |= std::uint64_t{bit} << i;
  }
  return raw;
}

void insert_raw(const SignalLayout& layout, std::uint64_t raw,
                std::span<std::uint8_t> data) noexcept {
  std::array<std::uint16_t, 64> pos{};
  const std::size_t n = signal_bit_positions(layout, data.size() * 8, pos);
  for (std::size_t i = 0; i < n; ++i) {
    const auto mask = static_cast<std::uint8_t>(1U << (pos[i] % 8U));
    if (((raw >> i) & 1U) != 0) {
      data[pos[i] / 8U] = static_cast<std::uint8_t>(data[pos[i] / 8U] | mask);
    } else {
      data[pos[i] / 8U] = static_cast<std::uint8_t>(data[pos[i] / 8U] & ~mask);
    }
  }
}

double raw_to_physical(const SignalLayout& layout, std::uint64_t raw) noexcept {
  double v = 0.0;
  switch (layout.type) {
    case ValueType::kUnsigned:
      v = static_cast<double>(raw);
      break;
    case ValueType::kSigned:
      v = static_cast<double>(sign_extend(raw, layout.length_bits));
      break;
    case ValueType::kFloat:
      if (layout.length_bits == 32) {
        v = static_cast<double>(std::bit_cast<float>(static_cast<std::uint32_t>(raw)));
      } else {
        v = std::bit_cast<double>(raw);
      }
      break;
  }
  return v * layout.scale + layout.offset;
}

std::optional<std::uint64_t> physical_to_raw(const SignalLayout& layout, double value) noexcept {
  if (!std::isfinite(value)) {
    return std::nullopt;
  }
  const double r = (value - layout.offset) / layout.scale;
  if (!std::isfinite(r)) {
    return std::nullopt;
  }
  const unsigned bits = layout.length_bits;
  switch (layout.type) {
    case ValueType::kFloat:
      if (bits == 32) {
        const auto f = static_cast<float>(r);
        if (!std::isfinite(f)) {
          return std::nullopt;
        }
        return std::bit_cast<std::uint32_t>(f);
      }
      return std::bit_cast<std::uint64_t>(r);
    case ValueType::kUnsigned: {
      const double q = std::nearbyint(r);
      const double hi = std::ldexp(1.0, static_cast<int>(bits)) - 1.0;
      if (q < 0.0 || q > hi || bits > 63) {
        if (bits == 64 && q >= 0.0 && q < 18446744073709551615.0) {
          return static_cast<std::uint64_t>(q);
        }
        return std::nullopt;
      }
      return static_cast<std::uint64_t>(q);
    }
    case ValueType::kSigned: {
      const double q = std::nearbyint(r);
      const double lim = std::ldexp(1.0, static_cast<int>(bits) - 1);
      if (q < -lim || q > lim - 1.0) {
        return std::nullopt;
      }
      const auto s = static_cast<std::int64_t>(q);
      const std::uint64_t mask = bits >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << bits) - 1;
      return static_cast<std::uint64_t>(s) & mask;
    }
  }
  return std::nullopt;
}

// ---------------------------------------------------------------------------------------------
// Names

std::optional<EventKind> event_kind_from_name(std::string_view name) noexcept {
  for (std::size_t i = 0; i < kEventNames.size(); ++i) {
    if (kEventNames[i] == name) {
      return static_cast<EventKind>(i);
    }
  }
  return std::nullopt;
}

std::string_view event_kind_name(EventKind kind) noexcept {
  return kEventNames[static_cast<std::size_t>(kind)];
}

std::optional<Field> field_from_name(EventKind kind, std::string_view name) noexcept {
  for (const auto& f : kFields) {
    if (f.kind == kind && f.name == name) {
      return f.field;
    }
  }
  return std::nullopt;
}

std::string field_names(EventKind kind) {
  std::string s;
  for (const auto& f : kFields) {
    if (f.kind == kind) {
      if (!s.empty()) {
        s += ", ";
      }
      s += f.name;
    }
  }
  return s;
}

bool valid_payload_length(std::size_t n, bool fd) noexcept {
  if (n <= 8) {
    return true;
  }
  if (!fd) {
    return false;
  }
  return n == 12 || n == 16 || n == 20 || n == 24 || n == 32 || n == 48 || n == 64;
}

// ---------------------------------------------------------------------------------------------
// Validation

bool validate_mapping(CanMapping& m, formats::Diagnostics& diag,
                      const formats::KeyPositions* positions) {
  Reporter rep(m, diag, positions);
  std::set<std::uint32_t> rx_ids;
  std::set<std::pair<EventKind, Field>> mapped;
  int max_axis = 2;
  for (auto& f : m.rx) {
    check_id(rep, f.origin, "id", f.id, f.extended);
    check_length(rep, m, f.origin, f.length_bytes);
    if (!rx_ids.insert(id_key(f.id, f.extended)).second) {
      rep.error(f.origin, "id", "frame ID " + hex(f.id) + " is mapped twice");
    }
    if (f.signals.empty()) {
      rep.error(f.origin, "signal", "a received frame needs at least one signal");
    }
    std::bitset<kMaxPayloadBytes * 8> used;
    for (auto& s : f.signals) {
      const auto field = field_from_name(f.event, s.name);
      if (!field) {
        rep.error(s.origin, "name",
                  "unknown signal '" + s.name + "' for event " +
                      std::string(event_kind_name(f.event)) + " (known: " + field_names(f.event) +
                      ")");
        continue;
      }
      s.field = *field;
      if (!mapped.insert({f.event, *field}).second) {
        rep.error(s.origin, "name",
                  "signal '" + s.name + "' of " + std::string(event_kind_name(f.event)) +
                      " is mapped by more than one frame");
      }
      (void)check_layout(rep, s.origin, "", s.layout, f.length_bytes, &used);
      if (std::isnan(s.min) || std::isnan(s.max) || s.min > s.max) {
        rep.error(s.origin, "min", "min must be <= max");
      }
      if (f.event == EventKind::kAxisSample) {
        const int axis = static_cast<int>(*field) - static_cast<int>(Field::kXmm);
        if (axis >= 0 && axis < static_cast<int>(core::kMaxAxes)) {
          max_axis = std::max(max_axis, axis);
        }
      }
    }
  }
  m.axis_count = static_cast<std::uint8_t>(max_axis + 1);
  std::set<std::uint16_t> regs;
  std::set<std::uint32_t> tx_ids;
  for (auto& r : m.offsets) {
    check_id(rep, r.origin, "id", r.id, r.extended);
    check_length(rep, m, r.origin, r.length_bytes);
    if (!regs.insert(r.register_index).second) {
      rep.error(r.origin, "register",
                "register " + std::to_string(r.register_index) + " is mapped twice");
    }
    const std::uint32_t k = id_key(r.id, r.extended);
    if (rx_ids.count(k) != 0 || !tx_ids.insert(k).second) {
      rep.error(r.origin, "id", "frame ID " + hex(r.id) + " is already used by another frame");
    }
    (void)check_layout(rep, r.origin, "value", r.value, r.length_bytes, nullptr);
    if (r.ack) {
      check_id(rep, r.origin, "ack_id", r.ack->id, r.ack->extended);
      const std::uint32_t a = id_key(r.ack->id, r.ack->extended);
      if (rx_ids.count(a) != 0 || !tx_ids.insert(a).second) {
        rep.error(r.origin, "ack_id",
                  "acknowledge ID " + hex(r.ack->id) + " is already used by another frame");
      }
    }
  }
  return rep.count() == 0;
}

// ---------------------------------------------------------------------------------------------
// Decoder

FrameDecoder::FrameDecoder(const CanMapping& mapping) : mapping_(mapping) {
  bool has_normal = false;
  for (const auto& f : mapping.rx) {
    for (const auto& s : f.signals) {
      has_normal = has_normal || s.field == Field::kNormalX || s.field == Field::kNormalY ||
                   s.field == Field::kNormalZ;
    }
  }
  for (std::size_t i = 0; i < kEventKinds; ++i) {
    latest_[i] = initial_event(static_cast<EventKind>(i), mapping.axis_count, has_normal);
  }
  for (std::size_t i = 0; i < mapping.rx.size(); ++i) {
    index_.emplace_back(id_key(mapping.rx[i].id, mapping.rx[i].extended), static_cast<int>(i));
  }
  std::sort(index_.begin(), index_.end());
}

int FrameDecoder::find(std::uint32_t id, bool extended) const noexcept {
  const std::uint32_t k = id_key(id, extended);
  const auto it = std::lower_bound(index_.begin(), index_.end(), std::make_pair(k, -1));
  return (it != index_.end() && it->first == k) ? it->second : -1;
}

FrameDecoder::Result FrameDecoder::decode(std::uint32_t id, bool extended,
                                          std::span<const std::uint8_t> payload,
                                          core::TimeNs now_ns, core::Event& out) noexcept {
  const int idx = find(id, extended);
  if (idx < 0) {
    return {RejectReason::kUnknownId, false};
  }
  const RxFrame& f = mapping_.rx[static_cast<std::size_t>(idx)];
  if (payload.size() != f.length_bytes) {
    return reject(f, RejectReason::kWrongLength, now_ns, out);
  }
  // Check every signal before applying any: a malformed frame leaves the latest values alone.
  std::array<double, kMaxPayloadBytes * 8> values{};
  for (std::size_t i = 0; i < f.signals.size(); ++i) {
    const RxSignal& s = f.signals[i];
    const double v = raw_to_physical(s.layout, extract_raw(s.layout, payload));
    if (!std::isfinite(v)) {
      return reject(f, RejectReason::kNotFinite, now_ns, out);
    }
    const FieldInfo* info = field_info(f.event, s.field);
    if (v < s.min || v > s.max || (info != nullptr && (v < info->lo || v > info->hi))) {
      return reject(f, RejectReason::kOutOfRange, now_ns, out);
    }
    if (info != nullptr && info->integral && std::fabs(v - std::nearbyint(v)) > 1e-9) {
      return reject(f, RejectReason::kOutOfRange, now_ns, out);
    }
    if (s.field == Field::kDirection && std::fabs(v) < 0.5) {
      // An approach direction is +1 or -1.
      return reject(f, RejectReason::kOutOfRange, now_ns, out);
    }
    values[i] = (info != nullptr && info->integral) ? std::nearbyint(v) : v;
  }
  const auto k = static_cast<std::size_t>(f.event);
  core::Event& ev = latest_[k];
  for (std::size_t i = 0; i < f.signals.size(); ++i) {
    apply(ev, f.signals[i].field, values[i]);
  }
  set_time(ev, now_ns);
  if (!f.emit) {
    return {RejectReason::kNone, false};
  }
  out = ev;
  // A measurement one of whose earlier frames was rejected is delivered faulted.
  core::set_fault(out, faults_[k]);
  faults_[k] = core::InputFault::kNone;
  return {RejectReason::kNone, true};
}

FrameDecoder::Result FrameDecoder::reject(const RxFrame& f, RejectReason why, core::TimeNs now_ns,
                                          core::Event& out) noexcept {
  if (f.event != EventKind::kToolMeasurement && f.event != EventKind::kProbeMeasurement &&
      f.event != EventKind::kCalibrationTouch) {
    return {why, false};
  }
  // The NC reported a measurement whose values cannot be used: it is delivered faulted (its
  // method raises the alarm), never dropped in silence, and never with an earlier measurement's
  // values in the fields this frame carries (they become unknown).
  const auto k = static_cast<std::size_t>(f.event);
  core::Event& ev = latest_[k];
  for (const RxSignal& s : f.signals) {
    apply(ev, s.field,
          s.field == Field::kCheckpoint  ? -1.0
          : s.field == Field::kDirection ? 1.0
                                         : 0.0);
  }
  set_time(ev, now_ns);
  if (faults_[k] == core::InputFault::kNone) {
    faults_[k] = why == RejectReason::kOutOfRange ? core::InputFault::kOutOfRange
                                                  : core::InputFault::kInvalid;
  }
  if (!f.emit) {
    return {why, false};
  }
  out = ev;
  core::set_fault(out, faults_[k]);
  faults_[k] = core::InputFault::kNone;
  return {why, true};
}

bool encode_offset(const TxRegister& reg, double value_um,
                   std::span<std::uint8_t, kMaxPayloadBytes> payload) noexcept {
  const auto raw = physical_to_raw(reg.value, value_um);
  std::fill(payload.begin(), payload.end(), std::uint8_t{0});
  if (!raw) {
    return false;
  }
  insert_raw(reg.value, *raw, payload.first(reg.length_bytes));
  return true;
}

std::optional<double> field_value(const core::Event& event, Field field) noexcept {
  return std::visit(
      [field](const auto& e) -> std::optional<double> {
        using E = std::decay_t<decltype(e)>;
        if constexpr (std::is_same_v<E, core::AxisSample>) {
          switch (field) {
            case Field::kXmm:
              return e.position_mm[0];
            case Field::kYmm:
              return e.position_mm[1];
            case Field::kZmm:
              return e.position_mm[2];
            case Field::kAdeg:
              return e.position_mm[3];
            case Field::kBdeg:
              return e.position_mm[4];
            case Field::kCdeg:
              return e.position_mm[5];
            case Field::kProgramPathMm:
              return e.program_path_mm;
            case Field::kTool:
              return e.tool;
            case Field::kNormalX:
              return e.normal[0];
            case Field::kNormalY:
              return e.normal[1];
            case Field::kNormalZ:
              return e.normal[2];
            case Field::kCutting:
              return e.cutting ? 1.0 : 0.0;
            default:
              return std::nullopt;
          }
        } else if constexpr (std::is_same_v<E, core::ToolMeasurement>) {
          switch (field) {
            case Field::kTool:
              return e.tool;
            case Field::kBroken:
              return e.broken ? 1.0 : 0.0;
            case Field::kWearUm:
              return e.wear_um[0];
            default:
              return std::nullopt;
          }
        } else if constexpr (std::is_same_v<E, core::ProbeMeasurement>) {
          switch (field) {
            case Field::kPart:
              return e.part;
            case Field::kCheckpoint:
              return e.checkpoint;
            case Field::kRawDeviationUm:
              return e.raw_deviation_um;
            case Field::kWallAngleDeg:
              return e.wall_angle_deg;
            case Field::kBallRadiusMm:
              return e.ball_radius_mm;
            case Field::kXmm:
              return e.position_mm[0];
            case Field::kYmm:
              return e.position_mm[1];
            case Field::kZmm:
              return e.position_mm[2];
            default:
              return std::nullopt;
          }
        } else if constexpr (std::is_same_v<E, core::CalibrationTouch>) {
          switch (field) {
            case Field::kProbe:
              return static_cast<double>(e.probe);
            case Field::kAxis:
              return e.axis;
            case Field::kDirection:
              return e.direction;
            case Field::kVariant:
              return e.variant;
            case Field::kTriggerPositionMm:
              return e.trigger_position_mm;
            default:
              return std::nullopt;
          }
        } else if constexpr (std::is_same_v<E, core::ToolChange>) {
          switch (field) {
            case Field::kTool:
              return e.tool;
            case Field::kSister:
              return e.sister ? 1.0 : 0.0;
            default:
              return std::nullopt;
          }
        } else if constexpr (std::is_same_v<E, core::ProgramEvent>) {
          switch (field) {
            case Field::kProgramKind:
              return static_cast<double>(e.kind);
            case Field::kPart:
              return e.part;
            default:
              return std::nullopt;
          }
        } else if constexpr (std::is_same_v<E, core::TemperatureSample>) {
          switch (field) {
            case Field::kSensor:
              return e.sensor;
            case Field::kTemperatureC:
              return e.temperature_c;
            default:
              return std::nullopt;
          }
        } else {
          return std::nullopt;  // events no CAN frame carries (e.g. operator commands)
        }
      },
      event);
}

}  // namespace nccomp::drivers::can
