#include "drivers/can/can_config.hpp"

#include <toml++/toml.h>
#include <algorithm>
#include <cmath>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <sstream>

#include "formats/toml/guard.hpp"

namespace nccomp::drivers::can {
namespace {

class Reader {
 public:
  explicit Reader(const std::string& file) : file_(file) {}

  [[noreturn]] void fail(const toml::node& at, const std::string& path,
                         const std::string& msg) const {
    // Included files: the node knows which file it came from.
    const auto& src = at.source();
    throw MappingError(src.path && !src.path->empty() ? *src.path : file_,
                       static_cast<int>(src.begin.line), static_cast<int>(src.begin.column), path,
                       msg);
  }

  // Unknown keys are errors: a typo must not silently fall back to a default.
  void only_keys(const toml::table& t, const std::string& path,
                 std::initializer_list<std::string_view> keys) const {
    for (const auto& [k, v] : t) {
      bool known = false;
      for (auto key : keys) {
        known = known || key == k.str();
      }
      if (!known) {
        std::string list;
        for (auto key : keys) {
          list += (list.empty() ? "" : ", ") + std::string(key);
        }
        fail(v, path + "." + std::string(k.str()), "unknown key (known: " + list + ")");
      }
    }
  }

  const toml::node* get(const toml::table& t, std::string_view key) const { return t.get(key); }

  bool get_bool(const toml::table& t, const std::string& path, std::string_view key,
                bool dflt) const {
    const auto* n = get(t, key);
    if (n == nullptr) {
      return dflt;
    }
    if (!n->is_boolean()) {
      fail(*n, path + "." + std::string(key), "must be true or false");
    }
    return n->as_boolean()->get();
  }

  double get_double(const toml::table& t, const std::string& path, std::string_view key,
                    std::optional<double> dflt, double lo, double hi) const {
    const auto* n = get(t, key);
    const std::string p = path + "." + std::string(key);
    if (n == nullptr) {
      if (!dflt) {
        fail(t, p, "required key missing");
      }
      return *dflt;
    }
    double v = 0.0;
    if (n->is_floating_point()) {
      v = n->as_floating_point()->get();
    } else if (n->is_integer()) {
      v = static_cast<double>(n->as_integer()->get());
    } else {
      fail(*n, p, "must be a number");
    }
    if (!std::isfinite(v) || v < lo || v > hi) {
      std::ostringstream s;
      s << "must be in [" << lo << ", " << hi << "], got " << v;
      fail(*n, p, s.str());
    }
    return v;
  }

  std::int64_t get_int(const toml::table& t, const std::string& path, std::string_view key,
                       std::optional<std::int64_t> dflt, std::int64_t lo, std::int64_t hi) const {
    const auto* n = get(t, key);
    const std::string p = path + "." + std::string(key);
    if (n == nullptr) {
      if (!dflt) {
        fail(t, p, "required key missing");
      }
      return *dflt;
    }
    if (!n->is_integer()) {
      fail(*n, p, "must be an integer");
    }
    const std::int64_t v = n->as_integer()->get();
    if (v < lo || v > hi) {
      fail(*n, p,
           "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " +
               std::to_string(v));
    }
    return v;
  }

  std::string get_string(const toml::table& t, const std::string& path, std::string_view key,
                         std::optional<std::string> dflt) const {
    const auto* n = get(t, key);
    const std::string p = path + "." + std::string(key);
    if (n == nullptr) {
      if (!dflt) {
        fail(t, p, "required key missing");
      }
      return *dflt;
    }
    if (!n->is_string()) {
      fail(*n, p, "must be a string");
    }
    return n->as_string()->get();
  }

  const toml::array* get_array_of_tables(const toml::table& t, const std::string& path,
                                         std::string_view key) const {
    const auto* n = get(t, key);
    if (n == nullptr) {
      return nullptr;
    }
    const auto* a = n->as_array();
    if (a == nullptr || !a->is_array_of_tables()) {
      fail(*n, path + "." + std::string(key), "must be an array of tables ([[...]])");
    }
    return a;
  }

  SignalLayout layout(const toml::table& t, const std::string& path) const {
    SignalLayout l;
    l.start_bit = static_cast<std::uint16_t>(get_int(t, path, "start_bit", std::nullopt, 0, 511));
    l.length_bits = static_cast<std::uint8_t>(get_int(t, path, "length_bits", std::nullopt, 1, 64));
    const std::string type = get_string(t, path, "type", "unsigned");
    if (type == "unsigned") {
      l.type = ValueType::kUnsigned;
    } else if (type == "signed") {
      l.type = ValueType::kSigned;
    } else if (type == "float") {
      l.type = ValueType::kFloat;
    } else {
      fail(*t.get("type"), path + ".type",
           "must be \"unsigned\", \"signed\" or \"float\", got \"" + type + "\"");
    }
    const std::string order = get_string(t, path, "byte_order", "little_endian");
    if (order == "little_endian") {
      l.byte_order = ByteOrder::kLittleEndian;
    } else if (order == "big_endian") {
      l.byte_order = ByteOrder::kBigEndian;
    } else {
      fail(*t.get("byte_order"), path + ".byte_order",
           "must be \"little_endian\" or \"big_endian\", got \"" + order + "\"");
    }
    constexpr double kBig = 1e15;
    l.scale = get_double(t, path, "scale", 1.0, -kBig, kBig);
    l.offset = get_double(t, path, "offset", 0.0, -kBig, kBig);
    if (std::fabs(l.scale) < 1e-300) {
      fail(*t.get("scale"), path + ".scale", "must not be 0");
    }
    return l;
  }

  Origin origin(const toml::node& n, const std::string& path) const {
    return Origin{path, static_cast<std::uint32_t>(n.source().begin.line)};
  }

 private:
  const std::string& file_;
};

constexpr std::int64_t kMaxId = kMaxExtendedId;

}  // namespace

CanConfig parse_can_config(std::string_view toml_text, const std::string& file) {
  toml::table root;
  try {
    root = formats::parse_toml(toml_text, file);
  } catch (const toml::parse_error& e) {
    throw MappingError(file, static_cast<int>(e.source().begin.line),
                       static_cast<int>(e.source().begin.column), "", std::string(e.description()));
  }
  const auto* can_node = root.get("can");
  if (can_node == nullptr || !can_node->is_table()) {
    throw MappingError(file, 1, 0, "can", "missing [can] table");
  }
  return parse_can_table(*can_node->as_table(), file);
}

CanConfig parse_can_table(const toml::table& can, const std::string& file_name) {
  const std::string file =
      can.source().path && !can.source().path->empty() ? *can.source().path : file_name;
  const Reader r(file);
  CanConfig c;
  c.mapping.file = file;
  const std::string p = "can";
  r.only_keys(can, p,
              {"interface", "fd", "restart", "restart_delay_s", "ack_timeout_s", "ack_retries",
               "enobufs_backoff_s", "link_check_s", "reconnect_max_s", "reconnect_reset_after_s",
               "alarm_after_s", "degraded_alarm_after_s", "rx_ring_events", "tx_ring_writes",
               "socket_rcvbuf_bytes", "rx", "offset"});
  c.interface = r.get_string(can, p, "interface", std::nullopt);
  if (c.interface.empty() || c.interface.size() >= 16) {
    r.fail(*can.get("interface"), p + ".interface", "must be 1..15 characters (IFNAMSIZ)");
  }
  c.mapping.fd = r.get_bool(can, p, "fd", false);
  const std::string restart = r.get_string(can, p, "restart", "kernel");
  if (restart == "kernel") {
    c.restart = RestartMode::kKernel;
  } else if (restart == "daemon") {
    c.restart = RestartMode::kDaemon;
  } else {
    r.fail(*can.get("restart"), p + ".restart", "must be \"kernel\" or \"daemon\"");
  }
  c.restart_delay_s = r.get_double(can, p, "restart_delay_s", 0.1, 0.001, 60.0);
  c.ack_timeout_s = r.get_double(can, p, "ack_timeout_s", 0.05, 0.0001, 10.0);
  c.ack_retries = static_cast<std::uint32_t>(r.get_int(can, p, "ack_retries", 3, 0, 100));
  c.enobufs_backoff_s = r.get_double(can, p, "enobufs_backoff_s", 0.0005, 0.00001, 1.0);
  c.link_check_s = r.get_double(can, p, "link_check_s", 0.05, 0.001, 10.0);
  c.reconnect_max_s = r.get_double(can, p, "reconnect_max_s", 5.0, 0.001, 600.0);
  // Shorter than the cap, a link that fails just after each such stretch would be recovered more
  // often than reconnect_max_s allows.
  c.reconnect_reset_after_s = r.get_double(can, p, "reconnect_reset_after_s",
                                           std::max(10.0, c.reconnect_max_s), 0.001, 86400.0);
  if (c.reconnect_reset_after_s < c.reconnect_max_s) {
    r.fail(*can.get("reconnect_reset_after_s"), p + ".reconnect_reset_after_s",
           "smaller than reconnect_max_s");
  }
  c.alarm_after_s = r.get_double(can, p, "alarm_after_s", 1.0, 0.0, 3600.0);
  c.degraded_alarm_after_s = r.get_double(can, p, "degraded_alarm_after_s", 5.0, 0.01, 3600.0);
  const auto pow2 = [&](std::string_view key, std::int64_t dflt) {
    const std::int64_t v = r.get_int(can, p, key, dflt, 2, 1 << 20);
    if ((v & (v - 1)) != 0) {
      r.fail(*can.get(key), p + "." + std::string(key), "must be a power of two");
    }
    return static_cast<std::uint32_t>(v);
  };
  c.rx_ring_events = pow2("rx_ring_events", 4096);
  c.tx_ring_writes = pow2("tx_ring_writes", 256);
  c.socket_rcvbuf_bytes =
      static_cast<std::uint32_t>(r.get_int(can, p, "socket_rcvbuf_bytes", 0, 0, 1 << 28));

  if (const auto* rx = r.get_array_of_tables(can, p, "rx")) {
    for (std::size_t i = 0; i < rx->size(); ++i) {
      const toml::table& ft = *rx->get(i)->as_table();
      const std::string fp = p + ".rx[" + std::to_string(i) + "]";
      r.only_keys(ft, fp, {"id", "extended", "length_bytes", "event", "emit", "signal"});
      RxFrame f;
      f.origin = r.origin(ft, fp);
      f.extended = r.get_bool(ft, fp, "extended", false);
      f.id = static_cast<std::uint32_t>(r.get_int(ft, fp, "id", std::nullopt, 0, kMaxId));
      f.length_bytes = static_cast<std::uint8_t>(r.get_int(ft, fp, "length_bytes", 8, 0, 64));
      const std::string ev = r.get_string(ft, fp, "event", std::nullopt);
      const auto kind = event_kind_from_name(ev);
      if (!kind) {
        r.fail(*ft.get("event"), fp + ".event",
               "unknown event \"" + ev +
                   "\" (known: axis_sample, tool_measurement, probe_measurement, "
                   "calibration_touch, tool_change, program_event, temperature)");
      }
      f.event = *kind;
      f.emit = r.get_bool(ft, fp, "emit", true);
      const auto* sigs = r.get_array_of_tables(ft, fp, "signal");
      if (sigs == nullptr) {
        r.fail(ft, fp + ".signal", "a received frame needs at least one [[can.rx.signal]]");
      }
      for (std::size_t j = 0; j < sigs->size(); ++j) {
        const toml::table& st = *sigs->get(j)->as_table();
        const std::string sp = fp + ".signal[" + std::to_string(j) + "]";
        r.only_keys(st, sp,
                    {"name", "start_bit", "length_bits", "type", "byte_order", "scale", "offset",
                     "min", "max"});
        RxSignal s;
        s.origin = r.origin(st, sp);
        s.name = r.get_string(st, sp, "name", std::nullopt);
        s.layout = r.layout(st, sp);
        s.min = r.get_double(st, sp, "min", -1e300, -1e300, 1e300);
        s.max = r.get_double(st, sp, "max", 1e300, -1e300, 1e300);
        f.signals.push_back(std::move(s));
      }
      c.mapping.rx.push_back(std::move(f));
    }
  }
  if (const auto* offs = r.get_array_of_tables(can, p, "offset")) {
    for (std::size_t i = 0; i < offs->size(); ++i) {
      const toml::table& ot = *offs->get(i)->as_table();
      const std::string op = p + ".offset[" + std::to_string(i) + "]";
      r.only_keys(ot, op, {"register", "id", "extended", "length_bytes", "value", "ack_id"});
      TxRegister reg;
      reg.origin = r.origin(ot, op);
      reg.register_index = static_cast<std::uint16_t>(r.get_int(
          ot, op, "register", std::nullopt, 0, std::numeric_limits<std::uint16_t>::max()));
      reg.extended = r.get_bool(ot, op, "extended", false);
      reg.id = static_cast<std::uint32_t>(r.get_int(ot, op, "id", std::nullopt, 0, kMaxId));
      reg.length_bytes = static_cast<std::uint8_t>(r.get_int(ot, op, "length_bytes", 8, 0, 64));
      const auto* vn = ot.get("value");
      if (vn == nullptr || !vn->is_table()) {
        r.fail(vn != nullptr ? *vn : ot, op + ".value",
               "required table missing: the value signal's layout ([can.offset.value])");
      }
      const toml::table& vt = *vn->as_table();
      r.only_keys(vt, op + ".value",
                  {"start_bit", "length_bits", "type", "byte_order", "scale", "offset"});
      reg.value = r.layout(vt, op + ".value");
      if (ot.get("ack_id") != nullptr) {
        reg.ack = TxAck{static_cast<std::uint32_t>(r.get_int(ot, op, "ack_id", 0, 0, kMaxId)),
                        reg.extended};
      }
      c.mapping.offsets.push_back(std::move(reg));
    }
  }
  validate_mapping(c.mapping);
  return c;
}

CanConfig load_can_config(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw MappingError(path + ": cannot read the file");
  }
  std::ostringstream s;
  s << in.rdbuf();
  return parse_can_config(s.str(), path);
}

}  // namespace nccomp::drivers::can
