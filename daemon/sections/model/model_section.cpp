#include "daemon/sections/model/model_section.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <utility>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/sections/calibration/calibration_section.hpp"
#include "daemon/sections/model/context_section.hpp"
#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"

namespace nccomp::daemon::sections {

namespace {

namespace fs = std::filesystem;
namespace cm = core::model;
using formats::TableReader;

std::string fmt_alpha(double a) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", a);
  return buf;
}

/// The value of column c the entry fixes (kind, point, tool, angle_deg), NaN when the loop
/// gives it or the entry does not.
double entry_value(int c, const core::model::ModelApply& apply) {
  switch (static_cast<cm::Column>(c)) {
    case cm::Column::kKind:
      return apply.kind;
    case cm::Column::kPoint:
      return apply.point;
    case cm::Column::kTool:
      return apply.tool;
    case cm::Column::kAngle:
      return apply.angle_deg;
    default:
      return cm::kUnknown;
  }
}

/// A group key as the entry writes it: a kind by name, a number as it is.
std::string key_value(int c, double v) {
  if (c == static_cast<int>(cm::Column::kKind)) {
    for (const char* kind : {"tool_wear", "contour", "calib"}) {
      const auto i = static_cast<double>(formats::model_io::kind_from_name(kind));
      if (!(i < v) && !(v < i)) return kind;
    }
  }
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

/// "point = 0, 1, 2" (one group column) or "(kind = calib, point = 0), …" (two): the groups of
/// a per-group term, for the errors.
std::string group_list(const cm::Term& term, const std::vector<std::string>& extras) {
  constexpr std::size_t kShown = 16;
  const auto& per = term.spec.per;
  std::string out;
  const bool both = per[0] >= 0 && per[1] >= 0;
  for (std::size_t g = 0; g < term.groups.size() && g < kShown; ++g) {
    std::string key;
    for (std::size_t k = 0; k < 2; ++k) {
      if (per[k] < 0) continue;
      // One column: its name once, before the first value.
      if (both || g == 0) {
        key += (key.empty() ? "" : ", ") + cm::column_name(per[k], extras) + " = ";
      }
      key += key_value(per[k], term.groups[g][k]);
    }
    out += (out.empty() ? "" : ", ") + (both ? "(" + key + ")" : key);
  }
  if (term.groups.size() > kShown) {
    out += ", … (" + std::to_string(term.groups.size()) + " groups)";
  }
  return out;
}

/// Why a term cannot be evaluated in the loop as configured, or "" when it can. The loop knows
/// time_s, part, tool, temp_c, x/y/z and path_mm (the engine's machine context), kind / point /
/// tool / angle_deg when the [[model.apply]] entry fixes them, and extra columns mapped by
/// [[model.inputs]]. Position and path change within a part, so a term of them needs
/// update = "cycle". A per-group term contributes its group's coefficients, so the entry must
/// give the group columns the loop does not know (point), each as a value the model has a group
/// of.
std::string loop_context_problem(const cm::Term& term, bool each_cycle, const cm::Model& model,
                                 const std::vector<ModelInputConfig>& inputs,
                                 const core::model::ModelApply& apply) {
  const cm::TermSpec& spec = term.spec;
  const std::vector<std::string>& extras = model.extra_columns();
  // A term is fitted on rows of some kinds only (kind_mask) and evaluates to 0 for the others:
  // an entry of another kind would apply nothing, silently.
  if (apply.kind >= 0.0 && apply.kind < 8.0 &&
      (spec.kind_mask & (1U << static_cast<unsigned>(apply.kind))) == 0U) {
    std::string fitted;
    for (const char* k : {"tool_wear", "contour", "calib"}) {
      const auto i = static_cast<unsigned>(formats::model_io::kind_from_name(k));
      if ((spec.kind_mask & (1U << i)) != 0U) fitted += std::string(fitted.empty() ? "" : ", ") + k;
    }
    return "was fitted on " + fitted + " rows only and contributes nothing to kind = " +
           key_value(static_cast<int>(cm::Column::kKind), apply.kind) +
           ": give the entry the kind of the rows the term describes (kind = \"" +
           fitted.substr(0, fitted.find(',')) + "\")";
  }
  std::vector<int> cols;
  if (spec.form != cm::Form::kConstant) cols.push_back(spec.column);
  if (spec.form == cm::Form::kInteraction) cols.push_back(spec.column_b);
  for (const int c : spec.per) {
    if (c >= 0) cols.push_back(c);
  }
  if (spec.form == cm::Form::kWear) {
    // Proportional to the model's tool wear: the columns of the wear terms count too (kind and
    // point are fixed by the form).
    for (const cm::TermSpec& w : model.specs()) {
      if ((w.kind_mask & 1U) == 0U || w.form == cm::Form::kWear || w.form == cm::Form::kLag) {
        continue;
      }
      if (w.form != cm::Form::kConstant) cols.push_back(w.column);
      if (w.form == cm::Form::kInteraction) cols.push_back(w.column_b);
      for (const int c : w.per) {
        if (c >= 0 && c != static_cast<int>(cm::Column::kKind) &&
            c != static_cast<int>(cm::Column::kPoint)) {
          cols.push_back(c);
        }
      }
    }
  }
  for (const int c : cols) {
    // The session is the loop's warm-start count: a session term learns each one.
    if (c == static_cast<int>(cm::kSessionColumn)) continue;
    const std::string name = cm::column_name(c, extras);
    if (c == static_cast<int>(cm::Column::kAngle) && std::isnan(apply.angle_deg)) {
      return "depends on angle_deg, which the daemon's loop does not know: give the entry the "
             "wall or engagement angle of what the register serves (angle_deg = …)";
    }
    if (c >= static_cast<int>(cm::kStandardColumns)) {
      bool mapped = false;
      for (const auto& in : inputs) mapped = mapped || in.input.column == c;
      if (!mapped) {
        return "depends on " + name +
               ", which the daemon's loop does not know: map it to a sensor with "
               "[[model.inputs]] column = \"" +
               name + "\" sensor = N (or it would contribute nothing)";
      }
    }
    const bool within_part =
        c == static_cast<int>(cm::Column::kX) || c == static_cast<int>(cm::Column::kY) ||
        c == static_cast<int>(cm::Column::kZ) || c == static_cast<int>(cm::Column::kPath);
    if (within_part && !each_cycle) {
      return "depends on " + name +
             ", which changes within a part: set update = \"cycle\" in [model]";
    }
  }
  for (std::size_t k = 0; k < 2; ++k) {
    if (spec.per[k] == static_cast<int>(cm::Column::kPoint) && std::isnan(apply.point)) {
      return "has one coefficient set per point and the entry gives no point: add point = N "
             "(the model has " +
             group_list(term, extras) + "), or it would contribute nothing";
    }
  }
  // The group columns the entry fixes (kind always) must be those of a group; the loop gives
  // the others.
  std::array<double, 2> v{cm::kUnknown, cm::kUnknown};
  std::string fixed;
  for (std::size_t k = 0; k < 2; ++k) {
    if (spec.per[k] >= 0) v[k] = entry_value(spec.per[k], apply);
    if (std::isnan(v[k])) continue;
    fixed += (fixed.empty() ? "" : ", ") + cm::column_name(spec.per[k], extras) + " = " +
             key_value(spec.per[k], v[k]);
  }
  if (fixed.empty()) return {};
  for (const auto& g : term.groups) {
    bool match = true;
    for (std::size_t k = 0; k < 2; ++k) {
      if (!std::isnan(v[k]) && (v[k] < g[k] || v[k] > g[k])) match = false;
    }
    if (match) return {};
  }
  return "has no group " + fixed + " (the model has " + group_list(term, extras) +
         "): it would contribute nothing";
}

/// [model.shadow]; read when absent too, so that its defaults are those documented.
void parse_shadow(TableReader& r, ShadowOptions& o) {
  static const toml::table kEmpty;
  const toml::table* t = r.table("shadow");
  TableReader q(t != nullptr ? *t : kEmpty, "model.shadow", r.diagnostics());
  o.min_parts = static_cast<int>(q.integer("min_parts", 10, 1, 100000));
  o.alpha = q.number("alpha", 0.05, 1e-6, 0.5);
  o.margin_um = q.number("margin_um", 0.0, 0.0, 1000.0);
  o.promote = q.pick<ShadowPromote>(
      "promote", ShadowPromote::kAuto,
      {{"auto", ShadowPromote::kAuto}, {"operator", ShadowPromote::kOperator}});
  o.history_size = static_cast<int>(q.integer("history_size", 20, 1, 1000));
  // The sign test's smallest p-value is 2^-min_parts (the candidate better on every part).
  if (sign_test_p(o.min_parts, o.min_parts) > o.alpha) {
    int needed = o.min_parts;
    while (sign_test_p(needed, needed) > o.alpha) ++needed;
    q.error("min_parts", "min_parts = " + std::to_string(o.min_parts) +
                             " can never pass the sign test at alpha = " + fmt_alpha(o.alpha) +
                             ": at least " + std::to_string(needed) + " parts are needed");
  }
  q.finish();
}

}  // namespace

std::unique_ptr<ModelSection> parse_model_section(const toml::node& node,
                                                  formats::Diagnostics& diag) {
  auto s = std::make_unique<ModelSection>();
  s->where = formats::where_of(&node, "model");
  const auto* table = node.as_table();
  if (table == nullptr) {
    diag.error(&node, "model", "must be a table ([model])");
    return s;
  }
  TableReader r(*table, "model", diag);
  const std::string file = r.string("file", std::nullopt);
  const std::string update = r.choice("update", std::string("part"), {"part", "cycle"});
  s->each_cycle = update == "cycle";
  if (table->contains("temperature_sensor")) {
    s->temperature_sensor = static_cast<int>(r.integer("temperature_sensor", 0, -1, 255));
    s->has_temperature_sensor = true;
    s->temperature_where = r.where("temperature_sensor");
  }
  if (!file.empty()) {
    const auto& src = node.source();
    fs::path p(file);
    if (p.is_relative() && src.path) p = fs::path(*src.path).parent_path() / p;
    s->file = p.lexically_normal().string();
    s->configured_file = s->file;
    if (const auto choice = model_choice(); choice && choice->configured == s->file) {
      s->chosen = true;
      s->file = choice->live.file;
      s->disabled = s->file.empty();
    }
    try {
      if (!s->disabled) {
        s->model = formats::model_io::load_model_file(s->file);
        s->loaded = true;
      }
    } catch (const formats::DiagnosticsError& e) {
      // At the file key, then every error of the model file at its own line.
      diag.error(r.where("file"), "cannot load the model " + s->file +
                                      (s->chosen ? " (nccomp model load)" : std::string()) + ": " +
                                      (e.diagnostics().items().size() == 1
                                           ? std::string("1 error in it, below")
                                           : std::to_string(e.diagnostics().items().size()) +
                                                 " errors in it, below"));
      diag.append(e.diagnostics(), s->file);
    } catch (const std::exception& e) {
      diag.error(r.where("file"),
                 std::string("cannot load the model") +
                     (s->chosen ? " " + s->file + " (nccomp model load)" : std::string()) + ": " +
                     e.what());
    }
  }
  // Extra columns of the model fed from sensors (before the applies, which check them).
  const toml::array* ins = r.table_array("inputs");
  for (std::size_t i = 0; ins != nullptr && i < ins->size(); ++i) {
    const auto* t = ins->get(i)->as_table();
    if (t == nullptr) continue;
    const std::string path = "model.inputs[" + std::to_string(i) + "]";
    TableReader q(*t, path, diag);
    ModelInputConfig in;
    in.where = formats::where_of(ins->get(i), path);
    in.column = q.string("column", std::nullopt);
    in.input.sensor = static_cast<int>(q.integer("sensor", std::nullopt, 0, 255));
    q.finish();
    if (s->loaded && !in.column.empty()) {
      const auto& extras = s->model.extra_columns();
      const int c = cm::column_index(in.column, extras);
      if (c < static_cast<int>(cm::kStandardColumns)) {
        std::string names;
        for (const auto& e : extras) names += (names.empty() ? "" : ", ") + e;
        diag.error(q.where("column"),
                   c < 0 ? "'" + in.column + "' is not an extra column of " + s->file + " (" +
                               (names.empty() ? std::string("it has none") : names) + ")"
                         : "'" + in.column +
                               "' is a log column the loop knows already; "
                               "inputs feed extra columns only");
      } else {
        in.input.column = c;
        for (const auto& other : s->inputs) {
          if (other.input.column == c) {
            diag.error(q.where("column"), "'" + in.column + "' is mapped twice");
          }
        }
      }
    }
    s->inputs.push_back(std::move(in));
  }
  const toml::array* arr = r.table_array("apply");
  if (arr == nullptr || arr->empty()) {
    diag.error(s->where,
               "model.apply: at least one [[model.apply]] entry is needed (which "
               "fitted term goes onto which register)");
  }
  for (std::size_t i = 0; arr != nullptr && i < arr->size(); ++i) {
    const auto* t = arr->get(i)->as_table();
    if (t == nullptr) continue;  // table_array() reported it
    const std::string path = "model.apply[" + std::to_string(i) + "]";
    TableReader q(*t, path, diag);
    ModelApplyConfig a;
    a.where = formats::where_of(arr->get(i), path);
    a.term = q.string("term", std::nullopt);
    a.register_name = q.string("register", std::nullopt);
    a.apply.gain = q.number("gain", -1.0, -1e3, 1e3);
    const std::string kind =
        q.choice("kind", std::string("contour"), {"tool_wear", "contour", "calib"});
    a.apply.kind = static_cast<double>(formats::model_io::kind_from_name(kind));
    if (t->contains("point")) {
      a.apply.point = static_cast<double>(q.integer("point", std::nullopt, -1000000, 1000000));
    }
    if (t->contains("tool")) {
      a.apply.tool = static_cast<double>(q.integer("tool", std::nullopt, 0, 1000000));
    }
    if (t->contains("angle_deg")) {
      a.apply.angle_deg = q.number("angle_deg", std::nullopt, -360.0, 360.0);
    }
    // Several terms may share a name (analyze adds thermal_drift in time, in a temperature, as
    // a lag of the speed): the column and the form choose among them.
    const std::string column = t->contains("column") ? q.string("column", std::nullopt) : "";
    const std::string form = t->contains("form") ? q.string("form", std::nullopt) : "";
    q.finish();
    if (s->loaded && !a.term.empty()) {
      int found = -1;
      int count = 0;
      const auto& terms = s->model.terms();
      const auto& extras = s->model.extra_columns();
      auto describe = [&](const cm::TermSpec& spec) {
        return spec.name + " (" +
               (spec.form == cm::Form::kConstant ? std::string("constant")
                                                 : cm::term_column_name(spec, extras) + ", " +
                                                       std::string(cm::form_name(spec.form))) +
               ")";
      };
      for (std::size_t k = 0; k < terms.size(); ++k) {
        const cm::TermSpec& spec = terms[k].spec;
        if (spec.name != a.term) continue;
        if (!column.empty() &&
            (spec.form == cm::Form::kConstant || cm::term_column_name(spec, extras) != column)) {
          continue;
        }
        if (!form.empty() && cm::form_name(spec.form) != form) continue;
        found = static_cast<int>(k);
        ++count;
      }
      if (count != 1) {
        std::string names;
        for (const auto& term : terms) names += (names.empty() ? "" : ", ") + describe(term.spec);
        const std::string which = "'" + a.term + "'" +
                                  (column.empty() ? "" : " of column '" + column + "'") +
                                  (form.empty() ? "" : " of form '" + form + "'");
        diag.error(q.where("term"), count == 0
                                        ? "no term " + which + " in " + s->file + " (" + names + ")"
                                        : "term " + which + " appears " + std::to_string(count) +
                                              " times in " + s->file + " (" + names +
                                              "): choose one with column = … and / or form = …");
      } else {
        a.apply.term_index = static_cast<std::size_t>(found);
        const std::string problem = loop_context_problem(
            terms[static_cast<std::size_t>(found)], s->each_cycle, s->model, s->inputs, a.apply);
        if (!problem.empty()) diag.error(q.where("term"), "term '" + a.term + "' " + problem);
      }
    }
    s->applies.push_back(std::move(a));
  }
  parse_shadow(r, s->shadow);
  r.finish();
  return s;
}

const ModelSection* model_section(const config::Config& config) {
  return config.find<ModelSection>("model");
}

std::unique_ptr<core::model::ModelModule> make_model_module(
    const ModelSection& s, const std::vector<core::engine::RegisterSpec>& registers) {
  std::vector<core::model::ModelApply> applies;
  const core::engine::RegisterTable table(registers);
  for (std::size_t i = 0; i < s.applies.size(); ++i) {
    core::model::ModelApply a = s.applies[i].apply;
    const int idx = table.find(s.applies[i].register_name);
    if (idx < 0) {
      throw std::invalid_argument("model.apply[" + std::to_string(i) +
                                  "].register: no "
                                  "[[registers]] entry named '" +
                                  s.applies[i].register_name + "'");
    }
    a.register_index = static_cast<std::uint16_t>(idx);
    applies.push_back(a);
  }
  std::vector<core::model::ModelInput> inputs;
  for (const auto& in : s.inputs) {
    if (in.input.column >= 0) inputs.push_back(in.input);
  }
  auto m = std::make_unique<core::model::ModelModule>(s.model, std::move(applies), s.each_cycle,
                                                      std::move(inputs));
  m->attach(table);
  return m;
}

namespace {

class ModelParser final : public config::SectionParser {
 public:
  std::string_view name() const noexcept override { return "model"; }
  std::unique_ptr<config::Section> parse(const toml::node& node,
                                         formats::Diagnostics& diag) const override {
    return parse_model_section(node, diag);
  }
  void cross_check(const config::Config& config, formats::Diagnostics& diag) const override {
    const auto* s = model_section(config);
    if (s == nullptr) return;
    // temp_c is one column: the log records it from the measurement context's sensor, and the
    // terms fitted on it must be evaluated on the same sensor.
    const int log_sensor = measurement_context_options(config).temperature_sensor;
    if (s->has_temperature_sensor && s->temperature_sensor != log_sensor) {
      diag.error(s->temperature_where,
                 "sensor " + std::to_string(s->temperature_sensor) +
                     " differs from the sensor the measurement log records as temp_c (" +
                     std::to_string(log_sensor) +
                     ", [measurement_context] temperature_sensor): a term fitted on the log's "
                     "temp_c would be evaluated on another sensor; remove this key or set "
                     "[measurement_context] temperature_sensor = " +
                     std::to_string(s->temperature_sensor));
    }
    if (!s->loaded) return;
    std::vector<core::engine::RegisterSpec> specs;
    for (const auto& e : config::registers_section(config).registers) specs.push_back(e.spec);
    const core::engine::RegisterTable table(specs);
    // S3 with touch_positions = "machine" measures the whole drift whatever the NC's offset
    // holds: a trim on its register would be counted on top of it.
    const auto* calibration = calibration_section(config);
    const bool s3_whole_drift = calibration != nullptr && calibration->config.touch_positions ==
                                                              core::calib::TouchPositions::kMachine;
    for (std::size_t i = 0; i < s->applies.size(); ++i) {
      const auto& a = s->applies[i];
      const int idx = table.find(a.register_name);
      if (idx < 0) {
        diag.error(a.where, "model.apply[" + std::to_string(i) +
                                "].register: no [[registers]] "
                                "entry named '" +
                                a.register_name + "'");
      } else if (specs[static_cast<std::size_t>(idx)].kind == core::engine::RegisterKind::kFlag) {
        diag.error(a.where, "model.apply[" + std::to_string(i) + "].register: '" + a.register_name +
                                "' is a flag; a trim needs an offset register");
      } else if (s3_whole_drift &&
                 (idx == calibration->config.register_x || idx == calibration->config.register_y ||
                  idx == calibration->config.register_z)) {
        diag.error(a.where, "model.apply[" + std::to_string(i) + "].register: '" + a.register_name +
                                "' takes [calibration]'s correction, which measures the whole "
                                "drift with touch_positions = \"machine\": the term's trim would "
                                "count it twice; set [calibration] touch_positions = \"program\" "
                                "(the calibration then learns what the term leaves)");
      }
    }
  }
  void add_modules(const config::Config& config,
                   std::vector<std::unique_ptr<core::engine::Module>>& modules) const override {
    const auto* s = model_section(config);
    if (s == nullptr || s->disabled) return;
    std::vector<core::engine::RegisterSpec> specs;
    for (const auto& e : config::registers_section(config).registers) specs.push_back(e.spec);
    modules.push_back(make_model_module(*s, specs));
  }
};

NCCOMP_REGISTER_CONFIG_SECTION(ModelParser)

}  // namespace

}  // namespace nccomp::daemon::sections
