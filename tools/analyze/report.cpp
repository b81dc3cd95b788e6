#include "tools/analyze/report.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <string_view>

#include "tools/plot/plot.hpp"

namespace nccomp::tools::analyze {

namespace cm = core::model;
namespace plot = tools::plot;

namespace {

std::string num(double v, int digits = 6) {
  if (!std::isfinite(v)) return "null";
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

// A held-out RMS over no rows is no figure (it would read as 0 µm, "better").
std::string heldout_rms(const cm::ErrorStats& s) { return s.rows > 0 ? num(s.rms_um) : "null"; }

std::string json_string(const std::string& s) {
  std::string o = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') {
      o += '\\';
      o += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x",
                    static_cast<unsigned>(static_cast<unsigned char>(c)));
      o += buf;
    } else {
      o += c;
    }
  }
  return o + "\"";
}

std::string unit_suffix(const std::string& column) {
  const auto u = column.rfind('_');
  if (u == std::string::npos || u + 1 >= column.size()) return "";
  const std::string s = column.substr(u + 1);
  if (s == "s" || s == "mm" || s == "c" || s == "deg" || s == "um" || s == "rpm") return "_" + s;
  return "";
}

const cm::Term* find_term(const cm::Model& model, const cm::TermSpec& spec) {
  for (const auto& t : model.terms()) {
    if (t.spec.name == spec.name && t.spec.form == spec.form && t.spec.column == spec.column) {
      return &t;
    }
  }
  return nullptr;
}

}  // namespace

std::string safe_name(const std::string& column) {
  std::string o;
  for (char c : column) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-';
    o += ok ? c : '_';
  }
  return o;
}

std::string params_json(const cm::TermSpec& spec, const cm::Model& model,
                        const std::vector<std::string>& extras) {
  const std::string col = cm::column_name(spec.column, extras);
  const std::string unit = unit_suffix(col);
  std::ostringstream o;
  o << "{";
  switch (spec.form) {
    case cm::Form::kExpRise:
    case cm::Form::kExpGrowth:
      o << (col == "time_s" ? "\"time_constant_s\": " : "\"scale_length" + unit + "\": ")
        << num(spec.scale);
      break;
    case cm::Form::kLag:
      o << "\"time_constant_s\": " << num(spec.scale);
      break;
    case cm::Form::kSine:
      o << "\"period" << unit << "\": " << num(spec.scale);
      break;
    case cm::Form::kStep:
    case cm::Form::kHinge:
      o << "\"change_at" << unit << "\": " << num(spec.center);
      break;
    case cm::Form::kPoly:
      o << "\"degree\": " << spec.degree << ", \"center" << unit << "\": " << num(spec.center)
        << ", \"scale" << unit << "\": " << num(spec.scale);
      break;
    case cm::Form::kLinear:
      // The column's reference (coef_um per column − center), as model.toml writes it: 0 (the
      // meaning before references existed) is not written.
      if (std::abs(spec.center) > 0.0) o << "\"center" << unit << "\": " << num(spec.center, 8);
      break;
    case cm::Form::kWear:
      // coef_um: µm of error per µm of predicted wear at this edge support point.
      o << "\"wear_point\": " << num(spec.center);
      break;
    case cm::Form::kInteraction:
      // coef_um: per (a − center_a), (b − center_b), (a − center_a)(b − center_b).
      o << "\"center_a\": " << num(spec.center, 8) << ", \"center_b\": " << num(spec.center_b, 8);
      break;
    case cm::Form::kProfileWear:
      // coef_um: per w, u·w, u²·w; u = (a − center_a) / scale_a, w = b (the cut path).
      o << "\"center_a\": " << num(spec.center, 8) << ", \"scale_a\": " << num(spec.scale, 8);
      break;
    case cm::Form::kSession: {
      // The random effect's variances and its shrunk offset (BLUP) of every fitted session,
      // numbered from 1 as in the validation by session.
      o << "\"between_session_sigma_um\": " << num(spec.scale)
        << ", \"noise_sigma_um\": " << num(spec.center) << ", \"session_offsets\": [";
      const cm::Term* st = find_term(model, spec);
      for (std::size_t g = 0; st != nullptr && g < st->groups.size(); ++g) {
        o << (g ? ", " : "") << "{\"session\": " << num(st->groups[g][0] + 1.0, 12)
          << ", \"offset_um\": " << num(st->coef[g], 8) << "}";
      }
      o << "]";
      break;
    }
    default:
      break;
  }
  const cm::Term* t = find_term(model, spec);
  if (t != nullptr) {
    o << (o.tellp() > 1 ? ", " : "") << "\"coef_um\": [";
    for (std::size_t i = 0; i < t->coef.size(); ++i) o << (i ? ", " : "") << num(t->coef[i], 8);
    o << "]";
    if (spec.per[0] >= 0) {
      // coef_um holds one coefficient set per group, in this order.
      o << ", \"groups\": [";
      for (std::size_t g = 0; g < t->groups.size(); ++g) {
        o << (g ? ", " : "") << "[" << num(t->groups[g][0], 12) << ", " << num(t->groups[g][1], 12)
          << "]";
      }
      o << "]";
    }
  }
  o << "}";
  return o.str();
}

std::string summary_json(const cm::Dataset& data, const cm::AnalysisResult& result) {
  std::ostringstream o;
  o << "{\n  \"declared_rms_um\": " << num(result.declared.fitted.rms_um) << ",\n";
  o << "  \"effects\": [";
  for (std::size_t i = 0; i < result.effects.size(); ++i) {
    const auto& e = result.effects[i];
    o << (i ? "," : "") << "\n    {\"name\": " << json_string(e.spec.name) << ", \"label\": "
      << json_string(cm::effect_label(e.spec.name, e.spec.per, data.extra_columns))
      << ", \"per\": [";
    for (std::size_t k = 0; k < 2 && e.spec.per[k] >= 0; ++k) {
      o << (k ? ", " : "") << json_string(cm::column_name(e.spec.per[k], data.extra_columns));
    }
    o << "], \"column\": " << json_string(cm::term_column_name(e.spec, data.extra_columns))
      << ", \"form\": " << json_string(std::string(cm::form_name(e.spec.form)))
      << ", \"params\": " << params_json(e.spec, result.fitted_model, data.extra_columns)
      << ", \"rms_before_um\": " << num(e.before.fitted.rms_um)
      << ", \"rms_after_um\": " << num(e.after.fitted.rms_um)
      << ", \"heldout_rms_before_um\": " << heldout_rms(e.before.heldout)
      << ", \"heldout_rms_after_um\": " << heldout_rms(e.after.heldout)
      << ", \"p_value\": " << num(e.p_value, 4) << ", \"coef_ci95\": [";
    for (std::size_t k = 0; k < e.coef_ci95.size(); ++k) {
      o << (k ? ", " : "") << "[" << num(e.coef_ci95[k][0], 8) << ", " << num(e.coef_ci95[k][1], 8)
        << "]";
    }
    o << "]}";
  }
  o << (result.effects.empty() ? "" : "\n  ") << "],\n";
  o << "  \"final_rms_um\": " << num(result.final_stats.fitted.rms_um) << ",\n";
  o << "  \"noise_floor_um\": " << num(result.noise_floor_um) << ",\n";
  o << "  \"outliers\": [";
  for (std::size_t k = 0; k < result.outliers.size(); ++k) {
    const std::size_t i = result.outliers[k];
    const bool from_file = i < data.row_line.size() && data.row_line[i] > 0 &&
                           i < data.row_file.size() && data.row_file[i] < data.files.size();
    o << (k ? "," : "")
      << "\n    {\"file\": " << (from_file ? json_string(data.files[data.row_file[i]]) : "null")
      << ", \"line\": " << (from_file ? std::to_string(data.row_line[i]) : "null")
      << ", \"row\": " << i + 1 << ", \"value_um\": " << num(data.target_um[i])
      << ", \"residual_um\": " << num(result.declared_residual_um[i]) << "}";
  }
  o << (result.outliers.empty() ? "" : "\n  ") << "],\n";
  if (!result.session_folds.empty()) {
    // --validate sessions: each session held out in turn.
    o << "  \"validation\": {\"by\": \"session\", \"declared_rms_um\": "
      << num(result.sessions_declared.rms_um)
      << ", \"final_rms_um\": " << num(result.sessions_final.rms_um)
      << ", \"rows\": " << result.sessions_final.rows << ", \"sessions\": [";
    for (std::size_t k = 0; k < result.session_folds.size(); ++k) {
      const cm::SessionFold& f = result.session_folds[k];
      o << (k ? "," : "") << "\n    {\"session\": " << f.session + 1
        << ", \"first_row\": " << json_string(data.where(f.first_row))
        << ", \"rows\": " << f.final_model.rows
        << ", \"declared_rms_um\": " << num(f.declared.rms_um)
        << ", \"declared_max_um\": " << num(f.declared.max_um)
        << ", \"final_rms_um\": " << num(f.final_model.rms_um)
        << ", \"final_max_um\": " << num(f.final_model.max_um) << "}";
    }
    o << "\n  ]},\n";
  }
  {
    // The final model's 95 % prediction interval on the held-out rows and its coverage there.
    const cm::PredictionInterval& pi = result.prediction_interval;
    o << "  \"prediction_interval\": ";
    if (pi.rows == 0) {
      o << "null,\n";
    } else {
      o << "{\"level\": " << num(pi.level) << ", \"rows\": " << pi.rows
        << ", \"half_width_um\": " << num(pi.half_width_mean_um)
        << ", \"half_width_max_um\": " << num(pi.half_width_max_um)
        << ", \"coverage\": " << num(pi.coverage) << ", \"method\": "
        << (pi.method == cm::IntervalMethod::kValidation ? "\"validation\"" : "\"in_sample\"")
        << ", \"sigma_in_sample_um\": " << num(pi.sigma_in_sample_um)
        << ", \"validation_rms_um\": ";
      if (pi.validation_rows > 0) {
        o << num(pi.validation_rms_um);
      } else {
        o << "null";
      }
      o << ", \"validation_rows\": " << pi.validation_rows << "},\n";
    }
  }
  o << "  \"warnings\": [";
  for (std::size_t i = 0; i < result.warnings.size(); ++i) {
    o << (i ? "," : "") << "\n    {\"code\": " << json_string(result.warnings[i].code)
      << ", \"message\": " << json_string(result.warnings[i].message) << "}";
  }
  o << (result.warnings.empty() ? "" : "\n  ") << "]\n}\n";
  return o.str();
}

std::vector<int> plotted_columns(const cm::Dataset& data) {
  std::vector<int> out;
  for (std::size_t c = 0; c < data.columns.size(); ++c) {
    if (c == static_cast<std::size_t>(cm::Column::kKind)) continue;
    const auto& v = data.columns[c];
    double lo = HUGE_VAL;
    double hi = -HUGE_VAL;
    for (double x : v) {
      if (std::isfinite(x)) {
        lo = std::min(lo, x);
        hi = std::max(hi, x);
      }
    }
    if (hi > lo) out.push_back(static_cast<int>(c));
  }
  return out;
}

std::string residual_svg(const cm::Dataset& data, const cm::AnalysisResult& result, int column) {
  const auto& x = data.column(column);
  const std::string name = cm::column_name(column, data.extra_columns);
  // Axis title and unit from the column's name: x_mm → "x [mm]", temp_c → "temp [°C]".
  plot::Axis x_axis{name, "", plot::Scale::kLinear, false};
  static const std::array<std::pair<const char*, const char*>, 6> kUnits = {
      {{"_mm", "mm"}, {"_um", "µm"}, {"_c", "°C"}, {"_deg", "°"}, {"_rpm", "rpm"}, {"_s", "s"}}};
  for (const auto& [suffix, unit] : kUnits) {
    const std::string_view sv(suffix);
    if (name.size() > sv.size() && name.compare(name.size() - sv.size(), sv.size(), sv) == 0) {
      x_axis.title = name.substr(0, name.size() - sv.size());
      x_axis.unit = unit;
      break;
    }
  }
  if (column == static_cast<int>(cm::Column::kTime)) {
    // Seconds since 1970 (≥ 2001-09-09) are wall-clock time: shown as UTC dates.
    double lo = HUGE_VAL;
    for (double v : x) lo = std::isfinite(v) ? std::min(lo, v) : lo;
    x_axis.title = "time";
    x_axis.scale =
        lo >= 1e9 && std::isfinite(lo) ? plot::Scale::kUtcTime : plot::Scale::kElapsedTime;
  }
  plot::Figure fig;
  fig.title = "residual vs " + name;
  fig.max_points = 6000;
  const std::array<std::pair<const std::vector<double>*, const char*>, 2> panels = {
      std::pair{&result.declared_residual_um, "declared model"},
      std::pair{&result.final_residual_um, "after the added effects"}};
  // Held-out code 0 fitted, 1 held out, else left out.
  const std::array<const char*, 3> colours = {"#1f5fa8", "#e07000", "#999999"};
  for (const auto& [residual, title] : panels) {
    plot::Panel p;
    p.title = title;
    p.x = x_axis;
    p.y = plot::Axis{"residual", "µm", plot::Scale::kLinear, true};
    for (std::size_t g = 0; g < colours.size(); ++g) {
      plot::Series s;
      s.mark = plot::Mark::kPoints;
      s.colour = colours[g];
      s.opacity = 0.6;
      for (std::size_t i = 0; i < x.size() && i < residual->size() && i < result.heldout.size();
           ++i) {
        if (std::min<std::size_t>(result.heldout[i], 2) != g) continue;
        s.x.push_back(x[i]);
        s.y.push_back((*residual)[i]);
      }
      p.series.push_back(std::move(s));
    }
    fig.panels.push_back(std::move(p));
  }
  fig.legend = {{"fitted rows", colours[0], plot::Mark::kPoints, false},
                {"held-out rows", colours[1], plot::Mark::kPoints, false},
                {"left out (outliers, unseen groups)", colours[2], plot::Mark::kPoints, false}};
  return plot::render_svg(fig);
}

namespace {
// True when the reader put several of nccompd's logs one after another (time_s restarted).
bool logs_in_sequence(const cm::Dataset& data) {
  const auto& t = data.column(static_cast<int>(cm::Column::kTime));
  if (data.order_s.size() != data.rows() || t.size() != data.rows()) return false;
  for (std::size_t i = 0; i < t.size(); ++i) {
    if (std::isfinite(t[i]) && data.order_s[i] > t[i] + 0.5) return true;
  }
  return false;
}
}  // namespace

std::string report_markdown(const cm::Dataset& data, const cm::AnalysisResult& result,
                            const std::vector<std::string>& inputs,
                            const std::vector<int>& plotted) {
  std::ostringstream o;
  const auto& ex = data.extra_columns;
  o << "# nccomp analyze — report\n\n";
  o << "Inputs: ";
  for (std::size_t i = 0; i < inputs.size(); ++i) o << (i ? ", " : "") << "`" << inputs[i] << "`";
  o << "\n\nRows: " << data.rows() << " (fitted " << result.declared.fitted.rows << ", held out "
    << result.declared.heldout.rows << ": time_s ≥ " << num(result.split_time_s, 8)
    << (logs_in_sequence(data) ? " with nccompd's logs one after another" : "") << ").\n\n";
  o << "Noise floor (successive differences of the final residual per series): **"
    << num(result.noise_floor_um, 3) << " µm**.\n\n";
  if (!result.outliers.empty()) {
    o << "## Outliers (left out of every fit and figure)\n\n| row | value [µm] | residual of the "
         "declared model [µm] |\n| --- | --- | --- |\n";
    for (std::size_t i : result.outliers) {
      o << "| " << data.where(i) << " | " << num(data.target_um[i], 5) << " | "
        << num(result.declared_residual_um[i], 5) << " |\n";
    }
    o << "\n";
  }
  if (!result.warnings.empty()) {
    o << "## Warnings\n\n";
    for (const auto& w : result.warnings) o << "- **" << w.code << "**: " << w.message << "\n";
    o << "\n";
  }
  o << "## Error before and after each step\n\n";
  o << "| step | effect | column | form | parameter | fitted RMS [µm] | fitted max [µm] | held-out "
       "RMS [µm] | held-out max [µm] | p (adjusted) |\n";
  o << "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
  auto row = [&](const std::string& step, const std::string& eff, const std::string& col,
                 const std::string& form, const std::string& par, const cm::FitStats& s,
                 const std::string& p) {
    o << "| " << step << " | " << eff << " | " << col << " | " << form << " | " << par << " | "
      << num(s.fitted.rms_um, 4) << " | " << num(s.fitted.max_um, 4) << " | "
      << (s.heldout.rows > 0 ? num(s.heldout.rms_um, 4) : "—") << " | "
      << (s.heldout.rows > 0 ? num(s.heldout.max_um, 4) : "—") << " | " << p << " |\n";
  };
  row("0", "declared model", "", "", "", result.declared, "");
  for (std::size_t i = 0; i < result.effects.size(); ++i) {
    const auto& e = result.effects[i];
    // Built with append(): GCC 12 at -O3 reports a false -Wrestrict on "literal" + string.
    std::string effect("+ ");
    effect.append(cm::effect_label(e.spec.name, e.spec.per, ex));
    std::string params("`");
    params.append(params_json(e.spec, result.fitted_model, ex)).append("`");
    row(std::to_string(i + 1), effect, cm::term_column_name(e.spec, ex),
        std::string(cm::form_name(e.spec.form)), params, e.after, num(e.p_value, 3));
  }
  o << "\nAn effect is added when its nested-model F-test p-value, multiplied by the number of "
       "candidates and by its search multiplicity, is below alpha, and the held-out RMS drops.\n";
  if (result.prediction_interval.rows > 0) {
    const cm::PredictionInterval& pi = result.prediction_interval;
    o << "\nPrediction interval (" << num(100.0 * pi.level, 3) << " %) of the final model on the "
      << pi.rows << " held-out rows: half-width " << num(pi.half_width_mean_um, 3)
      << " µm on average (at most " << num(pi.half_width_max_um, 3) << " µm); it held "
      << num(100.0 * pi.coverage, 3) << " % of them. Its scale: ";
    if (pi.method == cm::IntervalMethod::kValidation) {
      o << "at each row the larger of the fit's prediction error there (its residual standard "
           "deviation, "
        << num(pi.sigma_in_sample_um, 3)
        << " µm, widened by the coefficients' error at the row) and the RMS error of the latest "
           "fitted hours predicted from the earlier ones, "
        << num(pi.validation_rms_um, 3) << " µm over " << pi.validation_rows << " rows.\n";
    } else {
      o << "the fit's residual standard deviation, " << num(pi.sigma_in_sample_um, 3)
        << " µm (in_sample: it assumes the held-out hours behave like the fitted ones).\n";
    }
  }
  if (!result.session_folds.empty()) {
    o << "\n## Leave-one-session-out validation\n\n"
         "Each session held out in turn: its rows predicted by the declared and the final terms "
         "fitted on every other session's rows.\n\n"
         "| session | first row | rows | declared RMS [µm] | declared max [µm] | final RMS [µm] | "
         "final max [µm] |\n| --- | --- | --- | --- | --- | --- | --- |\n";
    for (const cm::SessionFold& f : result.session_folds) {
      o << "| " << f.session + 1 << " | " << data.where(f.first_row) << " | " << f.final_model.rows
        << " | " << num(f.declared.rms_um, 4) << " | " << num(f.declared.max_um, 4) << " | "
        << num(f.final_model.rms_um, 4) << " | " << num(f.final_model.max_um, 4) << " |\n";
    }
    o << "| all | | " << result.sessions_final.rows << " | "
      << num(result.sessions_declared.rms_um, 4) << " | " << num(result.sessions_declared.max_um, 4)
      << " | " << num(result.sessions_final.rms_um, 4) << " | "
      << num(result.sessions_final.max_um, 4) << " |\n";
  }
  o << "\n## Candidates tried at each step (best first)\n\n";
  for (std::size_t s = 0; s < result.steps.size(); ++s) {
    o << "Step " << s + 1
      << ":\n\n| candidate | column | form | parameter | share of residual "
         "SS removed | p (adjusted) | held-out better |\n| --- | --- | --- | "
         "--- | --- | --- | --- |\n";
    for (const auto& c : result.steps[s]) {
      // Which power of its column a polynomial or a lag takes is part of what was tried.
      const bool degree = c.form == cm::Form::kPoly || c.form == cm::Form::kLag;
      o << "| " << cm::effect_label(c.name, c.per, ex) << " | " << c.column << " | "
        << cm::form_name(c.form)
        << (degree ? " (degree " + std::to_string(c.degree) + ")" : std::string()) << " | "
        << num(c.parameter, 5) << " | " << num(c.rss_reduction_fraction, 3) << " | "
        << (c.refitted ? num(c.p_value, 3) : "—") << " | "
        << (c.refitted ? (c.heldout_improved ? "yes" : "no") : "—") << " |\n";
    }
    o << "\n";
  }
  o << "## Residual against each context column\n\n";
  o << "Left: the declared model; right: after the added effects. Blue: fitted rows; orange: "
       "held-out rows; grey: rows left out (outliers, held-out rows of unseen groups).\n\n";
  for (int c : plotted) {
    const std::string name = cm::column_name(c, ex);
    o << "![residual vs " << name << "](plots/residual_" << safe_name(name) << ".svg)\n\n";
  }
  return o.str();
}

}  // namespace nccomp::tools::analyze
