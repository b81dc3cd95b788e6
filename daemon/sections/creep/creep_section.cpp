#include "daemon/sections/creep/creep_section.hpp"

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <utility>
#include <vector>

#include "core/creep/toolpath.hpp"
#include "daemon/config/builtin_sections.hpp"

namespace nccomp::daemon::sections {

namespace {

namespace fs = std::filesystem;
namespace cc = core::creep;
using formats::Diagnostics;
using formats::TableReader;
using formats::Where;

// Largest accepted toolpath file: kMaxToolpathRows rows of a generous 64 bytes each. A bigger
// file is refused before it is read (and /dev/zero or a FIFO is not a regular file).
constexpr std::uintmax_t kMaxToolpathBytes = std::uintmax_t{cc::kMaxToolpathRows} * 64U;
constexpr double kBig = 1e9;  // upper bound of plain magnitudes (µm, mm, s): catches typos only

/// A number > 0 (TableReader's ranges are inclusive).
double positive(TableReader& r, std::string_view key, double def, double max = kBig) {
  const double v = r.number(key, def, 0.0, max);
  if (!(v > 0.0)) {
    r.diagnostics().error(r.where(key), "must be > 0");
    return def;
  }
  return v;
}

double sign(TableReader& r, std::string_view key, double def) {
  const double v = r.number(key, def, -1.0, 1.0);
  if (std::fabs(std::fabs(v) - 1.0) > 1e-12) {
    r.diagnostics().error(r.where(key), "must be +1 or -1");
    return def;
  }
  return v;
}

template <typename E>
E pick(TableReader& r, std::string_view key, const std::vector<std::pair<std::string, E>>& map,
       E def) {
  std::vector<std::string> names;
  std::string def_name;
  for (const auto& [n, e] : map) {
    names.push_back(n);
    if (e == def) def_name = n;
  }
  const std::string v = r.choice(key, def_name, names);
  for (const auto& [n, e] : map) {
    if (n == v) return e;
  }
  return def;
}

/// Reads the toolpath file; errors are reported at the key.
cc::ToolpathTable read_toolpath(const std::string& path, const Where& where, Diagnostics& diag) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) {
    diag.error(where, "cannot read toolpath file '" + path + "': not a regular file");
    return {};
  }
  const auto size = fs::file_size(path, ec);
  if (ec || size > kMaxToolpathBytes) {
    diag.error(where, "toolpath file '" + path + "' is larger than " +
                          std::to_string(kMaxToolpathBytes) + " bytes");
    return {};
  }
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  if (!in) {
    diag.error(where, "cannot read toolpath file '" + path + "'");
    return {};
  }
  try {
    return cc::parse_toolpath(text.str(), path);
  } catch (const std::invalid_argument& e) {
    diag.error(where, e.what());
    return {};
  }
}

void parse_edge(TableReader& r, cc::CreepConfig& c, const toml::node& creep_node, CreepSection& s) {
  auto& e = c.edge;
  e.tool_shape = pick<cc::ToolShape>(r, "tool_shape",
                                     {{"tip", cc::ToolShape::kTip},
                                      {"ball", cc::ToolShape::kBall},
                                      {"bull_nose", cc::ToolShape::kBullNose}},
                                     e.tool_shape);
  e.edge_points = static_cast<std::size_t>(
      r.integer("edge_points", 1, 1, static_cast<std::int64_t>(core::kMaxEdgePoints)));
  e.normal_source = pick<cc::NormalSource>(r, "normal_source",
                                           {{"axis_sample", cc::NormalSource::kAxisSample},
                                            {"toolpath", cc::NormalSource::kToolpath},
                                            {"none", cc::NormalSource::kNone}},
                                           e.normal_source);
  const std::string file = r.string("toolpath_file", "");
  if (!file.empty()) {
    fs::path p(file);
    if (p.is_relative()) {
      // Relative to the file that holds [creep] (an included file keeps its own directory).
      const auto& src = creep_node.source();
      const fs::path dir = src.path ? fs::path(*src.path).parent_path() : fs::path();
      p = dir / p;
    }
    s.toolpath_file = p.lexically_normal().string();
    c.toolpath = read_toolpath(s.toolpath_file, r.where("toolpath_file"), r.diagnostics());
    if (e.normal_source == cc::NormalSource::kToolpath && !c.toolpath.rows.empty() &&
        !c.toolpath.has_normals) {
      r.diagnostics().error(r.where("normal_source"),
                            "\"toolpath\" needs normals (nx, ny, nz) in creep.edge.toolpath_file");
    }
  } else if (e.normal_source == cc::NormalSource::kToolpath) {
    r.diagnostics().error(r.where("normal_source"), "\"toolpath\" needs creep.edge.toolpath_file");
  }
  if (r.node().get("tool_axis") != nullptr) {
    const auto axis = r.number_list("tool_axis", -1.0, 1.0);
    if (axis.size() != 3) {
      r.diagnostics().error(r.where("tool_axis"), "must be 3 numbers [x, y, z]");
    } else {
      e.tool_axis = {axis[0], axis[1], axis[2]};
    }
  }
  e.fallback_channel = pick<cc::Channel>(r, "fallback_channel",
                                         {{"x", cc::Channel::kX},
                                          {"y", cc::Channel::kY},
                                          {"z", cc::Channel::kZ},
                                          {"radius", cc::Channel::kRadius},
                                          {"length", cc::Channel::kLength}},
                                         e.fallback_channel);
  e.fallback_sign = sign(r, "fallback_sign", e.fallback_sign);
  e.material_side = pick<cc::MaterialSide>(r, "material_side",
                                           {{"none", cc::MaterialSide::kNone},
                                            {"left", cc::MaterialSide::kLeft},
                                            {"right", cc::MaterialSide::kRight}},
                                           e.material_side);
}

void parse_output(TableReader& r, cc::CreepConfig& c, cc::CreepRegisterNames& names) {
  auto& o = c.output;
  o.mode = pick<cc::OutputMode>(
      r, "mode",
      {{"axes", cc::OutputMode::kAxes}, {"tool_registers", cc::OutputMode::kToolRegisters}},
      o.mode);
  static constexpr std::array<const char*, cc::kChannelCount> kKeys{
      "x_register", "y_register", "z_register", "radius_register", "length_register"};
  for (std::size_t i = 0; i < cc::kChannelCount; ++i) {
    names.channel[i] = r.string(kKeys[i], "");
  }
  o.tool_register_sign = sign(r, "tool_register_sign", o.tool_register_sign);
  names.warning = r.string("warning_register", "");
  names.alarm = r.string("alarm_register", "");
  names.measurement_due = r.string("measurement_due_register", "");
  names.tool_change = r.string("tool_change_register", "");
  names.restart_path = r.string("restart_path_register", "");
  o.write_resolution_um = positive(r, "write_resolution_um", o.write_resolution_um, 1e6);
  o.refresh_interval_s = r.number("refresh_interval_s", o.refresh_interval_s, 0.0, 86400.0);
  o.request_rearm_s = r.number("request_rearm_s", o.request_rearm_s, 0.0, 60.0);
}

void parse_limiter(TableReader& r, core::LimiterConfig& l) {
  l.max_abs_um = positive(r, "max_abs_um", l.max_abs_um, 1e6);
  l.max_step_um = positive(r, "max_step_um", l.max_step_um, 1e6);
  l.max_rate_um_per_s = positive(r, "max_rate_um_per_s", l.max_rate_um_per_s, 1e6);
}

void parse_interval(TableReader& r, cc::IntervalConfig& iv, bool have_toolpath) {
  iv.basis = pick<cc::IntervalBasis>(r, "basis",
                                     {{"off", cc::IntervalBasis::kOff},
                                      {"path", cc::IntervalBasis::kPath},
                                      {"time", cc::IntervalBasis::kTime},
                                      {"adaptive", cc::IntervalBasis::kAdaptive},
                                      {"material", cc::IntervalBasis::kMaterial},
                                      {"uncertainty", cc::IntervalBasis::kUncertainty}},
                                     iv.basis);
  iv.interval_mm = positive(r, "interval_mm", iv.interval_mm);
  iv.interval_s = positive(r, "interval_s", iv.interval_s);
  iv.target_increment_um = positive(r, "target_increment_um", iv.target_increment_um);
  iv.min_interval_mm = positive(r, "min_interval_mm", iv.min_interval_mm);
  iv.max_interval_mm = positive(r, "max_interval_mm", iv.max_interval_mm);
  iv.removal_mm3_per_mm = positive(r, "removal_mm3_per_mm", iv.removal_mm3_per_mm);
  iv.removal_source = pick<cc::RemovalSource>(
      r, "removal_source",
      {{"constant", cc::RemovalSource::kConstant}, {"toolpath", cc::RemovalSource::kToolpath}},
      iv.removal_source);
  if (iv.removal_source == cc::RemovalSource::kToolpath && !have_toolpath) {
    r.diagnostics().error(r.where("removal_source"),
                          "\"toolpath\" needs creep.edge.toolpath_file with a removal_mm2 column");
  }
  iv.interval_mm3 = positive(r, "interval_mm3", iv.interval_mm3);
  iv.max_sigma_um = positive(r, "max_sigma_um", iv.max_sigma_um, 1e3);
  if (iv.max_interval_mm < iv.min_interval_mm) {
    r.diagnostics().error(r.where("max_interval_mm"), "must be >= min_interval_mm");
  }
}

void parse_tool_life(TableReader& r, cc::ToolLifeConfig& t) {
  t.wear_limit_um = r.number("wear_limit_um", t.wear_limit_um, 0.0, 1e6);
  t.excessive_increment_um = r.number("excessive_increment_um", t.excessive_increment_um, 0.0, 1e6);
  t.on_excessive = pick<cc::ExcessivePolicy>(
      r, "on_excessive",
      {{"stop", cc::ExcessivePolicy::kStop}, {"sister", cc::ExcessivePolicy::kSister}},
      t.on_excessive);
  t.implausible_factor = r.number("implausible_factor", t.implausible_factor, 1.0, 1e6);
  t.min_expected_increment_um =
      positive(r, "min_expected_increment_um", t.min_expected_increment_um, 1e6);
  t.noise_um = r.number("noise_um", t.noise_um, 0.0, 1e6);
}

void parse_predict(TableReader& r, cc::PredictConfig& p) {
  p.enabled = r.boolean("enabled", p.enabled);
  p.window = static_cast<std::size_t>(
      r.integer("window", 5, 2, static_cast<std::int64_t>(cc::kMaxRateWindow)));
  p.max_um = positive(r, "max_um", p.max_um, 1e6);
}

void parse_estimator(TableReader& r, cc::EstimatorConfig& e) {
  e.enabled = r.boolean("enabled", e.enabled);
  e.measurement_sigma_um = positive(r, "measurement_sigma_um", e.measurement_sigma_um, 1e3);
  e.wear_noise_um_per_sqrt_m =
      r.number("wear_noise_um_per_sqrt_m", e.wear_noise_um_per_sqrt_m, 0.0, 1e3);
  e.rate_noise_um_per_mm_per_sqrt_m =
      r.number("rate_noise_um_per_mm_per_sqrt_m", e.rate_noise_um_per_mm_per_sqrt_m, 0.0, 1e3);
  e.initial_rate_sigma_um_per_mm =
      positive(r, "initial_rate_sigma_um_per_mm", e.initial_rate_sigma_um_per_mm, 1e3);
  // 0 < k < 2 is refused by core::creep::validate() (it would refuse good measurements).
  e.gate_sigmas = r.number("gate_sigmas", e.gate_sigmas, 0.0, 1e3);
  e.learn_rate_noise = r.boolean("learn_rate_noise", e.learn_rate_noise);
  e.family_min_tools = static_cast<std::size_t>(
      r.integer("family_min_tools", static_cast<std::int64_t>(e.family_min_tools), 1,
                static_cast<std::int64_t>(cc::kMaxFamilyMinTools)));
  e.learn_rate_prior = r.boolean("learn_rate_prior", e.learn_rate_prior);
  e.family_prior_path_mm = positive(r, "family_prior_path_mm", e.family_prior_path_mm, 1e7);
  e.adapt_rate_noise = r.boolean("adapt_rate_noise", e.adapt_rate_noise);
  e.adapt_window_measurements =
      r.number("adapt_window_measurements", e.adapt_window_measurements, 1.0, 1000.0);
  e.min_rate_noise_um_per_mm_per_sqrt_m = positive(r, "min_rate_noise_um_per_mm_per_sqrt_m",
                                                   e.min_rate_noise_um_per_mm_per_sqrt_m, 1e3);
  e.max_rate_noise_um_per_mm_per_sqrt_m = positive(r, "max_rate_noise_um_per_mm_per_sqrt_m",
                                                   e.max_rate_noise_um_per_mm_per_sqrt_m, 1e3);
}

void parse_entry(TableReader& r, cc::EntryConfig& e) {
  e.sister_offset_um = r.number("sister_offset_um", e.sister_offset_um, 0.0, 1e6);
  e.sister_length_mm = positive(r, "sister_length_mm", e.sister_length_mm);
  e.sister_restart_back_mm =
      r.number("sister_restart_back_mm", e.sister_restart_back_mm, 0.0, kBig);
  e.retract_um = r.number("retract_um", e.retract_um, 0.0, 1e6);
  e.refeed_length_mm = positive(r, "refeed_length_mm", e.refeed_length_mm);
}

void parse_deflection(const toml::array& arr, cc::CreepConfig& c, Diagnostics& diag) {
  if (arr.size() > 64) {
    diag.error(&arr, "creep.deflection", "more than 64 tables");
    return;
  }
  for (std::size_t i = 0; i < arr.size(); ++i) {
    TableReader r(*arr.get(i)->as_table(), "creep.deflection[" + std::to_string(i) + "]", diag);
    cc::DeflectionTable d;
    d.tool = static_cast<std::int32_t>(r.integer("tool", std::nullopt, 0, 65535));
    d.wear_um = r.number_list("wear_um", 0.0, 1e6);
    d.normal_um = r.number_list("normal_um", -1e6, 1e6);
    d.lateral_um = r.number_list("lateral_um", -1e6, 1e6);
    for (const char* k : {"wear_um", "normal_um", "lateral_um"}) {
      if (r.node().get(k) == nullptr) {
        diag.error(r.where(k), "missing required key");
      }
    }
    c.deflection.push_back(std::move(d));
  }
}

void parse_transitions(const toml::array& arr, cc::CreepConfig& c, Diagnostics& diag) {
  for (std::size_t i = 0; i < arr.size(); ++i) {
    TableReader r(*arr.get(i)->as_table(), "creep.transition[" + std::to_string(i) + "]", diag);
    cc::Transition t;
    t.tool = static_cast<std::int32_t>(r.integer("tool", std::nullopt, 1, 65535));
    t.start_path_mm = r.number("start_path_mm", std::nullopt, -kBig, kBig);
    t.end_path_mm = r.number("end_path_mm", std::nullopt, -kBig, kBig);
    t.in_offset_um = r.number("in_offset_um", 0.0, 0.0, 1e6);
    t.in_length_mm = r.number("in_length_mm", 0.0, 0.0, kBig);
    t.out_offset_um = r.number("out_offset_um", 0.0, 0.0, 1e6);
    t.out_length_mm = r.number("out_length_mm", 0.0, 0.0, kBig);
    c.transitions.push_back(t);
  }
}

}  // namespace

std::unique_ptr<CreepSection> parse_creep_section(const toml::node& node, Diagnostics& diag) {
  auto s = std::make_unique<CreepSection>();
  s->where = formats::where_of(&node, "creep");
  const auto* table = node.as_table();
  if (table == nullptr) {
    diag.error(&node, "creep", "must be a table ([creep])");
    return s;
  }
  formats::record_positions(node, "creep", s->key_positions);
  const std::size_t errors_before = diag.items().size();
  auto& c = s->module.creep;
  {
    TableReader r(*table, "creep", diag);
    s->enabled = r.boolean("enabled", true);
    c.creep_basis = pick<cc::CreepBasis>(r, "creep_basis",
                                         {{"path", cc::CreepBasis::kPath},
                                          {"time", cc::CreepBasis::kTime},
                                          {"rate_time", cc::CreepBasis::kRateTime},
                                          {"rate_path", cc::CreepBasis::kRatePath}},
                                         c.creep_basis);
    c.creep_length_mm = positive(r, "creep_length_mm", c.creep_length_mm);
    c.creep_time_s = positive(r, "creep_time_s", c.creep_time_s);
    c.creep_rate_um_per_min = positive(r, "creep_rate_um_per_min", c.creep_rate_um_per_min);
    c.creep_rate_um_per_mm = positive(r, "creep_rate_um_per_mm", c.creep_rate_um_per_mm);
    c.profile = pick<core::ProfileShape>(r, "profile",
                                         {{"linear", core::ProfileShape::kLinear},
                                          {"cosine", core::ProfileShape::kCosine},
                                          {"smoothstep", core::ProfileShape::kSmoothstep},
                                          {"table", core::ProfileShape::kTable},
                                          {"step", core::ProfileShape::kStep}},
                                         c.profile);
    c.profile_table = r.number_list("profile_table", 0.0, 1.0);
    if (c.profile == core::ProfileShape::kTable && r.node().get("profile_table") == nullptr) {
      diag.error(r.where("profile"), "\"table\" needs creep.profile_table");
    }
    c.on_unfinished = pick<cc::UnfinishedPolicy>(r, "on_unfinished",
                                                 {{"superpose", cc::UnfinishedPolicy::kSuperpose},
                                                  {"warn", cc::UnfinishedPolicy::kWarn},
                                                  {"alarm", cc::UnfinishedPolicy::kAlarm}},
                                                 c.on_unfinished);
    c.max_creeps = static_cast<std::size_t>(
        r.integer("max_creeps", 4, 1, static_cast<std::int64_t>(cc::kMaxCreeps)));

    if (const auto* t = r.table("edge")) {
      TableReader q(*t, "creep.edge", diag);
      parse_edge(q, c, node, *s);
    }
    if (const auto* t = r.table("output")) {
      TableReader q(*t, "creep.output", diag);
      parse_output(q, c, s->module.registers);
    }
    if (const auto* t = r.table("limiter")) {
      TableReader q(*t, "creep.limiter", diag);
      parse_limiter(q, c.limiter);
    }
    if (const auto* t = r.table("interval")) {
      TableReader q(*t, "creep.interval", diag);
      parse_interval(q, c.interval, !s->toolpath_file.empty());
    }
    if (const auto* t = r.table("tool_life")) {
      TableReader q(*t, "creep.tool_life", diag);
      parse_tool_life(q, c.tool_life);
    }
    if (const auto* t = r.table("predict")) {
      TableReader q(*t, "creep.predict", diag);
      parse_predict(q, c.predict);
    }
    if (const auto* t = r.table("estimator")) {
      TableReader q(*t, "creep.estimator", diag);
      parse_estimator(q, c.estimator);
    }
    if (const auto* t = r.table("entry")) {
      TableReader q(*t, "creep.entry", diag);
      parse_entry(q, c.entry);
    }
    if (const auto* a = r.table_array("deflection")) {
      parse_deflection(*a, c, diag);
    }
    if (const auto* a = r.table_array("transition")) {
      parse_transitions(*a, c, diag);
    }
  }
  if (diag.items().size() != errors_before) {
    return s;  // the core's rules would only repeat what is already reported
  }
  // The cross-field rules of the core (mode vs. registers, table lengths, ...). Named registers
  // stand in as index 0 here; cross_check() resolves them against [[registers]].
  cc::CreepConfig probe = c;
  for (std::size_t i = 0; i < cc::kChannelCount; ++i) {
    if (!s->module.registers.channel[i].empty()) probe.output.channel_register[i] = 0;
  }
  try {
    cc::validate(probe);
  } catch (const core::ConfigInvalid& e) {
    formats::report(s->key_positions, s->where, e, diag);
  }
  return s;
}

const CreepSection* creep_section(const config::Config& config) {
  return config.find<CreepSection>("creep");
}

namespace {

class CreepParser final : public config::SectionParser {
 public:
  std::string_view name() const noexcept override { return "creep"; }
  std::unique_ptr<config::Section> parse(const toml::node& node, Diagnostics& diag) const override {
    return parse_creep_section(node, diag);
  }
  void cross_check(const config::Config& config, Diagnostics& diag) const override {
    const auto* s = creep_section(config);
    if (s == nullptr) return;
    std::vector<core::engine::RegisterSpec> specs;
    for (const auto& e : config::registers_section(config).registers) {
      specs.push_back(e.spec);
    }
    // The module's own attach() is the one judge of names, kinds and limits; each issue names
    // its key, mapped to the key's position in the file.
    // (On the heap: the module holds the memory of 8 tools, ~100 kB.)
    auto m = std::make_unique<cc::CreepModule>(s->module);
    try {
      m->attach(core::engine::RegisterTable(specs));
    } catch (const core::ConfigInvalid& e) {
      formats::report(s->key_positions, s->where, e, diag);
    } catch (const std::invalid_argument& e) {
      diag.error(s->where, e.what());  // not a key's fault (e.g. the limiter's own refusal)
    }
  }
  void add_modules(const config::Config& config,
                   std::vector<std::unique_ptr<core::engine::Module>>& modules) const override {
    const auto* s = creep_section(config);
    if (s != nullptr && s->enabled) {
      modules.push_back(std::make_unique<cc::CreepModule>(s->module));
    }
  }
};

}  // namespace

NCCOMP_REGISTER_CONFIG_SECTION(CreepParser)

}  // namespace nccomp::daemon::sections
