#include "drivers/modbus/config.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <sstream>
#include <string>

#include <toml++/toml.h>

#include "formats/toml/guard.hpp"
#include "formats/toml/table_reader.hpp"

namespace nccomp::drivers::modbus {
namespace {

constexpr std::array<std::string_view, kGroupCount> kGroupKeys = {
    "axis",        "tool_measurement", "probe_measurement", "calibration_touch",
    "tool_change", "program_event"};

constexpr std::array<std::array<std::string_view, kMaxFields>, kGroupCount> kFieldKeys = {{
    {"x_mm", "y_mm", "z_mm", "a_deg", "b_deg", "c_deg", "program_path_mm", "tool", "normal_x",
     "normal_y", "normal_z", "cutting"},
    {"sequence", "tool", "wear_um", "broken"},
    {"sequence", "part", "checkpoint", "raw_deviation_um", "wall_angle_deg", "ball_radius_mm",
     "x_mm", "y_mm", "z_mm"},
    {"sequence", "probe", "axis", "direction", "variant", "trigger_position_mm"},
    {"sequence", "tool", "sister"},
    {"sequence", "kind", "part"},
}};
constexpr std::array<std::size_t, kGroupCount> kFieldCounts = {
    axis_field::kCount,  tool_meas_field::kCount,   probe_field::kCount,
    touch_field::kCount, tool_change_field::kCount, program_field::kCount};

/// Fields an event group cannot do without (besides the sequence counter).
bool required(Group g, std::size_t f) {
  switch (g) {
    case Group::kAxis:
      return f == axis_field::kX;
    case Group::kToolMeasurement:
      return f == tool_meas_field::kSeq || f == tool_meas_field::kTool ||
             f == tool_meas_field::kWear;
    case Group::kProbeMeasurement:
      return f == probe_field::kSeq || f == probe_field::kCheckpoint ||
             f == probe_field::kDeviation;
    case Group::kCalibrationTouch:
      return f == touch_field::kSeq || f == touch_field::kAxis || f == touch_field::kDirection ||
             f == touch_field::kPosition;
    case Group::kToolChange:
      return f == tool_change_field::kSeq || f == tool_change_field::kTool;
    case Group::kProgramEvent:
      return f == program_field::kSeq || f == program_field::kKind;
  }
  return false;
}

constexpr std::uint16_t kMaxReadRegisters = 125;  // Modbus spec, function 3/4
constexpr std::uint16_t kMaxReadBits = 2000;      // function 1/2

std::string table_name(Table t) {
  switch (t) {
    case Table::kCoil:
      return "coil";
    case Table::kDiscreteInput:
      return "discrete_input";
    case Table::kHolding:
      return "holding";
    case Table::kInput:
      return "input";
  }
  return "?";
}

using formats::Diagnostics;
using formats::TableReader;

template <typename E, std::size_t N>
std::vector<std::pair<std::string, E>> names_of(
    const std::array<std::pair<std::string_view, E>, N>& options) {
  std::vector<std::pair<std::string, E>> v;
  for (const auto& [name, e] : options) {
    v.emplace_back(std::string(name), e);
  }
  return v;
}

std::string join(const std::string& path, std::string_view key) {
  return path.empty() ? std::string(key) : path + "." + std::string(key);
}

constexpr std::array<std::pair<std::string_view, Table>, 4> kTables = {{
    {"coil", Table::kCoil},
    {"discrete_input", Table::kDiscreteInput},
    {"holding", Table::kHolding},
    {"input", Table::kInput},
}};
constexpr std::array<std::pair<std::string_view, ValueType>, 6> kTypes = {{
    {"bool", ValueType::kBool},
    {"int16", ValueType::kInt16},
    {"uint16", ValueType::kUint16},
    {"int32", ValueType::kInt32},
    {"uint32", ValueType::kUint32},
    {"float32", ValueType::kFloat32},
}};
constexpr std::array<std::pair<std::string_view, WordOrder>, 2> kWordOrders = {{
    {"high_first", WordOrder::kHighFirst},
    {"low_first", WordOrder::kLowFirst},
}};
constexpr std::array<std::pair<std::string_view, ByteOrder>, 2> kByteOrders = {{
    {"big", ByteOrder::kBigEndian},
    {"swapped", ByteOrder::kSwapped},
}};

/// Encoding keys shared by signals and offsets (of the table `r` reads).
Encoding read_encoding(TableReader& r, Table table) {
  Encoding e;
  const ValueType dflt = is_bit_table(table) ? ValueType::kBool : ValueType::kInt16;
  e.type = r.pick("type", dflt, names_of(kTypes));
  if (is_bit_table(table) && e.type != ValueType::kBool) {
    r.error("type", "a " + table_name(table) + " is one bit: type must be bool");
  }
  if (!is_bit_table(table) && e.type == ValueType::kBool) {
    r.error("type",
            "bool is for coil / discrete_input; use uint16 (non-zero = true) for registers");
  }
  e.word_order = r.pick("word_order", WordOrder::kHighFirst, names_of(kWordOrders));
  e.byte_order = r.pick("byte_order", ByteOrder::kBigEndian, names_of(kByteOrders));
  e.scale = r.number("scale", 1.0, -1e12, 1e12);
  if (std::fabs(e.scale) < 1e-12) {
    r.error("scale", "must not be 0");
    e.scale = 1.0;
  }
  e.offset = r.number("offset", 0.0, -1e12, 1e12);
  return e;
}

/// The plausibility range `min` / `max` of a signal (physical units, after scale and offset).
void read_range(TableReader& r, SignalMap& s) {
  const bool has_min = r.node().get("min") != nullptr;
  const bool has_max = r.node().get("max") != nullptr;
  if (!has_min && !has_max) {
    return;
  }
  if (is_bit_table(s.table)) {
    (void)r.value("min");
    (void)r.value("max");
    r.error(has_min ? "min" : "max",
            "a " + table_name(s.table) + " is one bit: min / max do not apply");
    return;
  }
  constexpr double kLimit = 1e300;
  s.min = r.number("min", s.min, -kLimit, kLimit);
  s.max = r.number("max", s.max, -kLimit, kLimit);
  if (s.min > s.max) {
    std::ostringstream m;
    m << "max " << s.max << " is below min " << s.min;
    r.error(has_max ? "max" : "min", m.str());
  }
}

/// The signal keys of table `r` reads. `allow_count`: the signal may be a run of `count`
/// consecutive values (a wear profile).
SignalMap read_signal(TableReader& r, bool allow_count = false) {
  SignalMap s;
  s.mapped = true;
  s.table = r.pick("table", Table::kHolding, names_of(kTables));
  s.address = static_cast<std::uint16_t>(r.integer("address", std::nullopt, 0, 65535));
  s.encoding = read_encoding(r, s.table);
  read_range(r, s);
  if (allow_count) {
    s.count = static_cast<std::uint8_t>(
        r.integer("count", 1, 1, static_cast<std::int64_t>(core::kMaxEdgePoints)));
  }
  if (static_cast<std::uint32_t>(s.address) + span(s) > 65536U) {
    r.error("address", "does not fit below address 65535");
  }
  return s;
}

struct Claim {
  Table table;
  std::uint32_t first;
  std::uint32_t last;
  std::string path;
  int line;
};

}  // namespace

std::string_view group_key(Group g) noexcept { return kGroupKeys[static_cast<std::size_t>(g)]; }
std::size_t field_count(Group g) noexcept { return kFieldCounts[static_cast<std::size_t>(g)]; }
std::string_view field_key(Group g, std::size_t field) noexcept {
  return kFieldKeys[static_cast<std::size_t>(g)][field];
}

double rtu_char_time_s(const ModbusConfig& c) noexcept {
  const double bits = 1.0 + c.data_bits + (c.parity == Parity::kNone ? 0.0 : 1.0) + c.stop_bits;
  return bits / static_cast<double>(c.baud);
}

double rtu_frame_gap_s(const ModbusConfig& c) noexcept {
  return c.baud > 19200 ? 0.00175 : 3.5 * rtu_char_time_s(c);
}

namespace {

/// The [modbus] table of a parsed document.
ModbusConfig parse_root(const toml::table& root, const std::string& file,
                        const ParseOptions& options) {
  const toml::node* mnode = root.get("modbus");
  if (mnode == nullptr || !mnode->is_table()) {
    Diagnostics diag;
    diag.error(mnode != nullptr ? mnode : &root, "modbus", "missing [modbus] table");
    throw formats::DiagnosticsError(std::move(diag), file);
  }
  return parse_modbus_table(*mnode->as_table(), file, options);
}

}  // namespace

ModbusConfig parse_modbus_config(std::string_view toml_text, const std::string& file,
                                 const ParseOptions& options) {
  toml::table root;
  try {
    root = formats::parse_toml(toml_text, file);
  } catch (const toml::parse_error& e) {
    throw formats::DiagnosticsError(e, file);
  }
  return parse_root(root, file, options);
}

ModbusConfig parse_modbus_table(const toml::table& m, const std::string& file,
                                const ParseOptions& options) {
  Diagnostics diag;
  auto c = read_modbus_table(m, file, options, diag);
  if (!c) {
    throw formats::DiagnosticsError(std::move(diag), file);
  }
  return std::move(*c);
}

namespace {

/// The checks of the whole map (overlaps, read blocks, RTU bus time); fills c.blocks and the
/// signals' block positions, and the offset write rate.
void check_map(const toml::table& m, const toml::node* mnode, const std::string& mp,
               const ParseOptions& options, ModbusConfig& c, std::vector<Claim>& claims,
               Diagnostics& diag) {
  const std::string table_file = m.source().path ? *m.source().path : std::string();
  // Overlaps: sort the claimed ranges per table and compare neighbours.
  std::sort(claims.begin(), claims.end(), [](const Claim& a, const Claim& b) {
    return a.table != b.table ? a.table < b.table : a.first < b.first;
  });
  for (std::size_t i = 1; i < claims.size(); ++i) {
    const Claim& a = claims[i - 1];
    const Claim& b = claims[i];
    if (a.table == b.table && b.first <= a.last) {
      std::ostringstream s;
      s << table_name(b.table) << " address " << b.first << " overlaps " << a.path << " (line "
        << a.line << ")";
      diag.error(formats::Where{table_file, b.line, 0, b.path}, s.str());
    }
  }

  // Read blocks: one per (group, table); an event group has exactly one.
  const auto plan = [&](const std::vector<SignalMap*>& signals, const std::string& path) {
    for (std::size_t ti = 0; ti < kTableCount; ++ti) {
      const auto table = static_cast<Table>(ti);
      std::uint32_t lo = 65536;
      std::uint32_t hi = 0;
      for (const SignalMap* s : signals) {
        if (s->table == table) {
          lo = std::min<std::uint32_t>(lo, s->address);
          hi = std::max<std::uint32_t>(hi, s->address + span(*s));
        }
      }
      if (lo > hi) {
        continue;
      }
      const std::uint32_t span = hi - lo;
      const std::uint32_t max = is_bit_table(table) ? kMaxReadBits : kMaxReadRegisters;
      if (span > max) {
        std::ostringstream s;
        s << "its " << table_name(table) << " signals span " << span
          << " addresses, more than one read request carries (" << max
          << "); place them closer together";
        const std::size_t dot = path.rfind('.');
        const toml::node* n = dot == std::string::npos ? nullptr : m.get(path.substr(dot + 1));
        diag.error(n != nullptr ? n : mnode, path, s.str());
      }
      const std::size_t bi = c.blocks.size();
      c.blocks.push_back({table, static_cast<std::uint16_t>(lo), static_cast<std::uint16_t>(span)});
      for (SignalMap* s : signals) {
        if (s->table == table) {
          s->block = bi;
          s->block_offset = static_cast<std::uint16_t>(s->address - lo);
        }
      }
    }
  };
  for (std::size_t gi = 0; gi < kGroupCount; ++gi) {
    if (!c.groups[gi].present) {
      continue;
    }
    std::vector<SignalMap*> sigs;
    for (std::size_t fi = 0; fi < kFieldCounts[gi]; ++fi) {
      if (c.groups[gi].fields[fi].mapped) {
        sigs.push_back(&c.groups[gi].fields[fi]);
      }
    }
    plan(sigs, mp + "." + std::string(kGroupKeys[gi]));
  }
  {
    std::vector<SignalMap*> sigs;
    for (auto& t : c.temperatures) {
      sigs.push_back(&t.value);
    }
    plan(sigs, "modbus.temperature");
  }
  if (c.blocks.empty()) {
    diag.error(mnode, "modbus", "no signal mapped: nothing to poll");
  }

  // Merge close blocks of one table (fewer requests: on RTU each costs two frame gaps). Every
  // group stays inside one request, so event groups remain atomic.
  {
    std::vector<std::size_t> order(c.blocks.size());
    for (std::size_t i = 0; i < order.size(); ++i) {
      order[i] = i;
    }
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
      const ReadBlock& x = c.blocks[a];
      const ReadBlock& y = c.blocks[b];
      return x.table != y.table ? x.table < y.table : x.start < y.start;
    });
    std::vector<ReadBlock> merged;
    std::vector<std::size_t> new_index(c.blocks.size());
    std::vector<std::uint16_t> shift(c.blocks.size());
    for (std::size_t i : order) {
      const ReadBlock& b = c.blocks[i];
      const std::uint32_t bits = is_bit_table(b.table) ? 8U : 1U;
      const std::uint32_t max = is_bit_table(b.table) ? kMaxReadBits : kMaxReadRegisters;
      if (!merged.empty() && merged.back().table == b.table) {
        ReadBlock& m_last = merged.back();
        const std::uint32_t last_end = std::uint32_t{m_last.start} + m_last.count;
        const std::uint32_t end = std::max(last_end, std::uint32_t{b.start} + b.count);
        const std::uint32_t gap = b.start > last_end ? b.start - last_end : 0U;
        if (gap <= c.merge_gap_registers * bits && end - m_last.start <= max) {
          m_last.count = static_cast<std::uint16_t>(end - m_last.start);
          new_index[i] = merged.size() - 1;
          shift[i] = static_cast<std::uint16_t>(b.start - m_last.start);
          continue;
        }
      }
      merged.push_back(b);
      new_index[i] = merged.size() - 1;
      shift[i] = 0;
    }
    const auto remap = [&](SignalMap& s) {
      if (s.mapped) {
        s.block_offset = static_cast<std::uint16_t>(s.block_offset + shift[s.block]);
        s.block = new_index[s.block];
      }
    };
    for (GroupMap& g : c.groups) {
      for (SignalMap& s : g.fields) {
        remap(s);
      }
    }
    for (TemperatureMap& t : c.temperatures) {
      remap(t.value);
    }
    c.blocks = std::move(merged);
  }

  // Bus time (RTU): request 8 bytes; response 5 + data; each frame followed by the 3.5-char gap.
  if (c.transport == Transport::kRtu) {
    const double ch = rtu_char_time_s(c);
    const double gap = rtu_frame_gap_s(c);
    for (const ReadBlock& b : c.blocks) {
      const double data = is_bit_table(b.table) ? std::ceil(b.count / 8.0) : 2.0 * b.count;
      c.poll_bus_time_s += (8.0 + 5.0 + data) * ch + 2.0 * gap;
    }
    for (const OffsetMap& o : c.offsets) {
      const double n = width(o.encoding.type);
      c.write_bus_time_s += (9.0 + 2.0 * n + 8.0) * ch + 2.0 * gap;
    }
    const double load = c.poll_bus_time_s * c.poll_rate_hz;
    if (load > 0.9) {
      std::ostringstream s;
      s << c.poll_rate_hz << " Hz";
      if (c.poll_rate_defaulted) {
        s << " (poll_rate_hz is not set: "
          << (options.rate_source.empty() ? std::string("the default")
                                          : "the loop rate " + std::string(options.rate_source))
          << ")";
      }
      s << " needs " << load * 100.0 << " % of the bus at " << c.baud << " baud ("
        << c.poll_bus_time_s * 1e3 << " ms per poll for " << c.blocks.size()
        << " read requests); at most " << 0.9 / c.poll_bus_time_s << " Hz";
      const toml::node* n = m.get("poll_rate_hz");
      diag.error(n != nullptr ? n : mnode, "modbus.poll_rate_hz", s.str());
    }
    const double budget_hz =
        c.write_bus_time_s > 0.0 ? (0.9 - load) / c.write_bus_time_s : c.poll_rate_hz;
    if (c.offset_write_rate_hz <= 0.0) {
      c.offset_write_rate_hz = std::min(c.poll_rate_hz, budget_hz);
    } else if (c.offset_write_rate_hz > budget_hz + 1e-9) {
      std::ostringstream s;
      s << c.offset_write_rate_hz << " Hz does not fit the bus time the polls leave at " << c.baud
        << " baud; at most " << budget_hz << " Hz";
      diag.error(m.get("offset_write_rate_hz"), "modbus.offset_write_rate_hz", s.str());
    }
  } else if (c.offset_write_rate_hz <= 0.0) {
    c.offset_write_rate_hz = c.poll_rate_hz;
  }
}

/// An event group's or the axes' table: its signals (each a sub-table), the group's rules.
void read_group(const toml::table& m, Group g, const std::string& mp, ModbusConfig& c,
                Diagnostics& diag, std::vector<Claim>& claims) {
  const std::size_t gi = static_cast<std::size_t>(g);
  const std::string gp = mp + "." + std::string(kGroupKeys[gi]);
  const toml::table* gt = m.get_as<toml::table>(kGroupKeys[gi]);
  GroupMap& gm = c.groups[gi];
  gm.present = true;
  const auto& keys = kFieldKeys[gi];
  const auto keys_end = keys.begin() + static_cast<std::ptrdiff_t>(kFieldCounts[gi]);
  for (auto&& [k, v] : *gt) {
    const auto it = std::find(keys.begin(), keys_end, k.str());
    const std::string fp = join(gp, k.str());
    if (it == keys_end) {
      diag.error(&v, fp, "unknown signal");
      continue;
    }
    const auto* st = v.as_table();
    if (st == nullptr) {
      diag.error(&v, fp, "must be a table { table = ..., address = ..., type = ... }");
      continue;
    }
    const auto fi = static_cast<std::size_t>(it - keys.begin());
    TableReader r(*st, fp, diag);
    gm.fields[fi] = read_signal(r, g == Group::kToolMeasurement && fi == tool_meas_field::kWear);
    claims.push_back({gm.fields[fi].table, gm.fields[fi].address,
                      gm.fields[fi].address + span(gm.fields[fi]) - 1U, fp,
                      static_cast<int>(v.source().begin.line)});
  }
  for (std::size_t fi = 0; fi < kFieldCounts[gi]; ++fi) {
    if (required(g, fi) && !gm.fields[fi].mapped) {
      diag.error(gt, join(gp, keys[fi]), "missing required key (this group needs it)");
    }
  }
  if (g == Group::kAxis) {
    // Axes fill AxisSample.position_mm from X on: a gap would leave an axis undefined.
    bool gap = false;
    for (std::size_t a = axis_field::kX; a <= axis_field::kC; ++a) {
      if (!gm.fields[a].mapped) {
        gap = true;
      } else if (gap) {
        diag.error(gt->get(keys[a]), join(gp, keys[a]),
                   "axes must be mapped in order x, y, z, a, b, c without gaps");
      }
    }
    const bool nx = gm.fields[axis_field::kNormalX].mapped;
    if (nx != gm.fields[axis_field::kNormalY].mapped ||
        nx != gm.fields[axis_field::kNormalZ].mapped) {
      diag.error(gt, gp + ".normal_x", "normal_x, normal_y and normal_z go together");
    }
    return;
  }
  const SignalMap& seq = gm.fields[0];
  if (!seq.mapped) {
    return;  // reported above
  }
  const std::string sp = gp + ".sequence";
  if (seq.encoding.type != ValueType::kUint16 && seq.encoding.type != ValueType::kUint32) {
    diag.error(gt->get("sequence"), sp, "a sequence counter must be uint16 or uint32");
  }
  if (is_bit_table(seq.table)) {
    diag.error(gt->get("sequence"), sp, "a sequence counter must be in holding or input");
  }
  if (!std::isinf(seq.min) || !std::isinf(seq.max)) {
    const toml::table* st = gt->get("sequence")->as_table();
    const bool has_min = st != nullptr && st->get("min") != nullptr;
    diag.error(st != nullptr ? st->get(has_min ? "min" : "max") : gt,
               sp + (has_min ? ".min" : ".max"),
               "a sequence counter has no range: it counts events and wraps");
  }
  for (std::size_t fi = 1; fi < kFieldCounts[gi]; ++fi) {
    if (gm.fields[fi].mapped && gm.fields[fi].table != seq.table) {
      diag.error(gt->get(keys[fi]), join(gp, keys[fi]),
                 "must be in the same table as sequence (" + table_name(seq.table) +
                     ") so that the event is read in one request");
    }
  }
}

}  // namespace

std::optional<ModbusConfig> read_modbus_table(const toml::table& m, std::string_view file,
                                              const ParseOptions& options,
                                              formats::Diagnostics& out) {
  Diagnostics diag;
  const toml::node* mnode = &m;
  const std::string mp = "modbus";
  ModbusConfig c;
  std::vector<Claim> claims;
  {
    TableReader r(m, mp, diag);
    static constexpr std::array<std::pair<std::string_view, Transport>, 2> kTransports = {{
        {"tcp", Transport::kTcp},
        {"rtu", Transport::kRtu},
    }};
    if (m.get("transport") == nullptr) {
      r.error("transport", "missing required key (tcp or rtu)");
    }
    c.transport = r.pick("transport", Transport::kTcp, names_of(kTransports));
    c.host = r.string("host", c.host);
    c.port = static_cast<std::uint16_t>(r.integer("port", 502, 1, 65535));
    c.device = r.string("device", "");
    c.baud = static_cast<std::uint32_t>(r.integer("baud", 19200, 300, 4000000));
    static constexpr std::array<std::pair<std::string_view, Parity>, 3> kParities = {{
        {"none", Parity::kNone},
        {"even", Parity::kEven},
        {"odd", Parity::kOdd},
    }};
    c.parity = r.pick("parity", Parity::kEven, names_of(kParities));
    c.data_bits = static_cast<std::uint8_t>(r.integer("data_bits", 8, 7, 8));
    c.stop_bits = static_cast<std::uint8_t>(r.integer("stop_bits", 1, 1, 2));
    c.rs485 = r.boolean("rs485", false);
    if (c.transport == Transport::kRtu && c.device.empty()) {
      r.error("device", "missing required key: RTU needs a serial device path");
    }
    if (c.transport == Transport::kTcp && c.host.empty()) {
      r.error("host", "must not be empty");
    }
    c.unit_id = static_cast<std::uint8_t>(r.integer("unit_id", 1, 0, 247));
    c.response_timeout_s = r.number("response_timeout_s", 0.5, 0.001, 60.0);
    c.byte_timeout_s = r.number("byte_timeout_s", 0.5, 0.0001, 60.0);
    c.poll_rate_defaulted = m.get("poll_rate_hz") == nullptr;
    c.poll_rate_hz = r.number("poll_rate_hz", options.default_poll_rate_hz, 0.01, 10000.0);
    if (options.max_poll_rate_hz > 0.0 && c.poll_rate_hz > options.max_poll_rate_hz + 1e-9) {
      std::ostringstream s;
      s << c.poll_rate_hz << " Hz is faster than the loop ("
        << (options.rate_source.empty() ? "loop rate" : options.rate_source) << " = "
        << options.max_poll_rate_hz
        << " Hz), which takes at most one sample per cycle: the extra polls only load the NC "
           "and the bus; at most "
        << options.max_poll_rate_hz << " Hz (leave poll_rate_hz out to poll at the loop rate)";
      r.error("poll_rate_hz", s.str());
    }
    c.offset_write_rate_hz = r.number("offset_write_rate_hz", 0.0, 0.0, 10000.0);
    c.reconnect_min_s = r.number("reconnect_min_s", 0.1, 0.001, 600.0);
    c.reconnect_max_s = r.number("reconnect_max_s", 5.0, 0.001, 600.0);
    if (c.reconnect_max_s < c.reconnect_min_s) {
      r.error("reconnect_max_s", "smaller than reconnect_min_s");
    }
    // Shorter than the cap, a peer that drops each connection just after that long would get
    // reconnects more often than reconnect_max_s allows.
    c.reconnect_reset_after_s =
        r.number("reconnect_reset_after_s", std::max(10.0, c.reconnect_max_s), 0.001, 86400.0);
    if (c.reconnect_reset_after_s < c.reconnect_max_s) {
      r.error("reconnect_reset_after_s", "smaller than reconnect_max_s");
    }
    c.dead_after_failures =
        static_cast<std::uint32_t>(r.integer("dead_after_failures", 3, 1, 1000));
    c.verify_writes = r.boolean("verify_writes", false);
    c.alarm_after_s = r.number("alarm_after_s", 1.0, 0.0, 3600.0);
    c.degraded_alarm_after_s = r.number("degraded_alarm_after_s", 5.0, 0.01, 3600.0);
    c.rx_capacity = static_cast<std::size_t>(r.power_of_two("rx_capacity", 1024, 2, 1 << 20));
    c.tx_capacity = static_cast<std::size_t>(r.power_of_two("tx_capacity", 256, 2, 1 << 20));
    c.merge_gap_registers = static_cast<std::uint32_t>(r.integer("merge_gap_registers", 0, 0, 125));

    // Real-time policy of the I/O thread (applied by the thread itself, see modbus_bus.hpp).
    c.io_sched_fifo_priority = static_cast<int>(r.integer("io_sched_fifo_priority", 0, 0, 99));
    if (c.io_sched_fifo_priority > 0 && options.loop_sched_fifo_priority >= 0 &&
        c.io_sched_fifo_priority >= options.loop_sched_fifo_priority) {
      const std::string src = options.loop_priority_source.empty()
                                  ? std::string("the loop's priority")
                                  : std::string(options.loop_priority_source);
      std::ostringstream s;
      s << c.io_sched_fifo_priority << " is not below the loop thread's SCHED_FIFO priority ("
        << src << " = " << options.loop_sched_fifo_priority;
      if (options.loop_sched_fifo_priority == 0) {
        s << ": the loop runs at normal scheduling, so any SCHED_FIFO I/O thread would preempt "
             "it); raise the loop's priority above this one, or set 0 here";
      } else {
        s << "): the loop must always preempt the driver's I/O thread; at most "
          << options.loop_sched_fifo_priority - 1 << " (0 = off)";
      }
      r.error("io_sched_fifo_priority", s.str());
    }
    for (const std::int64_t cpu : r.integer_list("io_cpu_affinity", 0, 1023)) {
      if (std::find(c.io_cpu_affinity.begin(), c.io_cpu_affinity.end(), cpu) !=
          c.io_cpu_affinity.end()) {
        r.error("io_cpu_affinity", "CPU " + std::to_string(cpu) + " is listed twice");
        continue;
      }
      c.io_cpu_affinity.push_back(static_cast<int>(cpu));
    }

    // Signal groups.
    for (std::size_t gi = 0; gi < kGroupCount; ++gi) {
      if (r.table(kGroupKeys[gi]) != nullptr) {
        read_group(m, static_cast<Group>(gi), mp, c, diag, claims);
      }
    }

    // Temperatures.
    if (const toml::array* arr = r.table_array("temperature")) {
      for (std::size_t i = 0; i < arr->size(); ++i) {
        const std::string tp = "modbus.temperature[" + std::to_string(i) + "]";
        const toml::table& t = *(*arr)[i].as_table();
        TableReader tr(t, tp, diag);
        TemperatureMap tm;
        tm.sensor = static_cast<std::uint8_t>(tr.integer("sensor", std::nullopt, 0, 255));
        for (const auto& other : c.temperatures) {
          if (other.sensor == tm.sensor && t.get("sensor") != nullptr) {
            tr.error("sensor", "sensor mapped twice");
          }
        }
        tm.value = read_signal(tr);
        claims.push_back({tm.value.table, tm.value.address, tm.value.address + span(tm.value) - 1U,
                          tp, static_cast<int>(t.source().begin.line)});
        c.temperatures.push_back(tm);
      }
    }

    // Offsets.
    if (const toml::array* arr = r.table_array("offset")) {
      for (std::size_t i = 0; i < arr->size(); ++i) {
        const std::string op = "modbus.offset[" + std::to_string(i) + "]";
        const toml::table& t = *(*arr)[i].as_table();
        TableReader tr(t, op, diag);
        OffsetMap om;
        om.register_index =
            static_cast<std::uint16_t>(tr.integer("register_index", std::nullopt, 0, 65535));
        for (const auto& other : c.offsets) {
          if (other.register_index == om.register_index && t.get("register_index") != nullptr) {
            tr.error("register_index", "register_index mapped twice");
          }
        }
        om.address = static_cast<std::uint16_t>(tr.integer("address", std::nullopt, 0, 65535));
        om.encoding = read_encoding(tr, Table::kHolding);
        if (static_cast<std::uint32_t>(om.address) + width(om.encoding.type) > 65536U) {
          tr.error("address", "does not fit below address 65535");
        }
        SignalMap as_signal;
        as_signal.table = Table::kHolding;
        as_signal.address = om.address;
        as_signal.encoding = om.encoding;
        claims.push_back({Table::kHolding, om.address, om.address + span(as_signal) - 1U, op,
                          static_cast<int>(t.source().begin.line)});
        c.offsets.push_back(om);
      }
    }
  }
  // The checks of the whole map need every entry read: after an error they would only repeat it.
  if (diag.ok()) {
    check_map(m, mnode, mp, options, c, claims, diag);
  }
  // Tables built in memory carry no file name: the caller's.
  out.append(diag, file);
  if (!diag.ok()) {
    return std::nullopt;
  }
  return c;
}

ModbusConfig load_modbus_config(const std::string& path) {
  toml::table root;
  try {
    root = formats::parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    throw formats::DiagnosticsError(e, path);
  }
  return parse_root(root, path, {});
}

}  // namespace nccomp::drivers::modbus
