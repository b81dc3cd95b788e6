#include "daemon/config/builtin_sections.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "daemon/measurement_log_probe.hpp"
#include "drivers/loopback/loopback_bus.hpp"

namespace nccomp::daemon::config {

using formats::Diagnostics;
using formats::TableReader;
using formats::Where;
using formats::where_of;

namespace {

const toml::table* as_table(const toml::node& node, std::string_view name, Diagnostics& diag) {
  const auto* t = node.as_table();
  if (t == nullptr) {
    diag.error(&node, std::string(name), "must be a table ([" + std::string(name) + "])");
  }
  return t;
}

// The tables of an array of tables `[[name]]`, each with its key path ("name[i]"); none, and an
// error, when the node is not one or has more than `max` entries.
struct TableEntry {
  const toml::table* table;
  std::string path;
};
std::vector<TableEntry> array_of_tables(const toml::node& node, const std::string& name,
                                        Diagnostics& diag,
                                        std::size_t max = std::numeric_limits<std::size_t>::max()) {
  const auto* arr = node.as_array();
  if (arr == nullptr || !arr->is_array_of_tables()) {
    diag.error(&node, name, "must be an array of tables ([[" + name + "]])");
    return {};
  }
  if (arr->size() > max) {
    diag.error(&node, name, "at most " + std::to_string(max) + " entries");
    return {};
  }
  std::vector<TableEntry> out;
  for (std::size_t i = 0; i < arr->size(); ++i) {
    out.push_back({arr->get(i)->as_table(), name + "[" + std::to_string(i) + "]"});
  }
  return out;
}

// What useradd / systemd-sysusers accept as a group name.
bool valid_group_name(const std::string& n) {
  const auto alpha = [](char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z'); };
  const auto digit = [](char c) { return c >= '0' && c <= '9'; };
  if (n.empty() || n.size() > 32 || !(alpha(n[0]) || n[0] == '_')) return false;
  for (std::size_t i = 1; i < n.size(); ++i) {
    const char c = n[i];
    const bool last_dollar = c == '$' && i + 1 == n.size();
    if (!(alpha(c) || digit(c) || c == '_' || c == '-' || c == '.' || last_dollar)) return false;
  }
  return true;
}

template <typename T>
const T& typed(const Config& c, std::string_view name) {
  static const T fallback{};
  const T* p = c.find<T>(name);
  return p != nullptr ? *p : fallback;
}

class DaemonParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "daemon"; }
  std::unique_ptr<Section> absent() const override { return std::make_unique<DaemonSection>(); }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<DaemonSection>();
    const auto* t = as_table(node, name(), diag);
    if (t == nullptr) {
      return s;
    }
    TableReader r(*t, "daemon", diag);
    s->rate_hz = r.number("rate_hz", 1000.0, 1.0, 10000.0);
    s->dry_run = r.boolean("dry_run", false);
    s->max_events_per_cycle =
        static_cast<std::size_t>(r.integer("max_events_per_cycle", 256, 1, 65536));
    s->overrun_policy =
        r.choice("overrun_policy", "skip_missed", {"skip_missed", "restart"}) == "restart"
            ? OverrunPolicy::kRestart
            : OverrunPolicy::kSkipMissed;
    if (const auto* rt = r.table("realtime")) {
      TableReader q(*rt, "daemon.realtime", diag);
      s->sched_fifo_priority = static_cast<int>(q.integer("sched_fifo_priority", 0, 0, 99));
      for (auto c : q.integer_list("cpu_affinity", 0, 1023)) {
        s->cpu_affinity.push_back(static_cast<int>(c));
      }
      s->lock_memory = q.boolean("lock_memory", false);
      s->prefault_stack_kib =
          static_cast<std::size_t>(q.integer("prefault_stack_kib", 0, 0, 65536));
    }
    return s;
  }
};

class StateParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "state"; }
  std::unique_ptr<Section> absent() const override { return std::make_unique<StateSection>(); }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<StateSection>();
    if (const auto* t = as_table(node, name(), diag)) {
      TableReader r(*t, "state", diag);
      s->directory = r.string("directory", "");
      s->min_interval_s = r.number("min_interval_s", 0.5, 0.001, 3600.0);
    }
    return s;
  }
};

class LogParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "log"; }
  std::unique_ptr<Section> absent() const override { return std::make_unique<LogSection>(); }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<LogSection>();
    if (const auto* t = as_table(node, name(), diag)) {
      TableReader r(*t, "log", diag);
      s->level = r.choice("level", "info", {"trace", "debug", "info", "warning", "error"});
      s->target = r.choice("target", "auto", {"auto", "journal", "terminal"});
    }
    return s;
  }
};

class MeasurementLogParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "measurement_log"; }
  std::unique_ptr<Section> absent() const override {
    return std::make_unique<MeasurementLogSection>();
  }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<MeasurementLogSection>();
    if (const auto* t = as_table(node, name(), diag)) {
      TableReader r(*t, "measurement_log", diag);
      s->enabled = r.boolean("enabled", true);
      s->directory = r.string("directory", "");
      s->max_file_bytes = static_cast<std::uint64_t>(
          r.integer("max_file_bytes", 16 * 1024 * 1024, 4096, std::int64_t{1} << 40));
      s->keep_files = static_cast<int>(r.integer("keep_files", 8, 1, 1000));
      s->fsync_interval_s = r.number("fsync_interval_s", 1.0, 0.0, 3600.0);
      s->machine_id = r.string("machine_id", "");
      if (!s->machine_id.empty() && !formats::measurement_log::valid_machine_id(s->machine_id)) {
        diag.error(r.where("machine_id"),
                   "'" + s->machine_id +
                       "' is not a machine id: 1 to 64 letters, digits, '.', '_' or '-', "
                       "starting with a letter or digit (it names MQTT topics and files)");
      }
      if (const toml::array* a = r.table_array("context_columns")) {
        if (a->size() > core::kMaxContextValues) {
          diag.error(r.where("context_columns"), std::to_string(a->size()) +
                                                     " context columns, at most " +
                                                     std::to_string(core::kMaxContextValues));
        }
        const std::string v2 = std::string(formats::measurement_log::kV1Header) + ',' +
                               formats::measurement_log::kV2Columns + ",seq";
        for (std::size_t i = 0; i < a->size(); ++i) {
          const std::string path = "measurement_log.context_columns[" + std::to_string(i) + "]";
          TableReader c(*(*a)[i].as_table(), path, diag);
          formats::measurement_log::ContextColumn col;
          col.name = c.string("name", std::nullopt);
          col.sensor = static_cast<int>(c.integer("sensor", std::nullopt, 0, 255));
          const bool snake = !col.name.empty() && col.name.size() <= 64 &&
                             col.name.front() >= 'a' && col.name.front() <= 'z' &&
                             col.name.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789_") ==
                                 std::string::npos;
          if (!snake) {
            diag.error(c.where("name"), "'" + col.name +
                                            "' is not a column name: snake_case (a-z, 0-9, _), "
                                            "1 to 64 characters, starting with a letter");
          } else if (("," + v2 + ",").find("," + col.name + ",") != std::string::npos) {
            diag.error(c.where("name"), "'" + col.name + "' is a column of the log already");
          }
          for (const formats::measurement_log::ContextColumn& other : s->context_columns) {
            if (other.name == col.name) {
              diag.error(c.where("name"), "'" + col.name + "' named twice");
            }
          }
          s->context_columns.push_back(col);
        }
      }
      if (const toml::table* fp = r.table("face_probe")) {
        TableReader f(*fp, "measurement_log.face_probe", diag);
        s->has_face_probe = true;
        const std::vector<double> xs = f.number_list("points_x_mm", -1e6, 1e6);
        const std::vector<double> ys = f.number_list("points_y_mm", -1e6, 1e6);
        if (xs.size() != ys.size() || xs.empty() || xs.size() > kMaxFaceProbePoints) {
          diag.error(f.where("points_y_mm"),
                     "points_x_mm and points_y_mm must list as many values, 1 to " +
                         std::to_string(kMaxFaceProbePoints) + " (got " +
                         std::to_string(xs.size()) + " and " + std::to_string(ys.size()) + ")");
        } else {
          for (std::size_t i = 0; i < xs.size(); ++i) {
            s->face_probe_points_mm.push_back({xs[i], ys[i]});
          }
        }
        s->face_probe_capture_radius_mm = f.number("capture_radius_mm", 1.0, 1e-3, 100.0);
        s->face_probe_ball_radius_mm = f.number("ball_radius_mm", 0.0, 0.0, 100.0);
        s->face_probe_length_register = f.string("length_register", std::nullopt);
        s->face_probe_radius_register = f.string("radius_register", std::nullopt);
        s->face_probe_length_where = f.where("length_register");
        s->face_probe_radius_where = f.where("radius_register");
      }
    }
    return s;
  }
  void cross_check(const Config& config, Diagnostics& diag) const override {
    const MeasurementLogSection& s = measurement_log_section(config);
    if (!s.has_face_probe) return;
    const auto& regs = registers_section(config).registers;
    const std::pair<const std::string*, const Where*> refs[] = {
        {&s.face_probe_length_register, &s.face_probe_length_where},
        {&s.face_probe_radius_register, &s.face_probe_radius_where}};
    for (const auto& [name, where] : refs) {
      if (name->empty()) continue;  // missing: reported by the parser
      bool found = false;
      for (const auto& r : regs) found = found || r.spec.name == *name;
      if (!found) diag.error(*where, "no register named '" + *name + "' in [[registers]]");
    }
  }
};

class StatusParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "status"; }
  std::unique_ptr<Section> absent() const override { return std::make_unique<StatusSection>(); }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<StatusSection>();
    if (const auto* t = as_table(node, name(), diag)) {
      TableReader r(*t, "status", diag);
      s->socket_path = r.string("socket_path", "");
      if (s->socket_path.size() >= 100) {
        diag.error(r.where("socket_path"), "a Unix socket path must be shorter than 100 bytes");
      }
      s->prometheus_port = static_cast<int>(r.integer("prometheus_port", 0, 0, 65535));
      s->prometheus_address = r.choice("prometheus_address", "127.0.0.1", {"127.0.0.1", "::1"});
      s->admin_group = r.string("admin_group", "nccomp-admin");
      if (!valid_group_name(s->admin_group)) {
        diag.error(r.where("admin_group"),
                   "must be a group name: a letter or '_', then letters, digits, '_', '-' or "
                   "'.', at most 32 characters");
      }
      s->client_timeout_s = r.number("client_timeout_s", 2.0, 0.1, 60.0);
      s->max_clients = static_cast<int>(r.integer("max_clients", 32, 1, 1024));
    }
    return s;
  }
};

class RegistersParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "registers"; }
  std::unique_ptr<Section> absent() const override { return std::make_unique<RegistersSection>(); }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<RegistersSection>();
    std::set<std::string> names;
    for (const auto& entry : array_of_tables(node, "registers", diag)) {
      const auto& t = *entry.table;
      const std::string& path = entry.path;
      TableReader r(t, path, diag);
      RegisterEntry e;
      e.where = where_of(&t, path);
      e.spec.name = r.string("name", std::nullopt);
      if (!e.spec.name.empty() && !names.insert(e.spec.name).second) {
        diag.error(r.where("name"), "register name '" + e.spec.name + "' is used twice");
      }
      if (e.spec.name.size() > 255) {
        diag.error(r.where("name"), "longer than 255 characters");
      }
      const std::string kind =
          r.choice("kind", std::nullopt,
                   {"tool_length_wear", "tool_radius_wear", "checkpoint", "axis_offset", "flag"});
      (void)core::engine::parse_register_kind(kind, e.spec.kind);
      e.bus = r.string("bus", std::nullopt);
      if (e.spec.kind == core::engine::RegisterKind::kFlag) {
        // Flags and program positions (e.g. a restart path of several metres in µm) are written
        // as asked: only the absolute bound applies (core/engine/engine.hpp, kFlag).
        e.spec.limits.max_abs_um = r.number("max_abs_um", 1.0, 1e-3, 1e12);
        e.spec.limits.max_step_um = e.spec.limits.max_abs_um;
        e.spec.limits.max_rate_um_per_s = e.spec.limits.max_abs_um;
      } else {
        e.spec.limits.max_abs_um = r.number("max_abs_um", std::nullopt, 1e-3, 1e6);
        e.spec.limits.max_step_um = r.number("max_step_um", std::nullopt, 1e-3, 1e6);
        e.spec.limits.max_rate_um_per_s = r.number("max_rate_um_per_s", std::nullopt, 1e-3, 1e6);
      }
      e.where.key_path = path;
      s->registers.push_back(std::move(e));
    }
    return s;
  }
  void cross_check(const Config& config, Diagnostics& diag) const override {
    for (const auto& e : registers_section(config).registers) {
      const SectionParser* p = find_section_parser(e.bus);
      if (p == nullptr || !p->provides_bus() || !config.has(e.bus)) {
        std::string buses;
        for (const auto* q : section_parsers()) {
          if (q->provides_bus() && config.has(q->name())) {
            buses += (buses.empty() ? "" : ", ") + std::string(q->name());
          }
        }
        Where w = e.where;
        w.key_path += ".bus";
        diag.error(std::move(w), "no bus section '" + e.bus + "' in the config (buses: " +
                                     (buses.empty() ? "none" : buses) + ")");
      }
    }
  }
};

class RampParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "ramp"; }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<RampSection>();
    std::set<std::string> names;
    for (const auto& entry : array_of_tables(node, "ramp", diag)) {
      const auto& t = *entry.table;
      const std::string& path = entry.path;
      TableReader r(t, path, diag);
      RampEntry e;
      e.where = where_of(&t, path);
      e.config.name = "ramp/" + r.string("name", std::nullopt);
      if (!names.insert(e.config.name).second) {
        diag.error(r.where("name"), "ramp name is used twice");
      }
      e.config.register_name = r.string("register", std::nullopt);
      e.config.start_um = r.number("start_um", 0.0, -1e6, 1e6);
      e.config.target_um = r.number("target_um", std::nullopt, -1e6, 1e6);
      e.config.rate_um_per_s = r.number("rate_um_per_s", std::nullopt, 1e-6, 1e6);
      s->ramps.push_back(std::move(e));
    }
    return s;
  }
  void cross_check(const Config& config, Diagnostics& diag) const override {
    const auto* s = config.find<RampSection>("ramp");
    if (s == nullptr) {
      return;
    }
    const auto& regs = registers_section(config).registers;
    for (const auto& e : s->ramps) {
      bool found = false;
      for (const auto& r : regs) {
        found = found || r.spec.name == e.config.register_name;
      }
      if (!found) {
        Where w = e.where;
        w.key_path += ".register";
        diag.error(std::move(w),
                   "no register named '" + e.config.register_name + "' in [[registers]]");
      }
    }
  }
  void add_modules(const Config& config,
                   std::vector<std::unique_ptr<core::engine::Module>>& modules) const override {
    if (const auto* s = config.find<RampSection>("ramp")) {
      for (const auto& e : s->ramps) {
        modules.push_back(std::make_unique<core::engine::RampModule>(e.config));
      }
    }
  }
};

// Reports the last sample of each of its sensors on the status socket under its key, in order,
// once the sensor has one. For the lags: each lag's value (sensor_N_lag), then their inputs'
// (sensor_N_input, N the lag's sensor), so that with more lags than the status holds the inputs
// of the last ones are left out, never a lag. For the sums: each sum's value (sensor_N_sum).
class SensorSamplesModule final : public core::engine::Module {
 public:
  SensorSamplesModule(std::string name, std::vector<std::pair<std::string, std::uint8_t>> keyed)
      : name_(std::move(name)) {
    for (auto& [key, sensor] : keyed) {
      keys_.push_back(std::move(key));
      sensors_.push_back(sensor);
    }
    values_.assign(sensors_.size(), std::numeric_limits<double>::quiet_NaN());
  }
  std::string_view name() const noexcept override { return name_; }
  void attach(const core::engine::RegisterTable& /*registers*/) override {}
  /// Real-time safe.
  void step(core::TimeNs /*now_ns*/, std::span<const core::Event> events,
            core::StepOutput& /*out*/) noexcept override {
    for (const auto& e : events) {
      const auto* t = std::get_if<core::TemperatureSample>(&e);
      if (t == nullptr) continue;
      for (std::size_t i = 0; i < sensors_.size(); ++i) {
        if (sensors_[i] == t->sensor) values_[i] = t->temperature_c;
      }
    }
  }
  /// Real-time safe.
  std::size_t status(std::span<core::engine::StatusValue> out) const noexcept override {
    std::size_t n = 0;
    for (std::size_t i = 0; i < keys_.size() && n < out.size(); ++i) {
      if (std::isfinite(values_[i])) out[n++] = {keys_[i].c_str(), values_[i], nullptr};
    }
    return n;
  }

 private:
  std::string name_;
  std::vector<std::string> keys_;
  std::vector<std::uint8_t> sensors_;
  std::vector<double> values_;
};

class InputLagsParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "input_lags"; }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<InputLagsSection>();
    for (const auto& entry :
         array_of_tables(node, "input_lags", diag, core::engine::kMaxInputLags)) {
      const auto& t = *entry.table;
      const std::string& path = entry.path;
      TableReader r(t, path, diag);
      InputLagEntry e;
      e.where = where_of(&t, path);
      e.spec.output_sensor = static_cast<std::uint8_t>(r.integer("sensor", std::nullopt, 0, 255));
      e.spec.input_sensor =
          static_cast<std::uint8_t>(r.integer("input_sensor", std::nullopt, 0, 255));
      e.spec.tau_s = r.number("tau_s", std::nullopt, 1e-3, 1e7);
      if (e.spec.output_sensor == e.spec.input_sensor) {
        diag.error(r.where("sensor"), "equals input_sensor: the lag needs a sensor of its own");
      }
      for (std::size_t j = 0; j < s->lags.size(); ++j) {
        const auto& o = s->lags[j].spec;
        if (o.output_sensor == e.spec.output_sensor) {
          diag.error(r.where("sensor"), "sensor " + std::to_string(e.spec.output_sensor) +
                                            " is already the lag of input_lags[" +
                                            std::to_string(j) + "]");
        }
        if (o.input_sensor == e.spec.output_sensor || o.output_sensor == e.spec.input_sensor) {
          diag.error(r.where("sensor"), "a lag of a lag (input_lags[" + std::to_string(j) +
                                            "]): lag the sensor itself");
        }
      }
      r.finish();
      s->lags.push_back(std::move(e));
    }
    return s;
  }
  void add_modules(const Config& config,
                   std::vector<std::unique_ptr<core::engine::Module>>& modules) const override {
    if (const auto* s = config.find<InputLagsSection>("input_lags")) {
      std::vector<std::pair<std::string, std::uint8_t>> keyed;
      for (const auto& e : s->lags) {
        keyed.emplace_back("sensor_" + std::to_string(e.spec.output_sensor) + "_lag",
                           e.spec.output_sensor);
      }
      for (const auto& e : s->lags) {
        keyed.emplace_back("sensor_" + std::to_string(e.spec.output_sensor) + "_input",
                           e.spec.input_sensor);
      }
      modules.push_back(std::make_unique<SensorSamplesModule>("input_lags", std::move(keyed)));
    }
  }
};

class InputSumsParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "input_sums"; }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<InputSumsSection>();
    for (const auto& entry :
         array_of_tables(node, "input_sums", diag, core::engine::kMaxInputSums)) {
      const auto& t = *entry.table;
      const std::string& path = entry.path;
      TableReader r(t, path, diag);
      InputSumEntry e;
      e.where = where_of(&t, path);
      e.sensor_where = r.where("sensor");
      e.spec.output_sensor = static_cast<std::uint8_t>(r.integer("sensor", std::nullopt, 0, 255));
      e.spec.offset = r.number("offset", 0.0, -1e12, 1e12);
      const std::size_t before = diag.items().size();
      for (const auto v : r.integer_list("inputs", 0, 255)) {
        e.spec.inputs.push_back(static_cast<std::uint8_t>(v));
      }
      e.spec.weights = r.number_list("weights", -1e12, 1e12);
      const bool lists_ok = diag.items().size() == before;
      if (!t.contains("inputs")) r.error("inputs", "missing required key");
      if (!t.contains("weights")) r.error("weights", "missing required key");
      if (lists_ok && t.contains("inputs") && t.contains("weights")) {
        const std::size_t n = e.spec.inputs.size();
        if (n == 0 || n > core::engine::kMaxSumInputs) {
          r.error("inputs", "must name 1 to " + std::to_string(core::engine::kMaxSumInputs) +
                                " sensors, got " + std::to_string(n));
        }
        if (e.spec.weights.size() != n) {
          r.error("weights", std::to_string(e.spec.weights.size()) + " weights for " +
                                 std::to_string(n) + " inputs: one weight per input");
        }
      }
      for (std::size_t k = 0; k < e.spec.inputs.size(); ++k) {
        const std::uint8_t in = e.spec.inputs[k];
        for (std::size_t m = 0; m < k; ++m) {
          if (e.spec.inputs[m] == in) {
            r.error("inputs", "sensor " + std::to_string(in) + " is listed twice (inputs[" +
                                  std::to_string(m) + "] and inputs[" + std::to_string(k) +
                                  "]): add the weights");
          }
        }
        if (in == e.spec.output_sensor) {
          r.error("sensor", "is one of its inputs (inputs[" + std::to_string(k) +
                                "]): the sum needs a sensor of its own");
        }
      }
      for (std::size_t j = 0; j < s->sums.size(); ++j) {
        const auto& o = s->sums[j].spec;
        const std::string other = "input_sums[" + std::to_string(j) + "]";
        if (o.output_sensor == e.spec.output_sensor) {
          r.error("sensor", "sensor " + std::to_string(e.spec.output_sensor) +
                                " is already the sum of " + other);
        }
        const auto has = [](const std::vector<std::uint8_t>& v, std::uint8_t x) {
          return std::find(v.begin(), v.end(), x) != v.end();
        };
        if (has(o.inputs, e.spec.output_sensor) || has(e.spec.inputs, o.output_sensor)) {
          r.error("sensor", "a sum of a sum (" + other + "): sum the sensors themselves");
        }
      }
      r.finish();
      s->sums.push_back(std::move(e));
    }
    return s;
  }
  // The lags are computed before the sums: a sum may take a lag's output, but not publish on a
  // lag's sensor nor be a lag's input.
  void cross_check(const Config& config, Diagnostics& diag) const override {
    const auto* s = config.find<InputSumsSection>("input_sums");
    const auto* lags = config.find<InputLagsSection>("input_lags");
    if (s == nullptr || lags == nullptr) return;
    for (const auto& e : s->sums) {
      for (std::size_t j = 0; j < lags->lags.size(); ++j) {
        const auto& l = lags->lags[j].spec;
        const std::string other = "input_lags[" + std::to_string(j) + "]";
        if (l.output_sensor == e.spec.output_sensor) {
          diag.error(e.sensor_where, "sensor " + std::to_string(e.spec.output_sensor) +
                                         " is already the lag of " + other);
        }
        if (l.input_sensor == e.spec.output_sensor) {
          diag.error(e.sensor_where,
                     "a lag of a sum (" + other +
                         "): the lags are computed before the sums, lag the sensors instead");
        }
      }
    }
  }
  void add_modules(const Config& config,
                   std::vector<std::unique_ptr<core::engine::Module>>& modules) const override {
    if (const auto* s = config.find<InputSumsSection>("input_sums")) {
      std::vector<std::pair<std::string, std::uint8_t>> keyed;
      for (const auto& e : s->sums) {
        keyed.emplace_back("sensor_" + std::to_string(e.spec.output_sensor) + "_sum",
                           e.spec.output_sensor);
      }
      modules.push_back(std::make_unique<SensorSamplesModule>("input_sums", std::move(keyed)));
    }
  }
};

class LoopbackParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "loopback"; }
  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    auto s = std::make_unique<LoopbackSection>();
    if (const auto* t = as_table(node, name(), diag)) {
      TableReader r(*t, "loopback", diag);
      const auto pow2 = [&](std::string_view key, std::int64_t def) {
        const auto v = r.integer(key, def, 2, 1 << 20);
        if ((v & (v - 1)) != 0) {
          diag.error(r.where(key), "must be a power of two");
          return static_cast<std::size_t>(def);
        }
        return static_cast<std::size_t>(v);
      };
      s->rx_capacity = pow2("rx_capacity", 1024);
      s->tx_capacity = pow2("tx_capacity", 1024);
    }
    return s;
  }
  bool provides_bus() const noexcept override { return true; }
  std::unique_ptr<drivers::Bus> make_bus(const Config& config) const override {
    const auto& s = typed<LoopbackSection>(config, "loopback");
    return std::make_unique<drivers::loopback::LoopbackBus>(s.rx_capacity, s.tx_capacity);
  }
};

}  // namespace

void register_builtin_sections() {
  register_section(std::make_unique<DaemonParser>());
  register_section(std::make_unique<StateParser>());
  register_section(std::make_unique<LogParser>());
  register_section(std::make_unique<MeasurementLogParser>());
  register_section(std::make_unique<StatusParser>());
  register_section(std::make_unique<RegistersParser>());
  register_section(std::make_unique<RampParser>());
  register_section(std::make_unique<LoopbackParser>());
  register_section(std::make_unique<InputLagsParser>());
  register_section(std::make_unique<InputSumsParser>());
}

const DaemonSection& daemon_section(const Config& c) { return typed<DaemonSection>(c, "daemon"); }
const StateSection& state_section(const Config& c) { return typed<StateSection>(c, "state"); }
const LogSection& log_section(const Config& c) { return typed<LogSection>(c, "log"); }
const MeasurementLogSection& measurement_log_section(const Config& c) {
  return typed<MeasurementLogSection>(c, "measurement_log");
}
const StatusSection& status_section(const Config& c) { return typed<StatusSection>(c, "status"); }
const RegistersSection& registers_section(const Config& c) {
  return typed<RegistersSection>(c, "registers");
}

std::unique_ptr<core::engine::Engine> build_engine(const Config& c) {
  std::vector<core::engine::RegisterSpec> regs;
  for (const auto& e : registers_section(c).registers) {
    regs.push_back(e.spec);
  }
  std::vector<std::unique_ptr<core::engine::Module>> modules;
  for (const auto* p : section_parsers()) {
    if (c.has(p->name())) {
      p->add_modules(c, modules);
    }
  }
  core::engine::EngineOptions options{daemon_section(c).max_events_per_cycle};
  if (const auto* s = c.find<InputLagsSection>("input_lags")) {
    for (const auto& e : s->lags) options.lags.push_back(e.spec);
  }
  if (const auto* s = c.find<InputSumsSection>("input_sums")) {
    for (const auto& e : s->sums) options.sums.push_back(e.spec);
  }
  auto engine = std::make_unique<core::engine::Engine>();
  engine->configure(std::move(regs), std::move(modules), options);
  return engine;
}

namespace {

Where section_where(const Config& c, const std::string& section) {
  if (auto it = c.keys().find(section); it != c.keys().end()) {
    return it->second.where;
  }
  return Where{c.files().empty() ? std::string() : c.files().front(), 0, 0, section};
}

// Keys of `section` that name register `name` (a string value) or its index (an integer value of
// a key with "register" in its name), in key order.
std::vector<Where> keys_naming(const Config& c, const std::string& section, const std::string& name,
                               std::size_t index) {
  std::vector<Where> out;
  const std::string idx = std::to_string(index);
  for (const auto& [path, info] : c.keys()) {
    if (path.rfind(section, 0) != 0 || path.size() == section.size() ||
        (path[section.size()] != '.' && path[section.size()] != '[')) {
      continue;
    }
    const auto last = path.substr(path.find_last_of(".]") + 1);
    if ((!info.value.empty() && info.value == name && last.find("register") != std::string::npos) ||
        (info.value == idx && last.find("register") != std::string::npos)) {
      out.push_back(info.where);
    }
  }
  return out;
}

std::string at(const Where& w) {
  // Appended piece by piece: GCC 12 -O3 reports a false -Wrestrict for "x" + std::string.
  std::string s = w.key_path;
  s += ", ";
  s += w.file;
  if (w.line > 0) {
    s += ':';
    s += std::to_string(w.line);
  }
  return s;
}

}  // namespace

std::unique_ptr<core::engine::Engine> build_engine(const Config& c, Diagnostics& diag) {
  try {
    return build_engine(c);
  } catch (const std::exception& refusal) {
    // Find out where: rebuild each section's modules on their own, attach them to the same
    // registers and look for the register two of them write.
    const std::size_t before = diag.items().size();
    const auto& entries = registers_section(c).registers;
    std::vector<core::engine::RegisterSpec> specs;
    for (const auto& e : entries) {
      specs.push_back(e.spec);
    }
    const core::engine::RegisterTable table(specs);
    struct Owned {
      std::string section;
      std::unique_ptr<core::engine::Module> module;
    };
    std::vector<Owned> modules;
    for (const auto* p : section_parsers()) {
      if (!c.has(p->name())) {
        continue;
      }
      const std::string section(p->name());
      std::vector<std::unique_ptr<core::engine::Module>> made;
      try {
        p->add_modules(c, made);
        for (auto& m : made) {
          m->attach(table);
          modules.push_back(Owned{section, std::move(m)});
        }
      } catch (const std::exception& e) {
        diag.error(section_where(c, section), std::string("engine: ") + e.what());
      }
    }
    std::vector<int> writer(specs.size(), -1);
    for (std::size_t k = 0; k < modules.size(); ++k) {
      for (const std::uint16_t r : modules[k].module->written_registers()) {
        if (r >= writer.size()) {
          continue;
        }
        const int w = writer[r];
        if (w < 0 || static_cast<std::size_t>(w) == k) {
          writer[r] = static_cast<int>(k);
          continue;
        }
        const Owned& first = modules[static_cast<std::size_t>(w)];
        const Owned& second = modules[k];
        const std::string& name = specs[r].name;
        const auto first_keys = keys_naming(c, first.section, name, r);
        const auto second_keys = keys_naming(c, second.section, name, r);
        const Where first_at =
            first_keys.empty() ? section_where(c, first.section) : first_keys.front();
        const Where second_at =
            second_keys.empty() ? section_where(c, second.section) : second_keys.back();
        Where reg = r < entries.size() ? entries[r].where : Where{};
        diag.error(second_at, "register '" + name + "' (" + at(reg) + ") is written by module '" +
                                  std::string(first.module->name()) + "' (" + at(first_at) +
                                  ") and by '" + std::string(second.module->name()) +
                                  "'; give each module its own registers");
      }
    }
    if (diag.items().size() == before) {
      diag.error(Where{c.files().empty() ? std::string() : c.files().front(), 0, 0, "engine"},
                 refusal.what());
    }
    return nullptr;
  }
}

}  // namespace nccomp::daemon::config
