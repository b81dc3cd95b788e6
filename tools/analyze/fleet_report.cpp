// summary.json and report.md of a fleet run (fleet.hpp).
#include <array>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

#include "tools/analyze/fleet.hpp"

namespace nccomp::tools::analyze {

namespace {

namespace cm = core::model;

std::string num(double v, int digits = 6) {
  if (!std::isfinite(v)) return "null";
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

// Machine ids and column names are checked names; the escaping keeps the JSON valid anyway.
std::string json_string(const std::string& s) {
  std::string o = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') o += '\\';
    if (static_cast<unsigned char>(c) >= 0x20) o += c;
  }
  return o + "\"";
}

std::string group_text(const cm::TermSpec& spec, const std::array<double, 2>& g,
                       const std::vector<std::string>& extras) {
  std::string o;
  for (std::size_t k = 0; k < 2; ++k) {
    if (spec.per[k] < 0) continue;
    if (!o.empty()) o += ", ";
    o += cm::column_name(spec.per[k], extras) + " " + num(g[k]);
  }
  return o.empty() ? "all" : o;
}

// A constant has no column.
std::string column_text(const cm::TermSpec& spec, const std::vector<std::string>& extras) {
  return spec.column < 0 ? "" : cm::term_column_name(spec, extras);
}

std::string machines_json(const cm::FleetResult& r, const std::vector<std::size_t>& which) {
  std::string o = "[";
  for (std::size_t i = 0; i < which.size(); ++i) {
    o += (i ? ", " : "") + json_string(r.machines[which[i]]);
  }
  return o + "]";
}

std::vector<std::size_t> significant_on(const cm::FleetTerm& t) {
  std::vector<std::size_t> out;
  for (std::size_t m = 0; m < t.significant.size(); ++m) {
    if (t.significant[m] != 0U) out.push_back(m);
  }
  return out;
}

}  // namespace

std::string fleet_summary_json(const cm::FleetResult& r, const std::vector<std::string>& extras,
                               const std::vector<std::pair<std::string, std::string>>& models) {
  std::ostringstream o;
  const std::size_t nm = r.machines.size();
  std::vector<std::size_t> all(nm);
  for (std::size_t m = 0; m < nm; ++m) all[m] = m;
  o << "{\n  \"fleet\": {\n    \"machines\": " << machines_json(r, all)
    << ",\n    \"alpha\": " << num(r.alpha, 4)
    << ",\n    \"machine_alpha\": " << num(r.alpha / static_cast<double>(nm), 4)
    << ",\n    \"terms\": [";
  for (std::size_t i = 0; i < r.terms.size(); ++i) {
    const cm::FleetTerm& t = r.terms[i];
    o << (i ? "," : "") << "\n      {\"name\": " << json_string(t.spec.name)
      << ", \"label\": " << json_string(cm::effect_label(t.spec.name, t.spec.per, extras))
      << ", \"column\": " << json_string(column_text(t.spec, extras))
      << ", \"form\": " << json_string(std::string(cm::form_name(t.spec.form)))
      << ", \"role\": " << json_string(std::string(cm::fleet_role_name(t.role)));
    if (t.role == cm::FleetRole::kMachine)
      o << ", \"machine\": " << json_string(r.machines[t.owner]);
    if (t.role != cm::FleetRole::kDeclared) {
      o << ", \"found_on\": " << machines_json(r, t.found_on)
        << ", \"significant_on\": " << machines_json(r, significant_on(t)) << ", \"p_value\": {";
      for (std::size_t m = 0; m < t.p_value.size(); ++m) {
        o << (m ? ", " : "") << json_string(r.machines[m]) << ": " << num(t.p_value[m], 4);
      }
      o << "}, \"type_p_value\": " << num(t.type_p_value, 4);
    }
    o << ", \"coefficients\": [";
    for (std::size_t k = 0; k < t.coefficients.size(); ++k) {
      const cm::FleetCoefficient& c = t.coefficients[k];
      o << (k ? "," : "")
        << "\n        {\"group\": " << json_string(group_text(t.spec, c.group, extras))
        << ", \"basis\": " << c.basis << ", \"type_mean\": " << num(c.effect.mean, 8)
        << ", \"type_mean_sd\": " << num(std::sqrt(c.effect.mean_variance), 4)
        << ", \"between_machine_sd\": " << num(std::sqrt(c.effect.tau2), 4) << ", \"machines\": {";
      for (std::size_t m = 0; m < nm; ++m) {
        o << (m ? ", " : "") << json_string(r.machines[m])
          << ": {\"estimate\": " << num(c.estimate[m], 8)
          << ", \"sd\": " << num(std::sqrt(c.variance[m]), 4)
          << ", \"blup\": " << num(c.effect.blup[m], 8)
          << ", \"own_weight\": " << num(c.effect.own_weight[m], 4) << "}";
      }
      o << "}}";
    }
    o << (t.coefficients.empty() ? "" : "\n      ") << "]}";
  }
  o << "\n    ],\n    \"fit\": {";
  for (std::size_t m = 0; m < nm; ++m) {
    const cm::FleetFit& f = r.fits[m];
    o << (m ? "," : "") << "\n      " << json_string(r.machines[m]) << ": {\"rows\": " << f.own.rows
      << ", \"rms_own_model_um\": " << num(f.own.rms_um)
      << ", \"rms_type_model_um\": " << num(f.type.rms_um)
      << ", \"rms_alone_um\": " << num(f.alone.rms_um) << ", \"effects_alone\": [";
    const auto& effects = r.searches[m].effects;
    for (std::size_t e = 0; e < effects.size(); ++e) {
      o << (e ? ", " : "")
        << json_string(cm::effect_label(effects[e].spec.name, effects[e].spec.per, extras));
    }
    o << "]}";
  }
  o << "\n    },\n    \"models\": {";
  for (std::size_t i = 0; i < models.size(); ++i) {
    o << (i ? ", " : "") << json_string(models[i].first) << ": " << json_string(models[i].second);
  }
  o << "}\n  },\n  \"warnings\": [";
  for (std::size_t i = 0; i < r.warnings.size(); ++i) {
    o << (i ? "," : "") << "\n    {\"code\": " << json_string(r.warnings[i].code)
      << ", \"message\": " << json_string(r.warnings[i].message) << "}";
  }
  o << (r.warnings.empty() ? "" : "\n  ") << "]\n}\n";
  return o.str();
}

std::string fleet_report_markdown(const cm::FleetResult& r, const std::vector<std::string>& extras,
                                  const std::vector<MachineLogs>& inputs,
                                  const std::string& config_path) {
  std::ostringstream o;
  const std::size_t nm = r.machines.size();
  o << "# nccomp analyze — fleet report\n\n";
  o << "Config: `" << config_path << "`. Machines and their logs:\n\n";
  for (const MachineLogs& m : inputs) {
    o << "- **" << m.machine << "**:";
    for (const auto& f : m.files) o << " `" << f << "`";
    o << " ([its own search](machines/" << m.machine << "/report.md))\n";
  }
  o << "\n## Fleet\n\nEach machine's log was searched on its own at alpha / " << nm << " = "
    << num(r.alpha / static_cast<double>(nm), 3)
    << "; every effect found was then fitted on every machine (Wald test, p-values multiplied "
       "by machines × effects). **common**: significant on two or more machines, or the type "
       "mean is; **machine**: significant on one machine only, the others' mean not different "
       "from 0; **unsupported**: not confirmed, left out of every model.\n\n";
  o << "| effect | column | form | role | found by the search of | significant on | type mean "
       "p |\n| --- | --- | --- | --- | --- | --- | --- |\n";
  for (const cm::FleetTerm& t : r.terms) {
    if (t.role == cm::FleetRole::kDeclared) continue;
    auto list = [&](const std::vector<std::size_t>& v) {
      std::string s;
      for (std::size_t m : v) s += (s.empty() ? "" : ", ") + r.machines[m];
      return s.empty() ? std::string("—") : s;
    };
    std::string role(cm::fleet_role_name(t.role));
    if (t.role == cm::FleetRole::kMachine) role += " (" + r.machines[t.owner] + ")";
    o << "| " << cm::effect_label(t.spec.name, t.spec.per, extras) << " | "
      << cm::term_column_name(t.spec, extras) << " | " << cm::form_name(t.spec.form) << " | "
      << role << " | " << list(t.found_on) << " | " << list(significant_on(t)) << " | "
      << num(t.type_p_value, 3) << " |\n";
  }
  o << "\n## Coefficients: each machine, shrunk toward the type\n\n"
       "Per coefficient: the machines' estimates β ± sd, the between-machine spread τ "
       "(DerSimonian–Laird), the type mean μ, and each machine's BLUP μ + w (β − μ) with w = τ² / "
       "(τ² + sd²). Declared terms are not shrunk: their values are each machine's given the "
       "common effects at the type mean, and μ is the type's value (its prior).\n\n";
  for (const cm::FleetTerm& t : r.terms) {
    if (t.coefficients.empty()) continue;
    o << "### " << cm::effect_label(t.spec.name, t.spec.per, extras) << " ("
      << (t.spec.column < 0 ? "" : column_text(t.spec, extras) + ", ") << cm::form_name(t.spec.form)
      << ", " << cm::fleet_role_name(t.role) << ")\n\n| group | basis | type mean μ | τ |";
    for (std::size_t m = 0; m < nm; ++m) o << " " << r.machines[m] << ": β ± sd → BLUP |";
    o << "\n| --- | --- | --- | --- |";
    for (std::size_t m = 0; m < nm; ++m) o << " --- |";
    o << "\n";
    for (const cm::FleetCoefficient& c : t.coefficients) {
      o << "| " << group_text(t.spec, c.group, extras) << " | " << c.basis << " | "
        << num(c.effect.mean, 4) << " ± " << num(std::sqrt(c.effect.mean_variance), 2) << " | "
        << num(std::sqrt(c.effect.tau2), 3) << " |";
      for (std::size_t m = 0; m < nm; ++m) {
        if (std::isfinite(c.estimate[m])) {
          o << " " << num(c.estimate[m], 4) << " ± " << num(std::sqrt(c.variance[m]), 2);
          if (std::isfinite(c.effect.blup[m])) o << " → " << num(c.effect.blup[m], 4);
          o << " |";
        } else {
          o << " — |";
        }
      }
      o << "\n";
    }
    o << "\n";
  }
  o << "## Error of each machine's rows [µm RMS]\n\n| machine | rows | its fleet model | the "
       "type's "
       "prior | its own search alone | effects of its own search |\n| --- | --- | --- | --- | "
       "--- | --- |\n";
  for (std::size_t m = 0; m < nm; ++m) {
    const cm::FleetFit& f = r.fits[m];
    std::string effects;
    for (const auto& e : r.searches[m].effects) {
      effects += (effects.empty() ? "" : ", ") + cm::effect_label(e.spec.name, e.spec.per, extras);
    }
    o << "| " << r.machines[m] << " | " << f.own.rows << " | " << num(f.own.rms_um, 4) << " | "
      << num(f.type.rms_um, 4) << " | " << num(f.alone.rms_um, 4) << " | "
      << (effects.empty() ? "—" : effects) << " |\n";
  }
  o << "\nModels: `model-<machine>.toml` for each machine, `model-type.toml` (the declared and "
       "common effects at the type mean) for a machine of this type without data.\n";
  if (!r.warnings.empty()) {
    o << "\n## Warnings\n\n";
    for (const auto& w : r.warnings) o << "- **" << w.code << "**: " << w.message << "\n";
  }
  return o.str();
}

}  // namespace nccomp::tools::analyze
