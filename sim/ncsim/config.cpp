#include "sim/ncsim/config.hpp"

#include <toml++/toml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include "formats/checkpoints/checkpoints_toml.hpp"
#include "formats/toml/diagnostics.hpp"
#include "formats/toml/guard.hpp"
#include "formats/toml/table_reader.hpp"

namespace nccomp::sim::ncsim {
namespace {

namespace fs = std::filesystem;

using formats::Diagnostics;
using formats::TableReader;

const toml::table& or_empty(const toml::table* t) {
  static const toml::table kEmpty;
  return t != nullptr ? *t : kEmpty;
}

/// ncsim's tables read with the one TableReader: a key absent from the file keeps the value the
/// config already holds (its default, or an earlier program's), and every error is collected.
class Reader {
 public:
  Reader(const toml::table* t, std::string path, Diagnostics& diag)
      : r_(or_empty(t), std::move(path), diag) {}

  void number(std::string_view key, double& out, double lo, double hi) {
    out = r_.number(key, out, lo, hi);
  }
  void integer(std::string_view key, std::int32_t& out, std::int64_t lo, std::int64_t hi) {
    out = static_cast<std::int32_t>(r_.integer(key, out, lo, hi));
  }
  void boolean(std::string_view key, bool& out) { out = r_.boolean(key, out); }
  void string(std::string_view key, std::string& out) { out = r_.string(key, out); }
  void vec3(std::string_view key, Vec3& out, double lo, double hi) {
    const toml::node* n = r_.node().get(key);
    const std::vector<double> v = r_.number_list(key, lo, hi);
    if (n == nullptr || !n->is_array()) {
      return;
    }
    if (n->as_array()->size() != 3) {
      r_.error(key, "must be an array of 3 numbers [x, y, z]");
    } else if (v.size() == 3) {
      out = Vec3{v[0], v[1], v[2]};
    }
  }
  [[nodiscard]] std::vector<double> numbers(std::string_view key, double lo, double hi) {
    return r_.number_list(key, lo, hi);
  }
  /// Register indices.
  void int_list(std::string_view key, std::vector<std::int32_t>& out) {
    const bool present = r_.node().contains(key);
    const std::vector<std::int64_t> v = r_.integer_list(key, 0, 65535);
    if (present) {
      out.assign(v.begin(), v.end());
    }
  }
  /// File names.
  void string_list(std::string_view key, std::vector<std::string>& out) {
    const toml::node* n = r_.value(key);
    if (n == nullptr) {
      return;
    }
    const toml::array* a = n->as_array();
    if (a == nullptr) {
      r_.error(key, "must be an array of strings");
      return;
    }
    out.clear();
    for (std::size_t i = 0; i < a->size(); ++i) {
      const toml::node& e = *a->get(i);
      if (!e.is_string() || e.value<std::string>()->empty()) {
        r_.diagnostics().error(&e, r_.path(key) + "[" + std::to_string(i) + "]",
                               "must be a non-empty string (a file name)");
        continue;
      }
      out.push_back(*e.value<std::string>());
    }
  }
  template <typename E>
  void choice(std::string_view key, E& out,
              std::initializer_list<std::pair<std::string_view, E>> options) {
    std::vector<std::pair<std::string, E>> names;
    for (const auto& [name, value] : options) {
      names.emplace_back(std::string(name), value);
    }
    out = r_.pick(key, out, names);
  }
  /// A sub-table (nullptr if absent or not a table).
  const toml::table* table(std::string_view key) { return r_.table(key); }
  void error(std::string_view key, std::string message) { r_.error(key, std::move(message)); }
  void finish() { r_.finish(); }

 private:
  TableReader r_;
};

/// A data file's error at its line (0: the whole file).
[[noreturn]] void data_error(const std::string& path, std::size_t line, std::string message) {
  Diagnostics d;
  d.error(formats::Where{path, static_cast<int>(line), 0, ""}, std::move(message));
  throw formats::DiagnosticsError(std::move(d), path);
}

/// Runs a data file's reader; its errors join the config's. False if there was one.
template <typename F>
bool read_data(Diagnostics& diag, F&& read) {
  try {
    read();
    return true;
  } catch (const formats::DiagnosticsError& e) {
    diag.append(e.diagnostics(), "");
    return false;
  }
}

std::string resolve(const std::string& base_dir, const std::string& p) {
  if (p.empty() || fs::path(p).is_absolute()) {
    return p;
  }
  return (fs::path(base_dir) / p).lexically_normal().string();
}

std::optional<std::string> read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return std::nullopt;
  }
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

/// Applies one --set; what it cannot apply is reported.
void apply_override(toml::table& root, const std::string& spec, Diagnostics& diag) {
  const auto refuse = [&](const std::string& why) {
    diag.error(formats::Where{"--set", 0, 0, ""}, spec + ": " + why);
  };
  const auto eq = spec.find('=');
  if (eq == std::string::npos || eq == 0) {
    return refuse("expected KEY=VALUE");
  }
  std::string key = spec.substr(0, eq);
  const std::string value = spec.substr(eq + 1);
  static const std::set<std::string> kEffects = {"wear",        "pushoff",     "hardness",
                                                 "thermal",     "pitch",       "probe_noise",
                                                 "laser_noise", "broken_tool", "probe_outlier"};
  std::vector<std::string> parts;
  std::size_t start = 0;
  while (true) {
    const auto dot = key.find('.', start);
    parts.push_back(key.substr(start, dot - start));
    if (dot == std::string::npos) {
      break;
    }
    start = dot + 1;
  }
  for (const auto& p : parts) {
    if (p.empty()) {
      return refuse("empty key part");
    }
  }
  if (kEffects.count(parts.front()) != 0) {
    parts.insert(parts.begin(), "effects");
  }
  toml::table* t = &root;
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    toml::node* n = t->get(parts[i]);
    if (n == nullptr) {
      t->insert(parts[i], toml::table{});
      n = t->get(parts[i]);
    }
    if (!n->is_table()) {
      return refuse(parts[i] + " is not a table");
    }
    t = n->as_table();
  }
  try {
    const std::string doc = "v = " + value;
    toml::table v = formats::parse_toml(std::string_view(doc), std::string_view("--set"));
    t->insert_or_assign(parts.back(), std::move(*v.get("v")));
  } catch (const toml::parse_error&) {
    // Not a TOML value: a bare word is taken as a string (parsed, so it carries "--set" as its
    // source for the messages).
    std::string quoted = "v = \"";
    for (const char ch : value) {
      if (ch == '"' || ch == '\\') {
        quoted += '\\';
      }
      quoted += ch;
    }
    quoted += '"';
    try {
      toml::table v = formats::parse_toml(std::string_view(quoted), std::string_view("--set"));
      t->insert_or_assign(parts.back(), std::move(*v.get("v")));
    } catch (const toml::parse_error&) {
      return refuse("the value is neither TOML nor a plain string");
    }
  }
}

void read_effects(const toml::table* eff, const std::string& base, bool read_files,
                  EffectsConfig& e, Diagnostics& diag) {
  Reader r(eff, "effects", diag);
  {
    Reader w(r.table("wear"), "effects.wear", diag);
    WearConfig& c = e.wear;
    w.boolean("enabled", c.enabled);
    w.choice("curve", c.curve,
             {{"linear", WearCurve::kLinear},
              {"power", WearCurve::kPower},
              {"phm2010", WearCurve::kTable}});
    w.number("initial_um", c.initial_um, 0.0, 1e4);
    w.number("rate_um_per_m", c.rate_um_per_m, 0.0, 1e4);
    w.number("coefficient_um", c.coefficient_um, 0.0, 1e4);
    w.number("exponent", c.exponent, 0.05, 5.0);
    std::string phm_file;
    std::string column = "max";
    double path_per_cut_mm = 108.0;
    double radial_per_vb = 0.176;  // tan 10°: VB → radial wear through the clearance angle
    std::int32_t start_cut = 1;
    w.string("phm_file", phm_file);
    w.string("phm_column", column);
    w.number("path_per_cut_mm", path_per_cut_mm, 1e-3, 1e6);
    w.number("radial_per_vb", radial_per_vb, 0.0, 1.0);
    w.integer("start_cut", start_cut, 1, 314);
    if (c.curve == WearCurve::kTable && !read_files) {
      c.curve = WearCurve::kLinear;
    }
    if (c.curve == WearCurve::kTable) {
      if (phm_file.empty()) {
        w.error("phm_file", "curve = \"phm2010\" needs phm_file (c4_wear.csv or c6_wear.csv)");
      } else if (column != "max" && column != "flute_1" && column != "flute_2" &&
                 column != "flute_3") {
        w.error("phm_column",
                "must be one of \"flute_1\", \"flute_2\", \"flute_3\", \"max\", got \"" + column +
                    "\"");
      } else {
        const std::string path = resolve(base, phm_file);
        (void)read_data(diag, [&] {
          const auto cols = read_csv_columns(path, {"cut", "flute_1", "flute_2", "flute_3"});
          Curve curve;
          double vb0 = std::numeric_limits<double>::quiet_NaN();
          for (std::size_t i = 0; i < cols[0].size(); ++i) {
            const double cut = cols[0][i];
            double vb = 0.0;
            if (column == "max") {
              vb = std::max({cols[1][i], cols[2][i], cols[3][i]});
            } else {
              vb = cols[static_cast<std::size_t>(column.back() - '0')][i];
            }
            if (cut < start_cut) {
              continue;
            }
            if (std::isnan(vb0)) {
              vb0 = vb;
            }
            const double x = (cut - start_cut) * path_per_cut_mm;
            if (!curve.x.empty() && !(x > curve.x.back())) {
              data_error(path, 0, "cut numbers must increase");
            }
            curve.x.push_back(x);
            curve.y.push_back((vb - vb0) * radial_per_vb);
          }
          if (curve.x.size() < 2) {
            data_error(path, 0, "fewer than 2 cuts from start_cut on");
          }
          c.table = std::move(curve);
          c.table_source = path + " (" + column + ", from cut " + std::to_string(start_cut) + ", " +
                           std::to_string(path_per_cut_mm) + " mm per cut, radial = VB x " +
                           std::to_string(radial_per_vb) + ")";
        });
      }
    }
    w.finish();
  }
  {
    Reader p(r.table("pushoff"), "effects.pushoff", diag);
    PushoffConfig& c = e.pushoff;
    p.boolean("enabled", c.enabled);
    p.number("base_um", c.base_um, 0.0, 1e3);
    p.number("wear_gain_per_um", c.wear_gain_per_um, 0.0, 10.0);
    p.number("clamp_z_mm", c.clamp_z_mm, -1e4, 1e4);
    p.number("reference_lever_mm", c.reference_lever_mm, 1e-3, 1e4);
    p.finish();
  }
  {
    Reader h(r.table("hardness"), "effects.hardness", diag);
    h.boolean("enabled", e.hardness.enabled);
    h.number("amplitude", e.hardness.amplitude, 0.0, 0.9);
    h.number("wavelength_mm", e.hardness.wavelength_mm, 1.0, 1e5);
    h.boolean("per_part", e.hardness.per_part);
    h.finish();
  }
  {
    Reader t(r.table("thermal"), "effects.thermal", diag);
    ThermalConfig& c = e.thermal;
    t.boolean("enabled", c.enabled);
    t.choice("mode", c.mode,
             {{"first_order", ThermalMode::kFirstOrder}, {"replay", ThermalMode::kReplay}});
    t.vec3("gain_um", c.gain_um, -1e3, 1e3);
    t.number("time_constant_s", c.time_constant_s, 1e-3, 1e7);
    t.number("ambient_c", c.ambient_c, -50.0, 100.0);
    t.number("temperature_rise_c", c.temperature_rise_c, -50.0, 100.0);
    std::string replay_file;
    std::string channels[3] = {"", "", "ch5"};
    std::string temps[2] = {"t5", "t1"};
    Vec3 sign{1.0, 1.0, -1.0};
    t.string("replay_file", replay_file);
    t.string("x_channel", channels[0]);
    t.string("y_channel", channels[1]);
    t.string("z_channel", channels[2]);
    t.vec3("channel_sign", sign, -1.0, 1.0);
    t.string("spindle_temperature", temps[0]);
    t.string("ambient_temperature", temps[1]);
    t.number("time_scale", c.time_scale, 1e-3, 1e5);
    t.number("replay_start_s", c.replay_start_s, 0.0, 1e7);
    if (c.mode == ThermalMode::kReplay && !read_files) {
      c.mode = ThermalMode::kFirstOrder;
    }
    if (c.mode == ThermalMode::kReplay) {
      if (replay_file.empty()) {
        t.error("replay_file", "mode = \"replay\" needs replay_file (FL_THERMAL data.csv)");
      } else {
        const std::string path = resolve(base, replay_file);
        (void)read_data(diag, [&] {
          std::vector<std::string> names{"時間"};
          for (const auto& ch : channels) {
            if (!ch.empty()) {
              names.push_back(ch);
            }
          }
          names.push_back(temps[0]);
          names.push_back(temps[1]);
          const auto cols = read_csv_columns(path, names);
          for (std::size_t i = 1; i < cols[0].size(); ++i) {
            if (!(cols[0][i] > cols[0][i - 1])) {
              data_error(path, i + 2, "time must increase");
            }
          }
          std::size_t k = 1;
          for (std::size_t a = 0; a < 3; ++a) {
            if (channels[a].empty()) {
              continue;
            }
            Curve cv{cols[0], cols[k]};
            for (double& v : cv.y) {
              v *= sign[a];
            }
            c.replay_um[a] = std::move(cv);
            ++k;
          }
          c.replay_temperature_c[0] = Curve{cols[0], cols[k]};
          c.replay_temperature_c[1] = Curve{cols[0], cols[k + 1]};
          c.replay_source = path;
        });
      }
    }
    t.finish();
  }
  {
    Reader p(r.table("pitch"), "effects.pitch", diag);
    p.boolean("enabled", e.pitch.enabled);
    p.vec3("amplitude_um", e.pitch.amplitude_um, -100.0, 100.0);
    p.number("pitch_mm", e.pitch.pitch_mm, 0.1, 1e3);
    p.vec3("slope_um_per_m", e.pitch.slope_um_per_m, -1e3, 1e3);
    p.finish();
  }
  for (auto [name, cfg] :
       {std::pair{"probe_noise", &e.probe_noise}, std::pair{"laser_noise", &e.laser_noise}}) {
    Reader n(r.table(name), std::string("effects.") + name, diag);
    n.boolean("enabled", cfg->enabled);
    n.number("sigma_um", cfg->sigma_um, 0.0, 1e3);
    n.finish();
  }
  {
    Reader b(r.table("broken_tool"), "effects.broken_tool", diag);
    b.boolean("enabled", e.broken_tool.enabled);
    b.number("at_path_mm", e.broken_tool.at_path_mm, 0.0, 1e9);
    b.number("wear_jump_um", e.broken_tool.wear_jump_um, 0.0, 1e5);
    b.boolean("report_flag", e.broken_tool.report_flag);
    b.finish();
  }
  {
    Reader o(r.table("probe_outlier"), "effects.probe_outlier", diag);
    o.boolean("enabled", e.probe_outlier.enabled);
    o.integer("part", e.probe_outlier.part, 1, 1000000);
    o.integer("checkpoint", e.probe_outlier.checkpoint, 0, 100000);
    o.number("value_um", e.probe_outlier.value_um, -1e5, 1e5);
    o.finish();
  }
  r.finish();
}

}  // namespace

std::string_view program_name(ProgramKind p) noexcept {
  switch (p) {
    case ProgramKind::kMouldFace:
      return "mould_face";
    case ProgramKind::kSideWall:
      return "side_wall";
    case ProgramKind::kRoll:
      return "roll";
    case ProgramKind::kTouch:
      return "touch";
  }
  return "?";
}

std::string_view bus_name(BusKind b) noexcept { return b == BusKind::kModbus ? "modbus" : "can"; }

std::vector<std::vector<double>> read_csv_columns(const std::string& path,
                                                  const std::vector<std::string>& columns) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    data_error(path, 0, "cannot read the file");
  }
  std::string line;
  std::size_t line_no = 0;
  // Leading '#' comment lines and blank lines (the profile / trajectory CSVs of
  // docs/grinding.md allow them) come before the header.
  for (;;) {
    if (!std::getline(in, line)) {
      data_error(path, line_no + 1, "empty file, expected a header");
    }
    ++line_no;
    const auto first = line.find_first_not_of(" \t\r");
    if (first != std::string::npos && line[first] != '#') {
      break;
    }
  }
  auto split = [](const std::string& l) {
    std::vector<std::string> out;
    std::string cur;
    for (char ch : l) {
      if (ch == ',') {
        out.push_back(cur);
        cur.clear();
      } else if (ch != '\r') {
        cur += ch;
      }
    }
    out.push_back(cur);
    return out;
  };
  auto trim = [](std::string s) {
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) {
      s.pop_back();
    }
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) {
      s.erase(s.begin());
    }
    return s;
  };
  const auto header = split(line);
  std::vector<std::size_t> idx;
  for (const auto& want : columns) {
    std::size_t found = header.size();
    for (std::size_t i = 0; i < header.size(); ++i) {
      const std::string h = trim(header[i]);
      // "ch5(um)" is found as "ch5": the unit suffix is part of the source's header.
      if (h == want || h.substr(0, h.find('(')) == want) {
        found = i;
        break;
      }
    }
    if (found == header.size()) {
      data_error(path, line_no, "no column \"" + want + "\" in the header");
    }
    idx.push_back(found);
  }
  std::vector<std::vector<double>> out(columns.size());
  while (std::getline(in, line)) {
    ++line_no;
    const std::string t = trim(line);
    if (t.empty() || t == "\r" || t.front() == '#') {
      continue;
    }
    const auto cells = split(line);
    for (std::size_t k = 0; k < idx.size(); ++k) {
      if (idx[k] >= cells.size()) {
        data_error(path, line_no, "missing column \"" + columns[k] + "\"");
      }
      const std::string cell = trim(cells[idx[k]]);
      char* end = nullptr;
      const double v = std::strtod(cell.c_str(), &end);
      if (cell.empty() || *end != '\0' || !std::isfinite(v)) {
        data_error(path, line_no,
                   "column \"" + columns[k] + "\": not a finite number: \"" + cell + "\"");
      }
      out[k].push_back(v);
    }
  }
  if (out.front().empty()) {
    data_error(path, 0, "no data rows");
  }
  return out;
}

SimConfig parse_sim_config(std::string_view text, const std::string& file,
                           const std::string& base_dir, const std::vector<std::string>& overrides,
                           bool read_files, std::optional<ProgramKind> program) {
  const auto wants = [&](ProgramKind p) { return read_files && (!program || *program == p); };
  toml::table root;
  try {
    root = formats::parse_toml(text, file);
  } catch (const toml::parse_error& e) {
    throw formats::DiagnosticsError(e, file);
  }
  Diagnostics diag;
  for (const auto& o : overrides) {
    apply_override(root, o, diag);
  }
  SimConfig c;
  c.file = file;
  Reader top(&root, "", diag);
  {
    Reader n(top.table("ncsim"), "ncsim", diag);
    n.string("bus_map", c.bus_map_file);
    if (c.bus_map_file.empty()) {
      n.error("bus_map",
              "missing required key: the daemon's register map (reference-nc-modbus.toml)");
    }
    n.string_list("bus_map_extra", c.bus_map_extra_files);
    n.string("can_bus_map", c.can_bus_map_file);
    n.string_list("can_bus_map_extra", c.can_bus_map_extra_files);
    n.string("can_interface", c.can_interface);
    n.integer("modbus_port", c.modbus_port, -1, 65535);
    n.number("lockstep_rate_hz", c.lockstep_rate_hz, 1.0, 100000.0);
    n.number("step_mm", c.step_mm, 0.001, 0.1);
    std::int32_t seed = 1;
    n.integer("seed", seed, 0, std::numeric_limits<std::int32_t>::max());
    c.seed = static_cast<std::uint64_t>(seed);
    n.integer("parts", c.parts, 1, 100000);
    n.integer("first_part", c.first_part, 1, 1000000);
    n.number("tool_cut_path_mm", c.tool_cut_path_mm, 0.0, 1e9);
    n.int_list("initial_register_indices", c.initial_register_indices);
    c.initial_registers_um = n.numbers("initial_registers_um", -1e6, 1e6);
    if (c.initial_registers_um.size() != c.initial_register_indices.size()) {
      n.error("initial_registers_um", "has " + std::to_string(c.initial_registers_um.size()) +
                                          " values for the " +
                                          std::to_string(c.initial_register_indices.size()) +
                                          " registers of initial_register_indices");
    }
    // The maps' files: resolved against the config's folder, read unless only the text is checked.
    const auto read_map = [&](std::string_view key, std::string& f) {
      f = resolve(base_dir, f);
      std::optional<std::string> map_text;
      if (read_files && !(map_text = read_text(f))) {
        n.error(key, "cannot read " + f);
      }
      return map_text.value_or(std::string{});
    };
    if (!c.bus_map_file.empty()) {
      c.bus_map_text = read_map("bus_map", c.bus_map_file);
    }
    for (auto& f : c.bus_map_extra_files) {
      c.bus_map_extra_texts.push_back(read_map("bus_map_extra", f));
    }
    if (!c.can_bus_map_file.empty()) {
      c.can_bus_map_text = read_map("can_bus_map", c.can_bus_map_file);
    }
    for (auto& f : c.can_bus_map_extra_files) {
      c.can_bus_map_extra_texts.push_back(read_map("can_bus_map_extra", f));
    }
    n.finish();
  }
  {
    Reader n(top.table("nc"), "nc", diag);
    NcConfig& nc = c.nc;
    n.number("latency_s", nc.latency_s, 0.0, 60.0);
    n.number("offset_limit_um", nc.offset_limit_um, 0.0, 1e6);
    n.integer("tool_length_register", nc.tool_length_register, -1, 65535);
    n.integer("tool_radius_register", nc.tool_radius_register, -1, 65535);
    n.integer("axis_x_register", nc.axis_register[0], -1, 65535);
    n.integer("axis_y_register", nc.axis_register[1], -1, 65535);
    n.integer("axis_z_register", nc.axis_register[2], -1, 65535);
    n.integer("checkpoint_base_register", nc.checkpoint_base_register, -1, 65535);
    n.integer("checkpoint_register_count", nc.checkpoint_register_count, 0, 4096);
    n.integer("measure_request_register", nc.measure_request_register, -1, 65535);
    n.int_list("alarm_registers", nc.alarm_registers);
    n.integer("tool", nc.tool, 1, 9999);
    n.finish();
  }
  read_effects(top.table("effects"), base_dir, read_files, c.effects, diag);
  {
    Reader p(top.table("program"), "program", diag);
    {
      Reader m(p.table("mould_face"), "program.mould_face", diag);
      MouldFaceConfig& f = c.mould_face;
      m.number("size_x_mm", f.size_x_mm, 1.0, 1e4);
      m.number("size_y_mm", f.size_y_mm, 0.0, 1e4);
      m.number("bulge_x_mm", f.bulge_x_mm, -1e3, 1e3);
      m.number("bulge_y_mm", f.bulge_y_mm, -1e3, 1e3);
      m.number("base_z_mm", f.base_z_mm, -1e4, 1e4);
      m.number("stepover_mm", f.stepover_mm, 0.01, 1e3);
      m.number("feed_mm_per_min", f.feed_mm_per_min, 1.0, 1e6);
      m.number("ball_radius_mm", f.ball_radius_mm, 0.01, 100.0);
      m.number("measure_interval_mm", f.measure_interval_mm, 0.0, 1e9);
      m.number("laser_trip_s", f.laser_trip_s, 0.0, 3600.0);
      m.vec3("laser_position_mm", f.laser_position_mm, -1e5, 1e5);
      m.integer("probe_points", f.probe_points, 0, 64);
      m.number("probe_time_s", f.probe_time_s, 0.0, 3600.0);
      m.number("approach_s", f.approach_s, 0.0, 3600.0);
      m.finish();
    }
    {
      Reader s(p.table("side_wall"), "program.side_wall", diag);
      SideWallConfig& w = c.side_wall;
      s.string("checkpoints_file", w.checkpoints_file);
      s.number("feed_mm_per_min", w.feed_mm_per_min, 1.0, 1e6);
      s.number("probe_time_s", w.probe_time_s, 0.0, 3600.0);
      s.number("approach_s", w.approach_s, 0.0, 3600.0);
      s.boolean("table_registers", w.table_registers);
      if (!w.checkpoints_file.empty() && wants(ProgramKind::kSideWall)) {
        const std::string path = resolve(base_dir, w.checkpoints_file);
        try {
          w.plan = formats::checkpoints::load_checkpoints_file(path, std::nullopt).plan;
        } catch (const std::exception& e) {
          s.error("checkpoints_file", e.what());
        }
        w.checkpoints_file = path;
      }
      s.finish();
    }
    {
      Reader t(p.table("touch"), "program.touch", diag);
      TouchConfig& tc = c.touch;
      t.integer("cycles", tc.cycles, 0, 10000);
      t.number("cycle_interval_s", tc.cycle_interval_s, 0.0, 1e6);
      t.vec3("reference_center_mm", tc.reference_center_mm, -1e5, 1e5);
      t.number("reference_radius_mm", tc.reference_radius_mm, 0.0, 1e4);
      t.number("reference_axial_radius_mm", tc.reference_axial_radius_mm, 0.0, 1e4);
      t.vec3("body_center_mm", tc.body_center_mm, -1e5, 1e5);
      t.number("body_radius_mm", tc.body_radius_mm, 0.0, 1e4);
      t.number("body_axial_radius_mm", tc.body_axial_radius_mm, 0.0, 1e4);
      t.number("touch_time_s", tc.touch_time_s, 0.001, 3600.0);
      t.integer("touches_per_axis", tc.touches_per_axis, 1, 8);
      t.choice("touch_positions", tc.program_coordinates,
               {std::pair<std::string_view, bool>{"program", true}, {"machine", false}});
      t.vec3("axis_error_um", tc.axis_error_um, -1000.0, 1000.0);
      t.number("x_axial_error_um", tc.x_axial_error_um, -1000.0, 1000.0);
      t.number("reference_pretravel_um", tc.reference_pretravel_um, -100.0, 100.0);
      t.number("reference_axial_pretravel_um", tc.reference_axial_pretravel_um, -100.0, 100.0);
      t.number("blank_radius_mm", tc.blank_radius_mm, 0.1, 1000.0);
      t.number("grind_depth_mm", tc.grind_depth_mm, 0.001, 10.0);
      t.number("chord_noise_um", tc.chord_noise_um, 0.0, 100.0);
      t.number("grind_time_s", tc.grind_time_s, 0.1, 86400.0);
      t.string("facet_export_path", tc.facet_export_path);
      t.integer("request_register", tc.request_register, -1, 65535);
      t.choice("warm_up_from", tc.warm_up_after_nominals,
               {std::pair<std::string_view, bool>{"start", false}, {"nominals", true}});
      t.number("give_up_s", tc.give_up_s, 1.0, 1e7);
      if (!tc.facet_export_path.empty()) {
        tc.facet_export_path = resolve(base_dir, tc.facet_export_path);
      }
      t.finish();
    }
    {
      Reader g(p.table("roll"), "program.roll", diag);
      RollConfig& rc = c.roll;
      std::string profile;
      g.string("trajectory_file", rc.trajectory_file);
      g.string("profile_file", profile);
      g.number("feed_mm_per_min", rc.feed_mm_per_min, 1.0, 1e6);
      g.number("wheel_width_mm", rc.wheel_width_mm, 0.0, 2000.0);
      g.number("wheel_height_mm", rc.wheel_height_mm, 0.0, 100.0);
      g.integer("passes", rc.passes, 1, 1000);
      if (!rc.trajectory_file.empty() && wants(ProgramKind::kRoll)) {
        rc.trajectory_file = resolve(base_dir, rc.trajectory_file);
        if (profile.empty()) {
          g.error("profile_file", "the roll program needs the target profile (z_mm,u_mm)");
        } else {
          (void)read_data(diag, [&] {
            auto t = read_csv_columns(rc.trajectory_file, {"z_mm", "u_mm"});
            const std::string profile_path = resolve(base_dir, profile);
            auto p2 = read_csv_columns(profile_path, {"z_mm", "u_mm"});
            for (const auto& [zs, path] :
                 {std::pair{&t[0], rc.trajectory_file}, std::pair{&p2[0], profile_path}}) {
              for (std::size_t i = 1; i < zs->size(); ++i) {
                if (!((*zs)[i] > (*zs)[i - 1])) {
                  data_error(path, 0,
                             "z_mm must increase strictly (row " + std::to_string(i + 2) + ")");
                }
              }
            }
            rc.z_mm = std::move(t[0]);
            rc.u_mm = std::move(t[1]);
            rc.target_z_mm = std::move(p2[0]);
            rc.target_u_mm = std::move(p2[1]);
          });
        }
      }
      g.finish();
    }
    p.finish();
  }
  top.finish();
  if (!diag.ok()) {
    // A value from --set carries "--set" as its file: its line and column say nothing.
    Diagnostics named;
    for (formats::Diagnostic d : diag.items()) {
      if (d.where.file == "--set") {
        d.where.line = 0;
        d.where.column = 0;
      }
      named.error(std::move(d.where), std::move(d.message));
    }
    throw formats::DiagnosticsError(std::move(named), file);
  }
  return c;
}

SimConfig load_sim_config(const std::string& path, const std::vector<std::string>& overrides,
                          std::optional<ProgramKind> program) {
  const std::optional<std::string> text = read_text(path);
  if (!text) {
    data_error(path, 0, "cannot read the file");
  }
  return parse_sim_config(*text, path, fs::path(path).parent_path().string(), overrides, true,
                          program);
}

}  // namespace nccomp::sim::ncsim
