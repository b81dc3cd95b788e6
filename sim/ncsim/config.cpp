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
#include "formats/toml/guard.hpp"

namespace nccomp::sim::ncsim {
namespace {

namespace fs = std::filesystem;

std::string where(const std::string& file, const toml::source_region& r) {
  // A value from --set carries its own source name: say so rather than point into the file.
  if (r.path && *r.path == "--set") {
    return "--set";
  }
  return file + ":" + std::to_string(r.begin.line) + ":" + std::to_string(r.begin.column);
}

/// One TOML table being read: typed getters with range checks, unknown keys refused at the end.
class Reader {
 public:
  Reader(const toml::table* t, std::string path, const std::string& file)
      : t_(t), path_(std::move(path)), file_(file) {}

  [[noreturn]] void fail(std::string_view key, const std::string& msg) const {
    const toml::node* n = t_ != nullptr ? t_->get(key) : nullptr;
    const std::string pos = n != nullptr    ? where(file_, n->source())
                            : t_ != nullptr ? where(file_, t_->source())
                                            : file_;
    throw ConfigError(pos + ": " + key_path(key) + ": " + msg);
  }
  std::string key_path(std::string_view key) const {
    return path_.empty() ? std::string(key) : path_ + "." + std::string(key);
  }

  void number(std::string_view key, double& out, double lo, double hi) {
    const toml::node* n = take(key);
    if (n == nullptr) {
      return;
    }
    std::optional<double> v = n->value<double>();
    if (!v || !n->is_number()) {
      fail(key, "must be a number");
    }
    if (!std::isfinite(*v) || *v < lo || *v > hi) {
      std::ostringstream s;
      s << "must be in " << lo << " .. " << hi << ", got " << *v;
      fail(key, s.str());
    }
    out = *v;
  }
  void integer(std::string_view key, std::int32_t& out, std::int64_t lo, std::int64_t hi) {
    const toml::node* n = take(key);
    if (n == nullptr) {
      return;
    }
    if (!n->is_integer()) {
      fail(key, "must be an integer");
    }
    const std::int64_t v = *n->value<std::int64_t>();
    if (v < lo || v > hi) {
      fail(key, "must be in " + std::to_string(lo) + " .. " + std::to_string(hi) + ", got " +
                    std::to_string(v));
    }
    out = static_cast<std::int32_t>(v);
  }
  void boolean(std::string_view key, bool& out) {
    const toml::node* n = take(key);
    if (n == nullptr) {
      return;
    }
    if (!n->is_boolean()) {
      fail(key, "must be true or false");
    }
    out = *n->value<bool>();
  }
  void string(std::string_view key, std::string& out) {
    const toml::node* n = take(key);
    if (n == nullptr) {
      return;
    }
    if (!n->is_string()) {
      fail(key, "must be a string");
    }
    out = *n->value<std::string>();
  }
  void vec3(std::string_view key, Vec3& out, double lo, double hi) {
    const toml::node* n = take(key);
    if (n == nullptr) {
      return;
    }
    const toml::array* a = n->as_array();
    if (a == nullptr || a->size() != 3) {
      fail(key, "must be an array of 3 numbers [x, y, z]");
    }
    for (std::size_t i = 0; i < 3; ++i) {
      const auto v = (*a)[i].value<double>();
      if (!v || !std::isfinite(*v) || *v < lo || *v > hi) {
        fail(key, "element " + std::to_string(i) + " must be a number in range");
      }
      out[i] = *v;
    }
  }
  void int_list(std::string_view key, std::vector<std::int32_t>& out) {
    const toml::node* n = take(key);
    if (n == nullptr) {
      return;
    }
    const toml::array* a = n->as_array();
    if (a == nullptr) {
      fail(key, "must be an array of integers");
    }
    out.clear();
    for (const auto& e : *a) {
      const auto v = e.value<std::int64_t>();
      if (!e.is_integer() || *v < 0 || *v > 65535) {
        fail(key, "elements must be register indices 0 .. 65535");
      }
      out.push_back(static_cast<std::int32_t>(*v));
    }
  }
  void string_list(std::string_view key, std::vector<std::string>& out) {
    const toml::node* n = take(key);
    if (n == nullptr) {
      return;
    }
    const toml::array* a = n->as_array();
    if (a == nullptr) {
      fail(key, "must be an array of strings");
    }
    out.clear();
    for (const auto& e : *a) {
      if (!e.is_string() || e.value<std::string>()->empty()) {
        fail(key, "elements must be non-empty strings (file names)");
      }
      out.push_back(*e.value<std::string>());
    }
  }
  template <typename E>
  void choice(std::string_view key, E& out,
              std::initializer_list<std::pair<std::string_view, E>> options) {
    std::string s;
    const bool had = t_ != nullptr && t_->contains(key);
    string(key, s);
    if (!had) {
      return;
    }
    std::string names;
    for (const auto& [name, value] : options) {
      if (s == name) {
        out = value;
        return;
      }
      // Appended piecewise: GCC 12 warns (-Wrestrict, a false positive) on "\"" + string.
      if (!names.empty()) {
        names.append(", ");
      }
      names.append(1, '"').append(name).append(1, '"');
    }
    fail(key, "must be one of " + names + ", got \"" + s + "\"");
  }
  /// A sub-table (nullptr if absent); refuses a non-table.
  const toml::table* table(std::string_view key) {
    const toml::node* n = take(key);
    if (n == nullptr) {
      return nullptr;
    }
    if (!n->is_table()) {
      fail(key, "must be a table");
    }
    return n->as_table();
  }
  void finish() const {
    if (t_ == nullptr) {
      return;
    }
    for (const auto& [k, v] : *t_) {
      if (used_.count(std::string(k.str())) == 0) {
        throw ConfigError(where(file_, v.source()) + ": " + key_path(k.str()) + ": unknown key");
      }
    }
  }
  const std::string& path() const { return path_; }

 private:
  const toml::node* take(std::string_view key) {
    used_.insert(std::string(key));
    return t_ != nullptr ? t_->get(key) : nullptr;
  }
  const toml::table* t_;
  std::string path_;
  const std::string& file_;
  std::set<std::string> used_;
};

std::string resolve(const std::string& base_dir, const std::string& p) {
  if (p.empty() || fs::path(p).is_absolute()) {
    return p;
  }
  return (fs::path(base_dir) / p).lexically_normal().string();
}

std::string read_text(const std::string& path, const std::string& what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw ConfigError(what + ": cannot read " + path);
  }
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void apply_override(toml::table& root, const std::string& spec) {
  const auto eq = spec.find('=');
  if (eq == std::string::npos || eq == 0) {
    throw ConfigError("--set " + spec + ": expected KEY=VALUE");
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
      throw ConfigError("--set " + spec + ": empty key part");
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
      throw ConfigError("--set " + spec + ": " + parts[i] + " is not a table");
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
      throw ConfigError("--set " + spec + ": the value is neither TOML nor a plain string");
    }
  }
}

void read_effects(const toml::table* eff, const std::string& file, const std::string& base,
                  bool read_files, EffectsConfig& e) {
  Reader r(eff, "effects", file);
  {
    Reader w(r.table("wear"), "effects.wear", file);
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
        w.fail("phm_file", "curve = \"phm2010\" needs phm_file (c4_wear.csv or c6_wear.csv)");
      }
      if (column != "max" && column != "flute_1" && column != "flute_2" && column != "flute_3") {
        w.fail("phm_column", "must be \"flute_1\", \"flute_2\", \"flute_3\" or \"max\"");
      }
      const std::string path = resolve(base, phm_file);
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
          throw ConfigError(path + ": cut numbers must increase");
        }
        curve.x.push_back(x);
        curve.y.push_back((vb - vb0) * radial_per_vb);
      }
      if (curve.x.size() < 2) {
        throw ConfigError(path + ": fewer than 2 cuts from start_cut on");
      }
      c.table = std::move(curve);
      c.table_source = path + " (" + column + ", from cut " + std::to_string(start_cut) + ", " +
                       std::to_string(path_per_cut_mm) + " mm per cut, radial = VB x " +
                       std::to_string(radial_per_vb) + ")";
    }
    w.finish();
  }
  {
    Reader p(r.table("pushoff"), "effects.pushoff", file);
    PushoffConfig& c = e.pushoff;
    p.boolean("enabled", c.enabled);
    p.number("base_um", c.base_um, 0.0, 1e3);
    p.number("wear_gain_per_um", c.wear_gain_per_um, 0.0, 10.0);
    p.number("clamp_z_mm", c.clamp_z_mm, -1e4, 1e4);
    p.number("reference_lever_mm", c.reference_lever_mm, 1e-3, 1e4);
    p.finish();
  }
  {
    Reader h(r.table("hardness"), "effects.hardness", file);
    h.boolean("enabled", e.hardness.enabled);
    h.number("amplitude", e.hardness.amplitude, 0.0, 0.9);
    h.number("wavelength_mm", e.hardness.wavelength_mm, 1.0, 1e5);
    h.boolean("per_part", e.hardness.per_part);
    h.finish();
  }
  {
    Reader t(r.table("thermal"), "effects.thermal", file);
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
        t.fail("replay_file", "mode = \"replay\" needs replay_file (FL_THERMAL data.csv)");
      }
      const std::string path = resolve(base, replay_file);
      std::vector<std::string> names{"時間"};
      for (const auto& ch : channels) {
        if (!ch.empty()) {
          names.push_back(ch);
        }
      }
      names.push_back(temps[0]);
      names.push_back(temps[1]);
      const auto cols = read_csv_columns(path, names);
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
      for (std::size_t i = 1; i < cols[0].size(); ++i) {
        if (!(cols[0][i] > cols[0][i - 1])) {
          throw ConfigError(path + ":" + std::to_string(i + 2) + ": time must increase");
        }
      }
      c.replay_source = path;
    }
    t.finish();
  }
  {
    Reader p(r.table("pitch"), "effects.pitch", file);
    p.boolean("enabled", e.pitch.enabled);
    p.vec3("amplitude_um", e.pitch.amplitude_um, -100.0, 100.0);
    p.number("pitch_mm", e.pitch.pitch_mm, 0.1, 1e3);
    p.vec3("slope_um_per_m", e.pitch.slope_um_per_m, -1e3, 1e3);
    p.finish();
  }
  for (auto [name, cfg] :
       {std::pair{"probe_noise", &e.probe_noise}, std::pair{"laser_noise", &e.laser_noise}}) {
    Reader n(r.table(name), std::string("effects.") + name, file);
    n.boolean("enabled", cfg->enabled);
    n.number("sigma_um", cfg->sigma_um, 0.0, 1e3);
    n.finish();
  }
  {
    Reader b(r.table("broken_tool"), "effects.broken_tool", file);
    b.boolean("enabled", e.broken_tool.enabled);
    b.number("at_path_mm", e.broken_tool.at_path_mm, 0.0, 1e9);
    b.number("wear_jump_um", e.broken_tool.wear_jump_um, 0.0, 1e5);
    b.boolean("report_flag", e.broken_tool.report_flag);
    b.finish();
  }
  {
    Reader o(r.table("probe_outlier"), "effects.probe_outlier", file);
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
    throw ConfigError("cannot read " + path);
  }
  std::string line;
  std::size_t line_no = 0;
  // Leading '#' comment lines and blank lines (the profile / trajectory CSVs of
  // docs/grinding.md allow them) come before the header.
  for (;;) {
    if (!std::getline(in, line)) {
      throw ConfigError(path + ":" + std::to_string(line_no + 1) +
                        ": empty file, expected a header");
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
      throw ConfigError(path + ":" + std::to_string(line_no) + ": no column \"" + want +
                        "\" in the header");
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
        throw ConfigError(path + ":" + std::to_string(line_no) + ": missing column \"" +
                          columns[k] + "\"");
      }
      const std::string cell = trim(cells[idx[k]]);
      char* end = nullptr;
      const double v = std::strtod(cell.c_str(), &end);
      if (cell.empty() || *end != '\0' || !std::isfinite(v)) {
        throw ConfigError(path + ":" + std::to_string(line_no) + ": column \"" + columns[k] +
                          "\": not a finite number: \"" + cell + "\"");
      }
      out[k].push_back(v);
    }
  }
  if (out.front().empty()) {
    throw ConfigError(path + ": no data rows");
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
    throw ConfigError(where(file, e.source()) + ": " + std::string(e.description()));
  }
  for (const auto& o : overrides) {
    apply_override(root, o);
  }
  SimConfig c;
  c.file = file;
  Reader top(&root, "", file);
  {
    Reader n(top.table("ncsim"), "ncsim", file);
    n.string("bus_map", c.bus_map_file);
    if (c.bus_map_file.empty()) {
      n.fail("bus_map", "required: the daemon's register map (reference-nc-modbus.toml)");
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
    n.finish();
  }
  {
    Reader n(top.table("nc"), "nc", file);
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
  read_effects(top.table("effects"), file, base_dir, read_files, c.effects);
  {
    Reader p(top.table("program"), "program", file);
    {
      Reader m(p.table("mould_face"), "program.mould_face", file);
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
      m.finish();
    }
    {
      Reader s(p.table("side_wall"), "program.side_wall", file);
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
          throw ConfigError(where(file, root.source()) +
                            ": program.side_wall.checkpoints_file: " + e.what());
        }
        w.checkpoints_file = path;
      }
      s.finish();
    }
    {
      Reader t(p.table("touch"), "program.touch", file);
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
      Reader g(p.table("roll"), "program.roll", file);
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
        auto t = read_csv_columns(rc.trajectory_file, {"z_mm", "u_mm"});
        rc.z_mm = std::move(t[0]);
        rc.u_mm = std::move(t[1]);
        if (profile.empty()) {
          g.fail("profile_file", "the roll program needs the target profile (z_mm,u_mm)");
        }
        auto p2 = read_csv_columns(resolve(base_dir, profile), {"z_mm", "u_mm"});
        rc.target_z_mm = std::move(p2[0]);
        rc.target_u_mm = std::move(p2[1]);
        for (const auto* zs : {&rc.z_mm, &rc.target_z_mm}) {
          for (std::size_t i = 1; i < zs->size(); ++i) {
            if (!((*zs)[i] > (*zs)[i - 1])) {
              g.fail("trajectory_file",
                     "z_mm must increase strictly (row " + std::to_string(i + 2) + ")");
            }
          }
        }
      }
      g.finish();
    }
    p.finish();
  }
  top.finish();
  c.bus_map_file = resolve(base_dir, c.bus_map_file);
  if (read_files) {
    c.bus_map_text = read_text(c.bus_map_file, "ncsim.bus_map");
  }
  for (auto& f : c.bus_map_extra_files) {
    f = resolve(base_dir, f);
    if (read_files) {
      c.bus_map_extra_texts.push_back(read_text(f, "ncsim.bus_map_extra"));
    }
  }
  if (!c.can_bus_map_file.empty()) {
    c.can_bus_map_file = resolve(base_dir, c.can_bus_map_file);
    if (read_files) {
      c.can_bus_map_text = read_text(c.can_bus_map_file, "ncsim.can_bus_map");
    }
  }
  for (auto& f : c.can_bus_map_extra_files) {
    f = resolve(base_dir, f);
    if (read_files) {
      c.can_bus_map_extra_texts.push_back(read_text(f, "ncsim.can_bus_map_extra"));
    }
  }
  return c;
}

SimConfig load_sim_config(const std::string& path, const std::vector<std::string>& overrides,
                          std::optional<ProgramKind> program) {
  const std::string text = read_text(path, "ncsim config");
  return parse_sim_config(text, path, fs::path(path).parent_path().string(), overrides, true,
                          program);
}

}  // namespace nccomp::sim::ncsim
