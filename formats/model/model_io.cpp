#include "formats/model/model_io.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <string_view>
#include <utility>

#include "formats/toml/guard.hpp"

namespace nccomp::formats::model_io {

namespace cm = core::model;

namespace {

constexpr std::array<std::string_view, 3> kKindNames = {"tool_wear", "contour", "calib"};

void check_keys(const toml::table& t, std::string_view path,
                std::initializer_list<std::string_view> allowed, Diagnostics& diag) {
  for (const auto& [k, v] : t) {
    if (std::find(allowed.begin(), allowed.end(), k.str()) != allowed.end()) continue;
    std::string a;
    for (auto x : allowed) a += (a.empty() ? "" : ", ") + std::string(x);
    diag.error(&v, std::string(path) + "." + std::string(k.str()),
               "unknown key (allowed: " + a + ")");
  }
}

std::optional<double> get_number(const toml::node& n, const std::string& key, Diagnostics& diag) {
  if (auto d = n.value<double>(); d && (n.is_floating_point() || n.is_integer())) {
    if (std::isfinite(*d)) return *d;
    diag.error(&n, key, "must be a finite number");
    return std::nullopt;
  }
  diag.error(&n, key, "must be a number");
  return std::nullopt;
}

std::optional<std::string> get_string(const toml::node& n, const std::string& key,
                                      Diagnostics& diag) {
  if (auto s = n.value<std::string>(); s && n.is_string()) return *s;
  diag.error(&n, key, "must be a string");
  return std::nullopt;
}

/// nullopt if the array or any element is wrong (each reported).
std::optional<std::vector<std::string>> get_strings(const toml::node& n, const std::string& key,
                                                    Diagnostics& diag) {
  const auto* arr = n.as_array();
  if (arr == nullptr) {
    diag.error(&n, key, "must be an array of strings");
    return std::nullopt;
  }
  std::vector<std::string> out;
  bool ok = true;
  for (std::size_t i = 0; i < arr->size(); ++i) {
    if (auto s = get_string(*arr->get(i), key + "[" + std::to_string(i) + "]", diag)) {
      out.push_back(std::move(*s));
    } else {
      ok = false;
    }
  }
  if (!ok) return std::nullopt;
  return out;
}

std::optional<std::vector<double>> get_numbers(const toml::node& n, const std::string& key,
                                               Diagnostics& diag) {
  const auto* arr = n.as_array();
  if (arr == nullptr) {
    diag.error(&n, key, "must be an array of numbers");
    return std::nullopt;
  }
  std::vector<double> out;
  bool ok = true;
  for (std::size_t i = 0; i < arr->size(); ++i) {
    if (auto v = get_number(*arr->get(i), key + "[" + std::to_string(i) + "]", diag)) {
      out.push_back(*v);
    } else {
      ok = false;
    }
  }
  if (!ok) return std::nullopt;
  return out;
}

std::optional<std::uint8_t> kinds_mask(const toml::node& n, const std::string& key,
                                       Diagnostics& diag) {
  const auto names = get_strings(n, key, diag);
  if (!names) return std::nullopt;
  std::uint8_t mask = 0;
  bool ok = true;
  for (const auto& k : *names) {
    const int i = kind_from_name(k);
    if (i < 0) {
      diag.error(&n, key, "unknown kind '" + k + "' (tool_wear, contour, calib)");
      ok = false;
      continue;
    }
    mask = static_cast<std::uint8_t>(mask | (1U << static_cast<unsigned>(i)));
  }
  if (!ok) return std::nullopt;
  if (mask == 0) {
    diag.error(&n, key, "names no kind");
    return std::nullopt;
  }
  return mask;
}

std::optional<int> resolve_column(const std::string& name, std::vector<std::string>& extras,
                                  const toml::node& n, const std::string& key, Diagnostics& diag) {
  int c = cm::column_index(name, extras);
  if (c >= 0) return c;
  if (name == "measured_um" || name == "applied_um" || name.empty()) {
    diag.error(&n, key, "'" + name + "' cannot be a term's column");
    return std::nullopt;
  }
  if (extras.size() >= cm::kMaxExtraColumns) {
    diag.error(&n, key, "more than " + std::to_string(cm::kMaxExtraColumns) + " extra columns");
    return std::nullopt;
  }
  extras.push_back(name);
  return cm::column_index(name, extras);
}

constexpr std::array<std::string_view, 14> kEffectNames = {"thermal_drift",
                                                           "level_change",
                                                           "position_x",
                                                           "position_y",
                                                           "position_z",
                                                           "periodic_x",
                                                           "periodic_y",
                                                           "periodic_z",
                                                           "tool_wear",
                                                           "wear_nonlinear",
                                                           "part_trend",
                                                           "contact_angle",
                                                           "contact_angle*tool_wear",
                                                           "session_offset"};

// A `column_kind` table: column = "temperature" | "other" (how a linear effect in it is named).
// Wrong entries are reported and left out.
std::vector<std::pair<std::string, bool>> read_column_kinds(const toml::node& n,
                                                            const std::string& key,
                                                            Diagnostics& diag) {
  std::vector<std::pair<std::string, bool>> out;
  const auto* t = n.as_table();
  if (t == nullptr) {
    diag.error(&n, key, "must be a table of column = \"temperature\"");
    return out;
  }
  for (const auto& [k, v] : *t) {
    const std::string name(k.str());
    const auto kind = get_string(v, key + "." + name, diag);
    if (!kind) continue;
    if (*kind != "temperature" && *kind != "other") {
      diag.error(&v, key + "." + name, "'" + *kind + "' is not temperature or other");
      continue;
    }
    out.emplace_back(name, *kind == "temperature");
  }
  return out;
}

std::string fmt_double(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  std::string s(buf);
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  return s;
}

std::string quote(std::string_view s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}

std::string_view trim_view(std::string_view s) {
  std::size_t b = 0;
  std::size_t e = s.size();
  while (b < e && (s[b] == ' ' || s[b] == '\t' || s[b] == '\r')) ++b;
  while (e > b && (s[e - 1] == ' ' || s[e - 1] == '\t' || s[e - 1] == '\r')) --e;
  return s.substr(b, e - b);
}

std::string trim(std::string_view s) { return std::string(trim_view(s)); }

/// A number in a table, checked by `valid` (which names the rule in `rule`); nullopt if absent
/// or wrong.
template <typename Valid>
std::optional<double> checked_number(const toml::table& t, std::string_view key,
                                     const std::string& path, Valid valid, const char* rule,
                                     Diagnostics& diag) {
  const auto* n = t.get(key);
  if (n == nullptr) return std::nullopt;
  const auto v = get_number(*n, path, diag);
  if (!v) return std::nullopt;
  if (!valid(*v)) {
    diag.error(n, path, rule);
    return std::nullopt;
  }
  return v;
}

/// The analysis options of [model] (everything but the terms and the search).
void read_options(const toml::table& model, cm::AnalysisConfig& cfg, Diagnostics& diag) {
  for (const char* flag : {"ar1_correction", "lookahead"}) {
    if (const auto* n = model.get(flag)) {
      if (!n->is_boolean()) {
        diag.error(n, std::string("model.") + flag, "must be true or false");
        continue;
      }
      (std::string_view(flag) == "lookahead" ? cfg.lookahead : cfg.ar1_correction) =
          n->value_or(true);
    }
  }
  const auto integral = [](double v) { return !(std::floor(v) < v); };
  if (const auto v = checked_number(
          model, "heldout_fraction", "model.heldout_fraction",
          [](double x) { return x >= 0.0 && x <= 0.5; }, "must be within [0, 0.5]", diag)) {
    cfg.heldout_fraction = *v;
  }
  if (const auto v = checked_number(
          model, "alpha", "model.alpha", [](double x) { return x > 0.0 && x < 0.5; },
          "must be within (0, 0.5)", diag)) {
    cfg.alpha = *v;
  }
  if (const auto v = checked_number(
          model, "outlier_sigmas", "model.outlier_sigmas",
          [](double x) { return !(x < 0.0 || (x > 0.0 && x < 3.0) || x > 1e3); },
          "must be 0 (off) or within [3, 1000]", diag)) {
    cfg.outlier_sigmas = *v;
  }
  if (const auto v = checked_number(
          model, "session_gap_s", "model.session_gap_s", [](double x) { return x >= 0.0; },
          "must be 0 (off) or a time > 0 [s]", diag)) {
    cfg.session_gap_s = *v;
  }
  if (const auto v = checked_number(
          model, "max_effects", "model.max_effects",
          [&](double x) { return x >= 0.0 && x <= 16.0 && integral(x); },
          "must be an integer within [0, 16]", diag)) {
    cfg.max_effects = static_cast<std::size_t>(*v);
  }
  if (const auto v = checked_number(
          model, "search_rows", "model.search_rows",
          [&](double x) { return x >= 100.0 && x <= 1e6 && integral(x); },
          "must be an integer within [100, 1e6]", diag)) {
    cfg.search_rows = static_cast<std::size_t>(*v);
  }
  if (const auto v = checked_number(
          model, "validate_block_s", "model.validate_block_s", [](double x) { return x >= 0.0; },
          "must be 0 (off) or a time > 0 [s]", diag)) {
    cfg.validate_block_s = *v;
  }
  if (const auto v = checked_number(
          model, "rank_folds", "model.rank_folds",
          [&](double x) { return x >= 0.0 && x <= 10.0 && integral(x); },
          "must be 0 (off) or an integer within [1, 10]", diag)) {
    cfg.rank_folds = static_cast<std::size_t>(*v);
  }
  if (const auto* n = model.get("interval")) {
    if (const auto v = get_string(*n, "model.interval", diag)) {
      if (*v == "validation") {
        cfg.interval = cm::IntervalMethod::kValidation;
      } else if (*v == "in_sample") {
        cfg.interval = cm::IntervalMethod::kInSample;
      } else {
        diag.error(n, "model.interval", "'" + *v + "' is not validation or in_sample");
      }
    }
  }
}

/// One [[model.term]]: its spec, and its fitted coefficients if it carries them. Every error is
/// reported; those that depend on the form are judged only when the form is known.
void read_term(const toml::table& t, const std::string& key, bool require_fitted, ModelFile& out,
               Diagnostics& diag) {
  check_keys(t, key,
             {"name", "form", "column", "per", "kinds", "degree", "center", "center_b", "scale",
              "between_session_sigma_um", "noise_sigma_um", "groups", "coef_um"},
             diag);
  cm::TermSpec s;
  if (const auto* name = t.get("name"); name == nullptr) {
    diag.error(&t, key + ".name", "missing");
  } else if (const auto v = get_string(*name, key + ".name", diag)) {
    s.name = *v;
    if (s.name.empty()) diag.error(name, key + ".name", "must not be empty");
  }
  const auto* form = t.get("form");
  std::optional<std::string> fname;
  if (form == nullptr) {
    diag.error(&t, key + ".form", "missing");
  } else if ((fname = get_string(*form, key + ".form", diag)) && !cm::parse_form(*fname, s.form)) {
    diag.error(form, key + ".form",
               "unknown form '" + *fname +
                   "' (constant, linear, poly, exp_rise, sine, step, lag, exp_growth, hinge, "
                   "wear, interaction, session)");
    fname.reset();
  }
  if (const auto* p = t.get("per")) {
    if (const auto names = get_strings(*p, key + ".per", diag)) {
      if (names->size() > 2) {
        diag.error(p, key + ".per", "at most two columns");
      } else {
        for (std::size_t k = 0; k < names->size(); ++k) {
          s.per[k] =
              resolve_column((*names)[k], out.extra_columns, *p, key + ".per", diag).value_or(-1);
        }
      }
    }
  }
  if (const auto* k = t.get("kinds")) {
    s.kind_mask = kinds_mask(*k, key + ".kinds", diag).value_or(s.kind_mask);
  }
  if (const auto v = checked_number(
          t, "degree", key + ".degree",
          [](double x) { return x >= 1.0 && x <= 3.0 && !(std::floor(x) < x); },
          "must be 1, 2 or 3", diag)) {
    s.degree = static_cast<int>(*v);
  }
  if (const auto* c = t.get("center"))
    s.center = get_number(*c, key + ".center", diag).value_or(0.0);
  if (!fname) {
    // The rest depends on the form.
    return;
  }
  if (s.form == cm::Form::kSession) {
    // One offset per session, learned by the daemon from each session's first measurements.
    for (const char* k : {"column", "per", "center", "scale", "degree"}) {
      if (const auto* v = t.get(k)) {
        diag.error(v, key + "." + k,
                   "not for form = \"session\" (it is per session by definition; its variances "
                   "are between_session_sigma_um and noise_sigma_um)");
      }
    }
    for (const char* k : {"between_session_sigma_um", "noise_sigma_um"}) {
      const bool between = std::string_view(k) == "between_session_sigma_um";
      const auto* v = t.get(k);
      if (v == nullptr) {
        diag.error(&t, key + "." + k, "missing (form session)");
      } else if (const auto x = get_number(*v, key + "." + k, diag)) {
        if (!(between ? *x >= 0.0 : *x > 0.0) || !std::isfinite(*x)) {
          diag.error(v, key + "." + k, between ? "must be ≥ 0 [µm]" : "must be > 0 [µm]");
        } else {
          (between ? s.scale : s.center) = *x;
        }
      }
    }
    for (const cm::TermSpec& other : out.config.declared) {
      if (other.form == cm::Form::kSession) {
        diag.error(form, key + ".form", "a model has at most one session term");
      }
    }
    s.column = static_cast<int>(cm::kSessionColumn);
    s.per = {static_cast<int>(cm::kSessionColumn), -1};
  } else {
    for (const char* k : {"between_session_sigma_um", "noise_sigma_um"}) {
      if (const auto* v = t.get(k)) diag.error(v, key + "." + k, "only for form = \"session\"");
    }
  }
  if (const auto* c = t.get("column")) {
    if (const auto col = get_string(*c, key + ".column", diag)) {
      const auto star = col->find('*');
      if (cm::has_column_b(s.form)) {
        if (star == std::string::npos || star == 0 || star + 1 == col->size()) {
          const bool interaction = s.form == cm::Form::kInteraction;
          diag.error(c, key + ".column",
                     "'" + *col +
                         "': " + (interaction ? "an interaction's" : "a profile_wear term's") +
                         " column is two columns a*b (e.g. " +
                         (interaction ? "\"temp_c*x_mm\")" : "\"angle_deg*path_mm\")"));
        } else {
          s.column =
              resolve_column(col->substr(0, star), out.extra_columns, *c, key + ".column", diag)
                  .value_or(-1);
          s.column_b =
              resolve_column(col->substr(star + 1), out.extra_columns, *c, key + ".column", diag)
                  .value_or(-1);
        }
      } else if (star != std::string::npos) {
        diag.error(c, key + ".column",
                   "'" + *col +
                       "': a product of columns needs form = \"interaction\" or \"profile_wear\"");
      } else {
        s.column = resolve_column(*col, out.extra_columns, *c, key + ".column", diag).value_or(-1);
      }
    }
  } else if (s.form != cm::Form::kConstant && s.form != cm::Form::kSession) {
    diag.error(&t, key + ".column", "missing (form " + *fname + " needs a column)");
  }
  if (const auto* c = t.get("center_b")) {
    if (s.form != cm::Form::kInteraction) {
      diag.error(c, key + ".center_b", "only for form = \"interaction\"");
    } else {
      s.center_b = get_number(*c, key + ".center_b", diag).value_or(0.0);
    }
  }
  if (t.get("scale") != nullptr) {
    if (const auto v = checked_number(
            t, "scale", key + ".scale", [](double x) { return x > 0.0; }, "must be > 0", diag)) {
      s.scale = *v;
    }
  } else if (s.form == cm::Form::kExpRise || s.form == cm::Form::kSine ||
             s.form == cm::Form::kLag || s.form == cm::Form::kPoly ||
             s.form == cm::Form::kExpGrowth || s.form == cm::Form::kProfileWear) {
    diag.error(&t, key + ".scale",
               "missing (form " + *fname + " needs its scale / period / time constant)");
  }
  if ((s.form == cm::Form::kStep || s.form == cm::Form::kHinge) && t.get("center") == nullptr) {
    diag.error(&t, key + ".center", "missing (form " + *fname + " needs the change point)");
  }
  if (s.form == cm::Form::kWear && (s.kind_mask & 1U) != 0U) {
    diag.error(&t, key + ".kinds",
               "a term proportional to the tool wear (form wear) cannot apply to tool_wear rows; "
               "set kinds = [\"contour\"] or [\"contour\", \"calib\"]");
  }
  const auto* g = t.get("groups");
  const auto* c = t.get("coef_um");
  if ((g == nullptr) != (c == nullptr)) {
    diag.error(&t, key, "groups and coef_um go together");
  } else if (g != nullptr) {
    cm::Term term;
    term.spec = s;
    bool ok = true;
    if (const auto* ga = g->as_array(); ga == nullptr) {
      diag.error(g, key + ".groups", "must be an array of [a, b]");
      ok = false;
    } else {
      for (std::size_t j = 0; j < ga->size(); ++j) {
        const std::string gk = key + ".groups[" + std::to_string(j) + "]";
        const auto v = get_numbers(*ga->get(j), gk, diag);
        if (v && v->size() != 2) diag.error(ga->get(j), gk, "must have two numbers");
        if (!v || v->size() != 2) {
          ok = false;
          continue;
        }
        term.groups.push_back({(*v)[0], (*v)[1]});
      }
    }
    if (auto coef = get_numbers(*c, key + ".coef_um", diag)) {
      term.coef = std::move(*coef);
      const std::size_t expected = term.groups.size() * cm::basis_count(s.form, s.degree);
      if (ok && term.coef.size() != expected) {
        diag.error(c, key + ".coef_um",
                   "expected " + std::to_string(expected) +
                       " values (groups × basis functions), got " +
                       std::to_string(term.coef.size()));
      }
    }
    out.fitted_terms.push_back(std::move(term));
  } else if (require_fitted) {
    diag.error(&t, key, "no groups / coef_um: not a fitted model");
  }
  out.config.declared.push_back(s);
}

/// [model.search]: which effects the analysis looks for.
void read_search(const toml::node& sn, ModelFile& out, Diagnostics& diag) {
  const auto* st = sn.as_table();
  if (st == nullptr) {
    diag.error(&sn, "model.search", "must be a table");
    return;
  }
  check_keys(*st, "model.search",
             {"kinds", "exclude", "linear_columns", "lag_columns", "period_min_mm", "per",
              "group_columns", "column_kind"},
             diag);
  cm::SearchOptions& so = out.config.search;
  if (const auto* n = st->get("per")) {
    if (const auto names = get_strings(*n, "model.search.per", diag)) {
      if (names->size() > 2) {
        diag.error(n, "model.search.per", "at most two columns");
      } else {
        for (std::size_t k = 0; k < names->size(); ++k) {
          so.per[k] = resolve_column((*names)[k], out.extra_columns, *n, "model.search.per", diag)
                          .value_or(-1);
        }
      }
    }
  }
  if (const auto* n = st->get("kinds")) {
    so.kind_mask = kinds_mask(*n, "model.search.kinds", diag).value_or(so.kind_mask);
  }
  if (const auto* n = st->get("exclude")) {
    so.exclude = get_strings(*n, "model.search.exclude", diag).value_or(std::vector<std::string>{});
  }
  for (const auto* list : {"linear_columns", "lag_columns", "group_columns"}) {
    const auto* n = st->get(list);
    if (n == nullptr) continue;
    const std::string key = std::string("model.search.") + list;
    const std::string_view l(list);
    std::vector<int>& cols = l == "linear_columns" ? so.linear_columns
                             : l == "lag_columns"  ? so.lag_columns
                                                   : so.group_columns;
    for (const auto& name : get_strings(*n, key, diag).value_or(std::vector<std::string>{})) {
      const auto c = resolve_column(name, out.extra_columns, *n, key, diag);
      if (!c) continue;
      if (l == "group_columns" && std::find(cols.begin(), cols.end(), *c) != cols.end()) {
        diag.error(n, key, "'" + name + "' named twice");
        continue;
      }
      cols.push_back(*c);
    }
  }
  if (const auto* n = st->get("group_columns"); n != nullptr && so.per[0] >= 0) {
    // per already splits every candidate: there is no shared version to set beside it.
    diag.error(n, "model.search.group_columns",
               "not together with model.search.per (which splits every candidate)");
  }
  if (const auto* n = st->get("column_kind")) {
    for (const auto& [name, temperature] :
         read_column_kinds(*n, "model.search.column_kind", diag)) {
      if (const auto c = resolve_column(name, out.extra_columns, *n,
                                        "model.search.column_kind." + name, diag)) {
        so.column_is_temperature.emplace_back(*c, temperature);
      }
    }
  }
  if (const auto* n = st->get("exclude")) {
    // A misspelt name would exclude nothing, silently.
    for (const auto& name : so.exclude) {
      bool known = std::find(kEffectNames.begin(), kEffectNames.end(), name) != kEffectNames.end();
      for (int c : so.linear_columns) {
        known = known || name == "linear_" + cm::column_name(c, out.extra_columns);
      }
      // An interaction a*b of two known columns.
      const auto star = name.find('*');
      known = known || (star != std::string::npos &&
                        cm::column_index(name.substr(0, star), out.extra_columns) >= 0 &&
                        cm::column_index(name.substr(star + 1), out.extra_columns) >= 0);
      if (!known) {
        diag.error(
            n, "model.search.exclude",
            "no effect is called '" + name +
                "' (thermal_drift, level_change, position_x|y|z, periodic_x|y|z, "
                "tool_wear, wear_nonlinear, part_trend, contact_angle, contact_angle*tool_wear, "
                "session_offset, "
                "linear_<column> of linear_columns, a*b of an interaction)");
      }
    }
  }
  if (const auto v = checked_number(
          *st, "period_min_mm", "model.search.period_min_mm", [](double x) { return x > 0.0; },
          "must be > 0", diag)) {
    so.period_min_mm = *v;
  }
}

/// The text of a file; nullopt if it cannot be opened.
std::optional<std::string> read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

[[noreturn]] void cannot_open(const std::string& path) {
  Diagnostics diag;
  diag.error(Where{path, 0, 0, ""}, "cannot open");
  throw DiagnosticsError(std::move(diag), path);
}

toml::table parse_or_throw(std::string_view text, std::string_view source) {
  try {
    return formats::parse_toml(text, source);
  } catch (const toml::parse_error& e) {
    throw DiagnosticsError(e, std::string(source));
  }
}

}  // namespace

void read_log_file(const std::string& path, const Mapping& mapping, core::model::Dataset& data) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    Diagnostics diag;
    const std::filesystem::path inside = std::filesystem::path(path) / "measurements.csv";
    diag.error(Where{path, 0, 0, ""},
               std::filesystem::exists(inside, ec)
                   ? "is a directory: give the log file in it, " + inside.string()
                   : std::string("is a directory, not a log file"));
    throw DiagnosticsError(std::move(diag), path);
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) cannot_open(path);
  read_log(in, path, mapping, data);
}

int kind_from_name(std::string_view name) noexcept {
  for (std::size_t i = 0; i < kKindNames.size(); ++i) {
    if (kKindNames[i] == name) return static_cast<int>(i);
  }
  return -1;
}

ModelFile read_model_table(const toml::table& root, std::string_view source, bool require_fitted) {
  Diagnostics diag;
  ModelFile out;
  const auto* model = root["model"].as_table();
  if (model == nullptr) {
    diag.error(Where{}, "no [model] table");
    throw DiagnosticsError(std::move(diag), std::string(source));
  }
  check_keys(*model, "model",
             {"heldout_fraction", "alpha", "max_effects", "search_rows", "ar1_correction",
              "lookahead", "outlier_sigmas", "session_gap_s", "rank_folds", "validate_block_s",
              "interval", "term", "search"},
             diag);
  read_options(*model, out.config, diag);
  const auto* terms = model->get("term");
  if (terms == nullptr || !terms->is_array_of_tables()) {
    diag.error(where_of(terms, "model.term"), "declare at least one [[model.term]]");
  } else {
    const auto& arr = *terms->as_array();
    std::size_t with_coef = 0;
    for (std::size_t i = 0; i < arr.size(); ++i) {
      const auto& t = *arr.get(i)->as_table();
      if (t.get("groups") != nullptr && t.get("coef_um") != nullptr) ++with_coef;
      read_term(t, "model.term[" + std::to_string(i) + "]", require_fitted, out, diag);
    }
    if (with_coef != 0 && with_coef != arr.size()) {
      diag.error(where_of(terms, "model.term"), "either every term or none carries coefficients");
    }
  }
  if (const auto* sn = model->get("search")) read_search(*sn, out, diag);
  if (!diag.ok()) throw DiagnosticsError(std::move(diag), std::string(source));
  return out;
}

ModelFile read_model_text(std::string_view text, std::string_view source, bool require_fitted) {
  return read_model_table(parse_or_throw(text, source), source, require_fitted);
}

core::model::Model load_model_file(const std::string& path) {
  const auto text = read_text(path);
  if (!text) cannot_open(path);
  ModelFile f = read_model_text(*text, path, true);
  return cm::Model(f.extra_columns, std::move(f.fitted_terms));
}

std::string write_model_toml(const core::model::Model& model,
                             const core::model::AnalysisConfig& config,
                             const std::vector<std::string>& header) {
  std::ostringstream o;
  for (const auto& h : header) o << "# " << h << "\n";
  const auto& ex = model.extra_columns();
  o << "[model]\n";
  o << "heldout_fraction = " << fmt_double(config.heldout_fraction) << "\n";
  o << "alpha = " << fmt_double(config.alpha) << "\n";
  o << "max_effects = " << config.max_effects << "\n";
  o << "search_rows = " << config.search_rows << "\n";
  o << "rank_folds = " << config.rank_folds << "\n";
  o << "ar1_correction = " << (config.ar1_correction ? "true" : "false") << "\n";
  o << "lookahead = " << (config.lookahead ? "true" : "false") << "\n";
  o << "outlier_sigmas = " << fmt_double(config.outlier_sigmas) << "\n";
  o << "session_gap_s = " << fmt_double(config.session_gap_s) << "\n";
  o << "validate_block_s = " << fmt_double(config.validate_block_s) << "\n";
  o << "interval = "
    << (config.interval == cm::IntervalMethod::kInSample ? "\"in_sample\"" : "\"validation\"")
    << "\n";
  for (const cm::Term& t : model.terms()) {
    const cm::TermSpec& s = t.spec;
    o << "\n[[model.term]]\n";
    o << "name = " << quote(s.name) << "\n";
    o << "form = " << quote(cm::form_name(s.form)) << "\n";
    const bool session = s.form == cm::Form::kSession;
    if (s.form != cm::Form::kConstant && !session)
      o << "column = " << quote(cm::term_column_name(s, ex)) << "\n";
    if (s.per[0] >= 0 && !session) {
      o << "per = [" << quote(cm::column_name(s.per[0], ex));
      if (s.per[1] >= 0) o << ", " << quote(cm::column_name(s.per[1], ex));
      o << "]\n";
    }
    if (s.kind_mask != 0x7) {
      o << "kinds = [";
      bool first = true;
      for (std::size_t k = 0; k < kKindNames.size(); ++k) {
        if ((s.kind_mask & (1U << k)) == 0U) continue;
        o << (first ? "" : ", ") << quote(kKindNames[k]);
        first = false;
      }
      o << "]\n";
    }
    if (s.form == cm::Form::kPoly) o << "degree = " << s.degree << "\n";
    if (s.form == cm::Form::kPoly || s.form == cm::Form::kStep || s.form == cm::Form::kHinge ||
        s.form == cm::Form::kWear || cm::has_column_b(s.form)) {
      o << "center = " << fmt_double(s.center) << "\n";
    }
    // A linear term's reference value; 0 (the meaning before references existed) is not written.
    if (s.form == cm::Form::kLinear && std::abs(s.center) > 0.0) {
      o << "center = " << fmt_double(s.center) << "\n";
    }
    if (s.form == cm::Form::kInteraction) o << "center_b = " << fmt_double(s.center_b) << "\n";
    if (s.form == cm::Form::kPoly || s.form == cm::Form::kProfileWear ||
        cm::has_nonlinear_parameter(s.form)) {
      if (s.form != cm::Form::kStep && s.form != cm::Form::kHinge)
        o << "scale = " << fmt_double(s.scale) << "\n";
    }
    if (session) {
      // No coefficients: the sessions of the log are over; every new one is learned from its
      // own first measurements (the fitted offsets are in summary.json).
      o << "between_session_sigma_um = " << fmt_double(s.scale) << "\n";
      o << "noise_sigma_um = " << fmt_double(s.center) << "\n";
      o << "groups = []\ncoef_um = []\n";
      continue;
    }
    o << "groups = [";
    for (std::size_t g = 0; g < t.groups.size(); ++g) {
      o << (g ? ", " : "") << "[" << fmt_double(t.groups[g][0]) << ", "
        << fmt_double(t.groups[g][1]) << "]";
    }
    o << "]\ncoef_um = [";
    for (std::size_t c = 0; c < t.coef.size(); ++c) o << (c ? ", " : "") << fmt_double(t.coef[c]);
    o << "]\n";
  }
  const cm::SearchOptions& so = config.search;
  o << "\n[model.search]\n";
  o << "period_min_mm = " << fmt_double(so.period_min_mm) << "\n";
  if (so.kind_mask != 0x7) {
    o << "kinds = [";
    bool first = true;
    for (std::size_t k = 0; k < kKindNames.size(); ++k) {
      if ((so.kind_mask & (1U << k)) == 0U) continue;
      o << (first ? "" : ", ") << quote(kKindNames[k]);
      first = false;
    }
    o << "]\n";
  }
  auto list = [&](const char* key, const std::vector<int>& cols) {
    if (cols.empty()) return;
    o << key << " = [";
    for (std::size_t i = 0; i < cols.size(); ++i)
      o << (i ? ", " : "") << quote(cm::column_name(cols[i], ex));
    o << "]\n";
  };
  list("linear_columns", so.linear_columns);
  std::vector<int> per;
  for (int c : so.per) {
    if (c >= 0) per.push_back(c);
  }
  list("per", per);
  list("group_columns", so.group_columns);
  list("lag_columns", so.lag_columns);
  if (!so.exclude.empty()) {
    o << "exclude = [";
    for (std::size_t i = 0; i < so.exclude.size(); ++i)
      o << (i ? ", " : "") << quote(so.exclude[i]);
    o << "]\n";
  }
  if (!so.column_is_temperature.empty()) {
    o << "\n[model.search.column_kind]\n";
    for (const auto& [c, temperature] : so.column_is_temperature) {
      o << quote(cm::column_name(c, ex)) << " = " << (temperature ? "\"temperature\"" : "\"other\"")
        << "\n";
    }
  }
  return o.str();
}

// ---------------------------------------------------------------------------------------------
// Mapping files.

Mapping read_mapping_text(std::string_view text, std::string_view source) {
  const toml::table root = parse_or_throw(text, source);
  Diagnostics diag;
  check_keys(root, "",
             {"columns", "extra", "scale", "constant", "wide", "column_kind", "ids", "restarts",
              "header_rows", "names_row", "separator", "decimal"},
             diag);
  Mapping m;
  auto table = [&](const char* name) -> const toml::table* {
    const auto* n = root.get(name);
    if (n == nullptr) return nullptr;
    if (!n->is_table()) {
      diag.error(n, name, "must be a table");
      return nullptr;
    }
    return n->as_table();
  };
  auto is_target = [](const std::string& k) {
    return cm::column_index(k, {}) >= 0 || k == "measured_um" || k == "applied_um";
  };
  if (const auto* t = table("columns")) {
    for (const auto& [k, v] : *t) {
      const std::string key = "columns." + std::string(k.str());
      if (!is_target(std::string(k.str()))) {
        diag.error(&v, key, "not a measurement-log column");
      } else if (const auto h = get_string(v, key, diag)) {
        m.columns.emplace_back(std::string(k.str()), trim(*h));
      }
    }
  }
  if (const auto* t = table("extra")) {
    for (const auto& [k, v] : *t) {
      const std::string key = "extra." + std::string(k.str());
      if (is_target(std::string(k.str()))) {
        diag.error(&v, key, "a standard column name");
      } else if (const auto h = get_string(v, key, diag)) {
        m.extra.emplace_back(std::string(k.str()), trim(*h));
      }
    }
  }
  const auto* scales = table("scale");
  if (scales != nullptr) {
    for (const auto& [k, v] : *scales) {
      if (const auto x = get_number(v, "scale." + std::string(k.str()), diag)) {
        m.scale.emplace_back(std::string(k.str()), *x);
      }
    }
  }
  if (const auto* t = table("constant")) {
    for (const auto& [k, v] : *t) {
      const std::string name(k.str());
      const std::string key = "constant." + name;
      if (!is_target(name)) {
        diag.error(&v, key, "not a measurement-log column");
      } else if (name == "kind") {
        if (const auto kind = get_string(v, key, diag)) {
          const int i = kind_from_name(*kind);
          if (i < 0) {
            diag.error(&v, key, "unknown kind '" + *kind + "'");
          } else {
            m.constant.emplace_back(name, static_cast<double>(i));
          }
        }
      } else if (const auto x = get_number(v, key, diag)) {
        m.constant.emplace_back(name, *x);
      }
    }
  }
  if (const auto* n = root.get("column_kind")) {
    for (auto& [name, temperature] : read_column_kinds(*n, "column_kind", diag)) {
      const std::string& column = name;  // clang 14 cannot capture a structured binding
      const bool mapped =
          is_target(column) || std::any_of(m.extra.begin(), m.extra.end(),
                                           [&](const auto& e) { return e.first == column; });
      if (!mapped) {
        diag.error(n->as_table()->get(column), "column_kind." + column,
                   "not a log column nor a column of [extra]");
        continue;
      }
      m.column_kind.emplace_back(name, temperature);
    }
  }
  if (const auto* t = table("wide")) {
    check_keys(*t, "wide", {"measured_um", "points"}, diag);
    const auto* mu = t->get("measured_um");
    const auto* pts = t->get("points");
    if (mu == nullptr || pts == nullptr) {
      diag.error(t, "wide", "needs measured_um and points");
    } else {
      const auto measured = get_strings(*mu, "wide.measured_um", diag);
      const auto points = get_numbers(*pts, "wide.points", diag);
      if (measured && points) {
        m.wide_measured = *measured;
        for (auto& s : m.wide_measured) s = trim(s);
        m.wide_points = *points;
        if (m.wide_measured.size() != m.wide_points.size() || m.wide_measured.empty()) {
          diag.error(t, "wide", "measured_um and points must have the same, non-zero length");
        }
      }
    }
  }
  // A column read from the file: mapped under [columns] (not the measurement) or [extra].
  auto read_column = [&](const std::string& column) {
    auto named = [&](const auto& list) {
      return std::any_of(list.begin(), list.end(),
                         [&](const auto& e) { return e.first == column; });
    };
    return column != "measured_um" && column != "applied_um" &&
           (named(m.columns) || named(m.extra));
  };
  if (const auto* t = table("ids")) {
    for (const auto& [k, v] : *t) {
      const std::string column(k.str());
      const std::string key = "ids." + column;
      const bool group = column == "tool" || column == "point" || column == "part" ||
                         std::any_of(m.extra.begin(), m.extra.end(),
                                     [&](const auto& e) { return e.first == column; });
      if (!group || !read_column(column)) {
        diag.error(&v, key,
                   "text ids are for tool, point or part mapped under [columns], or a column of "
                   "[extra]");
        continue;
      }
      Mapping::TextIds ids{column, false, {}};
      if (v.is_string()) {
        if (v.value_or(std::string()) != "digits") {
          diag.error(&v, key, "must be \"digits\" or a table of text = number");
          continue;
        }
        ids.digits = true;
      } else if (const auto* texts = v.as_table(); texts != nullptr && !texts->empty()) {
        for (const auto& [id_text, number] : *texts) {
          const auto x = get_number(number, key + "." + std::string(id_text.str()), diag);
          if (!x) continue;
          if (std::floor(*x) < *x) {
            diag.error(&number, key + "." + std::string(id_text.str()), "must be an integer");
            continue;
          }
          ids.table.emplace_back(trim(std::string(id_text.str())), *x);
        }
      } else {
        diag.error(&v, key, "must be \"digits\" or a table of text = number");
        continue;
      }
      m.ids.push_back(std::move(ids));
    }
  }
  if (const auto* t = table("restarts")) {
    for (const auto& [k, v] : *t) {
      const std::string column(k.str());
      const std::string key = "restarts." + column;
      const auto how = get_string(v, key, diag);
      if (!how) continue;
      if (*how != "per_file" && *how != "on_decrease") {
        diag.error(&v, key, "'" + *how + "' is not per_file or on_decrease");
      } else if (!read_column(column)) {
        diag.error(&v, key, "not a column mapped under [columns] or [extra]");
      } else if (!m.restart_column.empty()) {
        diag.error(&v, key, "one counter only (already " + m.restart_column + ")");
      } else if (std::any_of(m.ids.begin(), m.ids.end(),
                             [&](const auto& i) { return i.column == column; })) {
        diag.error(&v, key, "a column of text ids is no counter");
      } else {
        m.restart_column = column;
        m.restart_per_file = *how == "per_file";
      }
    }
  }
  auto header_key = [&](const char* name, int fallback) {
    const auto* n = root.get(name);
    if (n == nullptr) return fallback;
    const auto x = get_number(*n, name, diag);
    if (!x) return fallback;
    if (std::floor(*x) < *x || *x < 1.0 || *x > 100.0) {
      diag.error(n, name, "must be an integer from 1 to 100");
      return fallback;
    }
    return static_cast<int>(*x);
  };
  m.header_rows = header_key("header_rows", 1);
  m.names_row = header_key("names_row", m.header_rows);
  if (m.names_row > m.header_rows) {
    diag.error(root.get("names_row"), "names_row",
               "beyond header_rows = " + std::to_string(m.header_rows));
  }
  // The field separator and the decimal mark: one character each, from a short list.
  auto char_key = [&](const char* name, char fallback, std::string_view allowed, const char* rule) {
    const auto* n = root.get(name);
    if (n == nullptr) return fallback;
    const auto v = get_string(*n, name, diag);
    if (!v) return fallback;
    if (v->size() != 1 || allowed.find((*v)[0]) == std::string_view::npos) {
      diag.error(n, name, rule);
      return fallback;
    }
    return (*v)[0];
  };
  m.separator = char_key("separator", ',', ",;\t", "must be \",\", \";\" or \"\\t\" (a tab)");
  m.decimal = char_key("decimal", '.', ".,", "must be \".\" or \",\"");
  if (m.decimal == m.separator) {
    diag.error(root.get("decimal"), "decimal",
               "\",\" is the field separator too: set separator = \";\" (or \"\\t\")");
  }
  // A scale applies to a column read from the file, once: one mapped under [columns] or
  // [extra], or measured_um read from [wide]. A scale of anything else would silently do nothing.
  for (const auto& [k, v] : m.scale) {
    const std::string& column = k;  // clang 14 cannot capture a structured binding
    auto named = [&](const auto& list) {
      return std::any_of(list.begin(), list.end(),
                         [&](const auto& e) { return e.first == column; });
    };
    const bool mapped =
        named(m.columns) || named(m.extra) || (column == "measured_um" && !m.wide_measured.empty());
    if (!mapped) {
      diag.error(scales->get(column), "scale." + column,
                 named(m.constant) ? "a [constant] is not scaled (write it in the target unit)"
                                   : "not a column mapped under [columns], [extra] or [wide]");
    } else if (std::any_of(m.ids.begin(), m.ids.end(),
                           [&](const auto& i) { return i.column == column; })) {
      diag.error(scales->get(column), "scale." + column, "a column of [ids] is not scaled");
    }
  }
  if (!diag.ok()) throw DiagnosticsError(std::move(diag), std::string(source));
  return m;
}

Mapping read_mapping_file(const std::string& path) {
  const auto text = read_text(path);
  if (!text) cannot_open(path);
  return read_mapping_text(*text, path);
}

// ---------------------------------------------------------------------------------------------
// CSV.

namespace {

// Splits one CSV line (RFC 4180 quotes, no embedded newlines; fields separated by `sep`) into
// `fields`, reusing their storage from line to line. Returns the field count, or 0 on a bad
// quote.
std::size_t split_csv(std::string_view line, std::vector<std::string>& fields, char sep) {
  std::size_t n = 0;
  std::size_t i = 0;
  while (true) {
    if (fields.size() <= n) fields.emplace_back();
    std::string& f = fields[n++];
    f.clear();
    if (i < line.size() && line[i] == '"') {
      ++i;
      while (true) {
        if (i >= line.size()) return 0;
        if (line[i] == '"') {
          if (i + 1 < line.size() && line[i + 1] == '"') {
            f += '"';
            i += 2;
            continue;
          }
          ++i;
          break;
        }
        f += line[i++];
      }
      if (i < line.size() && line[i] != sep) return 0;
    } else {
      const std::size_t e = std::min(line.find(sep, i), line.size());
      f.assign(line.substr(i, e - i));
      i = e;
    }
    if (i >= line.size()) break;
    ++i;  // the separator
  }
  return n;
}

// A cell's number, written with `decimal` as its decimal mark and an optional leading '+';
// nullopt if it is not one finite number. With a decimal comma a '.' is refused: it is a
// thousands separator there ("1.234,5"), or a file written in another locale.
std::optional<double> cell_number(std::string_view cell, char decimal) {
  if (!cell.empty() && cell.front() == '+') {
    cell.remove_prefix(1);
    if (!cell.empty() && (cell.front() == '-' || cell.front() == '+')) return std::nullopt;
  }
  std::array<char, 128> buf{};
  if (decimal != '.') {
    // A number of more than 128 characters is no measurement.
    if (cell.size() > buf.size() || cell.find('.') != std::string_view::npos) return std::nullopt;
    std::replace_copy(cell.begin(), cell.end(), buf.begin(), decimal, '.');
    cell = std::string_view(buf.data(), cell.size());
  }
  double v = 0.0;
  const auto [p, ec] = std::from_chars(cell.data(), cell.data() + cell.size(), v);
  if (ec != std::errc() || p != cell.data() + cell.size() || !std::isfinite(v)) {
    return std::nullopt;
  }
  return v;
}

// The largest |time_s| read (see read_log).
constexpr double kMaxTimeS = 1e12;

// A number as %.9g.
std::string number_text(double v) {
  std::array<char, 32> buf{};
  std::snprintf(buf.data(), buf.size(), "%.9g", v);
  return buf.data();
}

// A hint for a header that was split at the wrong character: a header of one field holding
// another separator (a semicolon or tab export read with the default ',').
std::string separator_hint(const std::vector<std::string>& header, char sep) {
  if (header.size() != 1) return "";
  for (const char other : {';', '\t', ','}) {
    if (other != sep && header[0].find(other) != std::string::npos) {
      return other == ';'
                 ? " (the header is one field holding ';': set separator = \";\" in the map)"
             : other == '\t'
                 ? " (the header is one field holding tabs: set separator = \"\\t\" in the map)"
                 : " (the header is one field holding ',': is separator right?)";
    }
  }
  return "";
}

// The error for a cell that is not a number: with a decimal comma, one with a '.' says why.
std::string not_a_number(std::string_view cell, char decimal) {
  // Appended piece by piece: g++ 12 -O3 warns (-Wrestrict, a false positive) on "'" + string.
  std::string msg = "'";
  msg.append(cell);
  msg += "' is not a finite number";
  if (decimal == ',' && cell.find('.') != std::string_view::npos) {
    msg += " (the map's decimal mark is ',': no '.', no thousands separators)";
  } else if (decimal == '.' && cell.find(',') != std::string_view::npos) {
    msg += " (a decimal comma? set decimal = \",\" in the map)";
  }
  return msg;
}

struct Target {
  int column{-1};        // Row / Dataset column index, or -1 for measured/applied
  int special{0};        // 1 measured_um, 2 applied_um
  int source_field{-1};  // CSV field index
  double scale{1.0};
  std::string name;
  const Mapping::TextIds* ids{nullptr};  // text ids of the column, if any
};

/// The group number of a text id: its entry in the table, or its one run of digits ("T12" →
/// 12); nullopt if it has none.
std::optional<double> text_id(std::string_view cell, const Mapping::TextIds& ids) {
  if (!ids.digits) {
    for (const auto& [text, number] : ids.table) {
      if (text == cell) return number;
    }
    return std::nullopt;
  }
  constexpr std::string_view kDigits = "0123456789";
  const auto b = cell.find_first_of(kDigits);
  if (b == std::string_view::npos) return std::nullopt;
  const auto e = std::min(cell.find_first_not_of(kDigits, b), cell.size());
  if (cell.find_first_of(kDigits, e) != std::string_view::npos || e - b > 15) return std::nullopt;
  double v = 0.0;
  std::from_chars(cell.data() + b, cell.data() + e, v);
  return v;
}

/// An error at a row (its line) and, where known, a field (0-based; -1 unknown) of the column
/// named `column`.
[[noreturn]] void csv_fail(std::string_view source, std::size_t line, const std::string& column,
                           const std::string& msg, int field = -1) {
  Diagnostics diag;
  diag.error(Where{std::string(source), static_cast<int>(line), field + 1, column}, msg);
  throw DiagnosticsError(std::move(diag), std::string(source));
}

}  // namespace

void read_log(std::istream& in, std::string_view source, const Mapping& mapping,
              core::model::Dataset& data) {
  std::string line;
  std::size_t line_no = 0;
  // The column names are on one of the header's rows (a title above them, units below them).
  const auto names_line = static_cast<std::size_t>(mapping.names_row);
  std::string names;
  while (line_no < static_cast<std::size_t>(mapping.header_rows)) {
    if (!std::getline(in, line)) {
      csv_fail(source, line_no + 1, "",
               line_no == 0 ? "empty file (no header row)"
                            : "the file ends within its " + std::to_string(mapping.header_rows) +
                                  " header rows (header_rows)");
    }
    if (++line_no == 1 && line.size() >= 3 && line.compare(0, 3, "\xEF\xBB\xBF") == 0) {
      line.erase(0, 3);
    }
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line_no == names_line) names = line;
  }
  std::vector<std::string> fields;
  const char sep = mapping.separator;
  std::size_t nf = split_csv(names, fields, sep);
  if (nf == 0) csv_fail(source, names_line, "", "bad quoting in the header row");
  std::vector<std::string> header;
  for (std::size_t i = 0; i < nf; ++i) header.push_back(trim(fields[i]));
  auto find = [&](const std::string& h) -> int {
    for (std::size_t i = 0; i < header.size(); ++i) {
      if (header[i] == h) return static_cast<int>(i);
    }
    return -1;
  };
  const bool mapped = !mapping.empty();
  std::vector<Target> targets;
  std::vector<std::pair<int, double>> constants;  // column (or -1/-2 special), value
  auto scale_of = [&](const std::string& name) {
    for (const auto& [k, v] : mapping.scale) {
      if (k == name) return v;
    }
    return 1.0;
  };
  auto add_target = [&](const std::string& name, const std::string& header_name, int column,
                        int special) {
    const int f = find(header_name);
    if (f < 0) {
      csv_fail(source, names_line, header_name,
               (mapped ? "not in the header (mapped to '" + name + "')"
                       : std::string("required column missing")) +
                   separator_hint(header, sep));
    }
    const Mapping::TextIds* ids = nullptr;
    for (const auto& i : mapping.ids) {
      if (i.column == name) ids = &i;
    }
    targets.push_back({column, special, f, scale_of(name), header_name, ids});
  };
  if (data.columns.size() < cm::kStandardColumns + data.extra_columns.size()) {
    data.columns.resize(cm::kStandardColumns + data.extra_columns.size());
  }
  if (!mapped) {
    for (std::size_t c = 0; c < cm::kStandardColumns; ++c) {
      add_target(std::string(cm::kStandardColumnNames[c]), std::string(cm::kStandardColumnNames[c]),
                 static_cast<int>(c), 0);
    }
    add_target("measured_um", "measured_um", -1, 1);
    add_target("applied_um", "applied_um", -1, 2);
    for (std::size_t e = 0; e < data.extra_columns.size(); ++e) {
      add_target(data.extra_columns[e], data.extra_columns[e],
                 static_cast<int>(cm::kStandardColumns + e), 0);
    }
  } else {
    bool have_measured = !mapping.wide_measured.empty();
    for (const auto& [name, h] : mapping.columns) {
      if (name == "measured_um") {
        if (have_measured) {
          csv_fail(source, names_line, h, "measured_um mapped twice (columns and wide)");
        }
        have_measured = true;
        add_target(name, h, -1, 1);
      } else if (name == "applied_um") {
        add_target(name, h, -1, 2);
      } else {
        add_target(name, h, cm::column_index(name, {}), 0);
      }
    }
    if (!have_measured) {
      csv_fail(source, names_line, "", "the mapping names no measured_um column");
    }
    for (std::size_t e = 0; e < data.extra_columns.size(); ++e) {
      bool found = false;
      for (const auto& [name, h] : mapping.extra) {
        if (name == data.extra_columns[e]) {
          add_target(name, h, static_cast<int>(cm::kStandardColumns + e), 0);
          found = true;
        }
      }
      if (!found) {
        csv_fail(source, names_line, data.extra_columns[e],
                 "the model uses this extra column but the mapping's [extra] does not name it");
      }
    }
    for (const auto& [name, v] : mapping.constant) {
      if (name == "measured_um" || name == "applied_um") {
        constants.emplace_back(name == "measured_um" ? -1 : -2, v);
      } else {
        constants.emplace_back(cm::column_index(name, {}), v);
      }
    }
  }
  // The CSV field a column is read from, for errors; -1 where it is not read from one.
  auto field_of = [&](std::size_t column) {
    for (const Target& t : targets) {
      if (t.column == static_cast<int>(column)) return t.source_field;
    }
    return -1;
  };
  std::vector<int> wide_fields;
  for (const auto& h : mapping.wide_measured) {
    const int f = find(h);
    if (f < 0) {
      csv_fail(source, names_line, h,
               "not in the header (mapping [wide])" + separator_hint(header, sep));
    }
    wide_fields.push_back(f);
  }
  const double measured_scale = scale_of("measured_um");
  const std::size_t time_col = static_cast<std::size_t>(cm::Column::kTime);
  double last_time = -std::numeric_limits<double>::infinity();
  const std::size_t start_rows = data.rows();
  // The order over files: this file's time_s, moved after the previous files' rows when its
  // times start earlier (nccompd's log of the next warm start). A mapped foreign CSV keeps its
  // times: several of them are often parallel series (two cutters, two gauges), not one after
  // another.
  data.order_s.resize(start_rows, cm::kUnknown);
  data.row_file.resize(start_rows, 0);
  data.row_line.resize(start_rows, 0);
  // Every file starts a session (a foreign log's file, nccompd's log of a warm start).
  std::uint32_t reader_session = 0;
  for (const std::uint32_t s : data.row_session) reader_session = std::max(reader_session, s + 1);
  data.row_session.resize(start_rows, reader_session);
  const auto file_index = static_cast<std::uint32_t>(data.files.size());
  data.files.emplace_back(source);
  double previous_end = -std::numeric_limits<double>::infinity();
  for (const double v : data.order_s) {
    if (std::isfinite(v)) previous_end = std::max(previous_end, v);
  }
  double order_offset = cm::kUnknown;
  auto& cols = data.columns;
  // Columns this file provides; the others keep their length and are padded with "unknown".
  std::vector<std::size_t> present;
  for (const Target& t : targets) {
    if (t.column >= 0) present.push_back(static_cast<std::size_t>(t.column));
  }
  for (const auto& [c, v] : constants) {
    if (c >= 0) present.push_back(static_cast<std::size_t>(c));
  }
  if (!wide_fields.empty()) present.push_back(static_cast<std::size_t>(cm::Column::kPoint));
  std::sort(present.begin(), present.end());
  present.erase(std::unique(present.begin(), present.end()), present.end());
  for (std::size_t c : present) cols[c].resize(start_rows, cm::kUnknown);
  // A counter that restarts ([restarts]): each restart starts a new run (session). time_s keeps
  // its values (time since the run started, as in nccompd's log after a warm start) and the run
  // is ordered after the rows before it; any other counter continues from the run before.
  int restart_col = -1;
  if (!mapping.restart_column.empty()) {
    for (const Target& t : targets) {
      if (t.column >= 0 && static_cast<std::size_t>(t.column) < cm::kStandardColumns &&
          cm::kStandardColumnNames[static_cast<std::size_t>(t.column)] == mapping.restart_column) {
        restart_col = t.column;
      }
    }
    for (std::size_t e = 0; e < data.extra_columns.size(); ++e) {
      if (data.extra_columns[e] == mapping.restart_column) {
        restart_col = static_cast<int>(cm::kStandardColumns + e);
      }
    }
  }
  const bool time_restarts = restart_col == static_cast<int>(time_col);
  double counter_offset = 0.0;
  double counter_last = cm::kUnknown;    // the counter's value as read, in this file
  double counter_before = cm::kUnknown;  // its last continued value, before this file
  if (restart_col >= 0 && !time_restarts) {
    for (double v : cols[static_cast<std::size_t>(restart_col)]) {
      if (std::isfinite(v)) counter_before = v;
    }
  }
  // v2 (the header has machine, utc and session; architecture.md): time_s restarts at each warm
  // start, so it must only grow within a session, and a later session is ordered after the
  // rows before it. One machine per file.
  const int session_field =
      !mapped && find("machine") >= 0 && find("utc") >= 0 ? find("session") : -1;
  const int machine_field = session_field >= 0 ? find("machine") : -1;
  double session = -1.0;
  std::string machine;
  std::size_t machine_line = 0;
  double order_end = previous_end;
  cm::Row values;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (trim(line).empty()) continue;
    nf = split_csv(line, fields, sep);
    if (nf == 0) csv_fail(source, line_no, "", "bad quoting");
    if (nf > header.size()) {
      // Reading on would shift every column after the extra field (e.g. a decimal comma).
      csv_fail(source, line_no, "",
               "the row has " + std::to_string(nf) + " fields, the header " +
                   std::to_string(header.size()) +
                   (sep == ','   ? " (a decimal comma or an unquoted comma in a field?)"
                    : sep == ';' ? " (an unquoted ';' in a field?)"
                                 : " (a tab in a field?)"));
    }
    values.fill(cm::kUnknown);
    double measured = cm::kUnknown;
    double applied = mapped ? 0.0 : cm::kUnknown;
    for (const auto& [c, v] : constants) {
      if (c == -1) {
        measured = v;
      } else if (c == -2) {
        applied = v;
      } else {
        values[static_cast<std::size_t>(c)] = v;
      }
    }
    for (const Target& t : targets) {
      if (static_cast<std::size_t>(t.source_field) >= nf) {
        csv_fail(source, line_no, t.name,
                 "missing (the row has " + std::to_string(nf) + " fields, the header " +
                     std::to_string(header.size()) + ")",
                 t.source_field);
      }
      const std::string_view cell = trim_view(fields[static_cast<std::size_t>(t.source_field)]);
      double v = cm::kUnknown;
      if (!cell.empty()) {
        if (!mapped && t.column == static_cast<int>(cm::Column::kKind)) {
          const int k = kind_from_name(cell);
          if (k < 0)
            csv_fail(source, line_no, t.name,
                     "'" + std::string(cell) + "' is not tool_wear, contour or calib",
                     t.source_field);
          v = k;
        } else if (t.ids != nullptr) {
          const auto id = text_id(cell, *t.ids);
          if (!id) {
            std::string known;
            for (const auto& [text, number] : t.ids->table) {
              known += (known.empty() ? "" : ", ") + text;
            }
            csv_fail(
                source, line_no, t.name,
                "'" + std::string(cell) + "' is not a text id of [ids] " +
                    (t.ids->digits ? "(digits: one run of digits, e.g. T12)" : "(" + known + ")"),
                t.source_field);
          }
          v = *id;
        } else {
          const auto number = cell_number(cell, mapping.decimal);
          if (!number) {
            csv_fail(source, line_no, t.name, not_a_number(cell, mapping.decimal), t.source_field);
          }
          v = *number * t.scale;
        }
      }
      if (t.special == 1) {
        measured = v;
      } else if (t.special == 2) {
        applied = v;
      } else {
        values[static_cast<std::size_t>(t.column)] = v;
      }
    }
    for (std::size_t c :
         {static_cast<std::size_t>(cm::Column::kPart), static_cast<std::size_t>(cm::Column::kTool),
          static_cast<std::size_t>(cm::Column::kPoint)}) {
      if (std::isfinite(values[c]) && std::floor(values[c]) < values[c]) {
        csv_fail(source, line_no, std::string(cm::kStandardColumnNames[c]), "must be an integer",
                 field_of(c));
      }
    }
    if (!std::isfinite(values[static_cast<std::size_t>(cm::Column::kKind)])) {
      csv_fail(source, line_no, "kind",
               mapped ? "no kind (map it or set [constant] kind)" : "empty",
               field_of(static_cast<std::size_t>(cm::Column::kKind)));
    }
    if (restart_col >= 0 && std::isfinite(values[static_cast<std::size_t>(restart_col)])) {
      double& v = values[static_cast<std::size_t>(restart_col)];
      if (std::isnan(counter_last)) {
        // The file's first value: a new file is a new run already.
        if (!time_restarts && std::isfinite(counter_before) &&
            (mapping.restart_per_file || v < counter_before)) {
          counter_offset = counter_before;
        }
      } else if (!mapping.restart_per_file && v < counter_last) {
        ++reader_session;
        if (time_restarts) {
          last_time = -std::numeric_limits<double>::infinity();
          previous_end = order_end;
          order_offset = cm::kUnknown;
        } else {
          counter_offset += counter_last;
        }
      }
      counter_last = v;
      if (!time_restarts) v += counter_offset;
    }
    const double t_s = values[time_col];
    // Beyond ±1e12 s (31 700 years) a time is a date or a counter read as seconds, and the
    // order over files and runs (time + an offset) would lose its last digits: 1e12 keeps it to
    // a millisecond.
    if (std::isfinite(t_s) && std::fabs(t_s) > kMaxTimeS) {
      csv_fail(source, line_no, "time_s",
               number_text(t_s) +
                   " s is beyond ±1e12 s: map seconds (a date or a counter in ms or µs needs a "
                   "[scale])",
               field_of(time_col));
    }
    if (session_field >= 0) {
      const auto sf = static_cast<std::size_t>(session_field);
      const auto mf = static_cast<std::size_t>(machine_field);
      if (sf >= nf || mf >= nf) {
        csv_fail(source, line_no, sf >= nf ? "session" : "machine",
                 "missing (the row has " + std::to_string(nf) + " fields)",
                 sf >= nf ? session_field : machine_field);
      }
      const std::string_view cell = trim_view(fields[sf]);
      double v = -1.0;
      const auto [p, ec] = std::from_chars(cell.data(), cell.data() + cell.size(), v);
      if (ec != std::errc() || p != cell.data() + cell.size() || !(v >= 0.0) || std::floor(v) < v) {
        csv_fail(source, line_no, "session",
                 "'" + std::string(cell) + "' is not a warm-start number (an integer >= 0)",
                 session_field);
      }
      if (v < session) {
        csv_fail(source, line_no, "session",
                 "goes backwards (" + std::string(cell) + " after " +
                     std::to_string(static_cast<long long>(session)) +
                     "); the log must be in time order",
                 session_field);
      }
      if (v > session && session >= 0.0) {
        // A new warm start: its time_s counts from 0 again, after this file's rows so far.
        ++reader_session;
        last_time = -std::numeric_limits<double>::infinity();
        previous_end = order_end;
        order_offset = cm::kUnknown;
      }
      session = v;
      const std::string m(trim_view(fields[mf]));
      if (machine_line == 0) {
        machine = m;
        machine_line = line_no;
      } else if (m != machine) {
        csv_fail(source, line_no, "machine",
                 "'" + m + "' in a log of '" + machine + "' (line " + std::to_string(machine_line) +
                     "): analyze one machine's log at a time",
                 machine_field);
      }
    }
    if (std::isfinite(t_s) && std::isnan(order_offset)) {
      order_offset =
          (!mapped || time_restarts) && t_s <= previous_end ? previous_end + 1.0 - t_s : 0.0;
    }
    if (std::isfinite(t_s)) {
      if (t_s < last_time) {
        csv_fail(source, line_no, "time_s",
                 "goes backwards (" + std::to_string(t_s) + " after " + std::to_string(last_time) +
                     "); the log must be in time order",
                 field_of(time_col));
      }
      last_time = t_s;
    }
    const std::size_t copies = wide_fields.empty() ? 1 : wide_fields.size();
    for (std::size_t w = 0; w < copies; ++w) {
      double y = measured;
      if (!wide_fields.empty()) {
        const auto f = static_cast<std::size_t>(wide_fields[w]);
        if (f >= nf) csv_fail(source, line_no, mapping.wide_measured[w], "missing", wide_fields[w]);
        const std::string_view cell = trim_view(fields[f]);
        y = cm::kUnknown;
        if (!cell.empty()) {
          const auto number = cell_number(cell, mapping.decimal);
          if (!number) {
            csv_fail(source, line_no, mapping.wide_measured[w], not_a_number(cell, mapping.decimal),
                     wide_fields[w]);
          }
          // A measured_um under [columns] got its scale when read (its target's scale).
          y = *number * measured_scale;
        }
        values[static_cast<std::size_t>(cm::Column::kPoint)] = mapping.wide_points[w];
      }
      for (std::size_t c : present) cols[c].push_back(values[c]);
      data.target_um.push_back(y + (std::isfinite(applied) ? applied : 0.0));
      data.order_s.push_back(std::isfinite(t_s) ? t_s + order_offset : cm::kUnknown);
      data.row_file.push_back(file_index);
      data.row_line.push_back(static_cast<std::uint32_t>(line_no));
      data.row_session.push_back(reader_session);
      if (std::isfinite(t_s)) order_end = std::max(order_end, t_s + order_offset);
    }
  }
  for (auto& c : cols) {
    if (!c.empty()) c.resize(data.target_um.size(), cm::kUnknown);
  }
  if (data.rows() == start_rows) csv_fail(source, line_no, "", "no data rows");
}

}  // namespace nccomp::formats::model_io
