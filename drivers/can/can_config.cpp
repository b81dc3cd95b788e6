#include "drivers/can/can_config.hpp"

#include <toml++/toml.h>
#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "formats/toml/guard.hpp"
#include "formats/toml/key_positions.hpp"
#include "formats/toml/table_reader.hpp"

namespace nccomp::drivers::can {
namespace {

using formats::Diagnostics;
using formats::TableReader;

constexpr std::int64_t kMaxId = kMaxExtendedId;

SignalLayout read_layout(TableReader& r) {
  SignalLayout l;
  l.start_bit = static_cast<std::uint16_t>(r.integer("start_bit", std::nullopt, 0, 511));
  l.length_bits = static_cast<std::uint8_t>(r.integer("length_bits", std::nullopt, 1, 64));
  l.type = r.pick("type", ValueType::kUnsigned,
                  {{"unsigned", ValueType::kUnsigned},
                   {"signed", ValueType::kSigned},
                   {"float", ValueType::kFloat}});
  l.byte_order =
      r.pick("byte_order", ByteOrder::kLittleEndian,
             {{"little_endian", ByteOrder::kLittleEndian}, {"big_endian", ByteOrder::kBigEndian}});
  constexpr double kBig = 1e15;
  l.scale = r.number("scale", 1.0, -kBig, kBig);
  if (std::fabs(l.scale) < 1e-300) {
    r.error("scale", "must not be 0");
    l.scale = 1.0;
  }
  l.offset = r.number("offset", 0.0, -kBig, kBig);
  return l;
}

std::vector<std::string> event_names() {
  std::vector<std::string> names;
  for (std::size_t i = 0; i < kEventKinds; ++i) {
    names.emplace_back(event_kind_name(static_cast<EventKind>(i)));
  }
  return names;
}

/// One [[can.rx]] frame and its signals.
RxFrame read_rx_frame(const toml::table& ft, const std::string& fp, Diagnostics& diag) {
  RxFrame f;
  {
    TableReader r(ft, fp, diag);
    f.origin = formats::where_of(&ft, fp);
    f.extended = r.boolean("extended", false);
    f.id = static_cast<std::uint32_t>(r.integer("id", std::nullopt, 0, kMaxId));
    f.length_bytes = static_cast<std::uint8_t>(r.integer("length_bytes", 8, 0, 64));
    f.event = event_kind_from_name(r.choice("event", std::nullopt, event_names()))
                  .value_or(EventKind::kAxisSample);
    f.emit = r.boolean("emit", true);
    if (const toml::array* sigs = r.table_array("signal")) {
      for (std::size_t j = 0; j < sigs->size(); ++j) {
        const toml::table& st = *sigs->get(j)->as_table();
        const std::string sp = fp + ".signal[" + std::to_string(j) + "]";
        TableReader sr(st, sp, diag);
        RxSignal s;
        s.origin = formats::where_of(&st, sp);
        s.name = sr.string("name", std::nullopt);
        s.layout = read_layout(sr);
        s.min = sr.number("min", -1e300, -1e300, 1e300);
        s.max = sr.number("max", 1e300, -1e300, 1e300);
        f.signals.push_back(std::move(s));
      }
    }
  }
  return f;
}

/// One [[can.offset]] register.
TxRegister read_offset(const toml::table& ot, const std::string& op, Diagnostics& diag) {
  TxRegister reg;
  {
    TableReader r(ot, op, diag);
    reg.origin = formats::where_of(&ot, op);
    reg.register_index = static_cast<std::uint16_t>(
        r.integer("register", std::nullopt, 0, std::numeric_limits<std::uint16_t>::max()));
    reg.extended = r.boolean("extended", false);
    reg.id = static_cast<std::uint32_t>(r.integer("id", std::nullopt, 0, kMaxId));
    reg.length_bytes = static_cast<std::uint8_t>(r.integer("length_bytes", 8, 0, 64));
    if (const toml::table* vt = r.table("value")) {
      TableReader vr(*vt, op + ".value", diag);
      reg.value = read_layout(vr);
    } else if (ot.get("value") == nullptr) {
      r.error("value", "missing required key: the value signal's layout ([can.offset.value])");
    }
    if (r.value("ack_id") != nullptr) {
      reg.ack = TxAck{static_cast<std::uint32_t>(r.integer("ack_id", 0, 0, kMaxId)), reg.extended};
    }
  }
  return reg;
}

/// The tables of an array, each read by `read`; only those read without an error are kept: the
/// map's checks would judge the defaults that stand in for refused values.
template <typename T, typename Read>
void read_entries(const toml::array* tables, const std::string& path, Diagnostics& diag,
                  std::vector<T>& out, Read read) {
  if (tables == nullptr) {
    return;
  }
  for (std::size_t i = 0; i < tables->size(); ++i) {
    const std::size_t errors_before = diag.items().size();
    T entry = read(*tables->get(i)->as_table(), path + "[" + std::to_string(i) + "]", diag);
    if (diag.items().size() == errors_before) {
      out.push_back(std::move(entry));
    }
  }
}

}  // namespace

std::optional<CanConfig> read_can_table(const toml::table& can, std::string_view file,
                                        formats::Diagnostics& out) {
  Diagnostics diag;
  CanConfig c;
  c.mapping.file =
      can.source().path && !can.source().path->empty() ? *can.source().path : std::string(file);
  {
    TableReader r(can, "can", diag);
    c.interface = r.string("interface", std::nullopt);
    if (can.get("interface") != nullptr && can.get("interface")->is_string() &&
        (c.interface.empty() || c.interface.size() >= 16)) {
      r.error("interface", "must be 1..15 characters (IFNAMSIZ)");
    }
    c.mapping.fd = r.boolean("fd", false);
    c.restart = r.pick("restart", RestartMode::kKernel,
                       {{"kernel", RestartMode::kKernel}, {"daemon", RestartMode::kDaemon}});
    c.restart_delay_s = r.number("restart_delay_s", 0.1, 0.001, 60.0);
    c.ack_timeout_s = r.number("ack_timeout_s", 0.05, 0.0001, 10.0);
    c.ack_retries = static_cast<std::uint32_t>(r.integer("ack_retries", 3, 0, 100));
    c.enobufs_backoff_s = r.number("enobufs_backoff_s", 0.0005, 0.00001, 1.0);
    c.link_check_s = r.number("link_check_s", 0.05, 0.001, 10.0);
    c.reconnect_max_s = r.number("reconnect_max_s", 5.0, 0.001, 600.0);
    // Shorter than the cap, a link that fails just after each such stretch would be recovered
    // more often than reconnect_max_s allows.
    c.reconnect_reset_after_s =
        r.number("reconnect_reset_after_s", std::max(10.0, c.reconnect_max_s), 0.001, 86400.0);
    if (c.reconnect_reset_after_s < c.reconnect_max_s) {
      r.error("reconnect_reset_after_s", "smaller than reconnect_max_s");
    }
    c.alarm_after_s = r.number("alarm_after_s", 1.0, 0.0, 3600.0);
    c.degraded_alarm_after_s = r.number("degraded_alarm_after_s", 5.0, 0.01, 3600.0);
    c.rx_ring_events =
        static_cast<std::uint32_t>(r.power_of_two("rx_ring_events", 4096, 2, 1 << 20));
    c.tx_ring_writes =
        static_cast<std::uint32_t>(r.power_of_two("tx_ring_writes", 256, 2, 1 << 20));
    c.socket_rcvbuf_bytes =
        static_cast<std::uint32_t>(r.integer("socket_rcvbuf_bytes", 0, 0, 1 << 28));
    read_entries(r.table_array("rx"), "can.rx", diag, c.mapping.rx, read_rx_frame);
    read_entries(r.table_array("offset"), "can.offset", diag, c.mapping.offsets, read_offset);
  }
  // The map's checks see the entries read without error, so each of their reports is a real one.
  formats::KeyPositions positions;
  formats::record_positions(can, "can", positions);
  (void)validate_mapping(c.mapping, diag, &positions);
  out.append(diag, file);
  if (!diag.ok()) {
    return std::nullopt;
  }
  return c;
}

CanConfig parse_can_table(const toml::table& can, const std::string& file_name) {
  Diagnostics diag;
  auto c = read_can_table(can, file_name, diag);
  if (!c) {
    throw formats::DiagnosticsError(std::move(diag), file_name);
  }
  return std::move(*c);
}

namespace {

/// The [can] table of a parsed document.
CanConfig parse_root(const toml::table& root, const std::string& file) {
  const toml::node* can = root.get("can");
  if (can == nullptr || !can->is_table()) {
    Diagnostics diag;
    diag.error(can != nullptr ? can : &root, "can", "missing [can] table");
    throw formats::DiagnosticsError(std::move(diag), file);
  }
  return parse_can_table(*can->as_table(), file);
}

}  // namespace

CanConfig parse_can_config(std::string_view toml_text, const std::string& file) {
  toml::table root;
  try {
    root = formats::parse_toml(toml_text, file);
  } catch (const toml::parse_error& e) {
    throw formats::DiagnosticsError(e, file);
  }
  return parse_root(root, file);
}

CanConfig load_can_config(const std::string& path) {
  toml::table root;
  try {
    root = formats::parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    throw formats::DiagnosticsError(e, path);
  }
  return parse_root(root, path);
}

}  // namespace nccomp::drivers::can
