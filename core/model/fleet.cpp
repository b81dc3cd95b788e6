#include "core/model/fleet.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <map>
#include <set>
#include <utility>

namespace nccomp::core::model {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// One effect whatever form the searches gave it: the warm-up of a machine whose temperature
// follows its time since the warm start is thermal_drift in time_s on one machine and in temp_c
// on the next, and both are one effect of the type (fitted in one form on every machine).
bool same_effect(const TermSpec& a, const TermSpec& b) {
  return a.name == b.name && a.per == b.per && a.kind_mask == b.kind_mask;
}

/// A machine's fit of a list of terms, with each coefficient's variance.
struct MachineFit {
  Model model;
  std::vector<std::size_t> offset;  // first coefficient of each term
  std::vector<double> variance;     // per coefficient [µm² per basis unit²]; NaN: not estimable
  double dof{0.0};                  // residual degrees of freedom
  bool collinear{false};            // rank-deficient: no coefficient is a measurement
};

/// Rows of the fleet fits: the kinds the terms and the search look at, no outlier of the
/// machine's own search, a finite target.
std::vector<std::uint8_t> fleet_rows(const Dataset& data, const AnalysisConfig& config,
                                     const AnalysisResult& search) {
  std::uint8_t mask = config.search.kind_mask;
  for (const TermSpec& s : config.declared) mask = static_cast<std::uint8_t>(mask | s.kind_mask);
  std::vector<std::uint8_t> use(data.rows(), 0);
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  for (std::size_t i = 0; i < data.rows(); ++i) {
    if (!std::isfinite(data.target_um[i])) continue;
    const double k = kind.empty() ? kNaN : kind[i];
    if (!std::isfinite(k) || k < 0.0 || k > 2.0) continue;
    if ((static_cast<unsigned>(mask) >> static_cast<unsigned>(k) & 1U) == 0U) continue;
    use[i] = 1;
  }
  for (const std::size_t o : search.outliers) {
    if (o < use.size()) use[o] = 0;
  }
  return use;
}

MachineFit fit_machine(const FleetMachine& m, const std::vector<TermSpec>& specs,
                       const std::vector<std::uint8_t>& use) {
  MachineFit f;
  FitInfo info;
  info.want_variance = true;
  try {
    f.model = fit_terms(m.data, specs, use, &info);
  } catch (const AnalysisError& e) {
    throw AnalysisError("machine '" + m.id + "': " + e.what());
  }
  const std::vector<double> r = residuals(m.data, f.model);
  double rss = 0.0;
  for (std::size_t i = 0; i < r.size(); ++i) {
    if (use[i] != 0U && std::isfinite(r[i])) rss += r[i] * r[i];
  }
  f.dof = static_cast<double>(info.rows) - static_cast<double>(info.rank);
  const double sigma2 = f.dof > 0.0 ? rss / f.dof : kNaN;
  std::size_t offset = 0;
  for (const Term& t : f.model.terms()) {
    f.offset.push_back(offset);
    offset += t.coef.size();
  }
  f.variance.assign(offset, kNaN);
  // A rank-deficient design has no unique coefficients: none of them is a measurement.
  f.collinear = info.rank < info.parameters;
  if (!f.collinear && info.coef_variance.size() == offset) {
    for (std::size_t k = 0; k < offset; ++k) f.variance[k] = info.coef_variance[k] * sigma2;
  }
  return f;
}

/// The machine's `specs` fitted on its target minus `fixed`'s prediction.
MachineFit fit_given(const FleetMachine& m, const Model& fixed, const std::vector<TermSpec>& specs,
                     const std::vector<std::uint8_t>& use) {
  FleetMachine rest{m.id, m.data};
  rest.data.target_um = residuals(m.data, fixed);
  return fit_machine(rest, specs, use);
}

/// The term at the type mean of each coefficient (0 where no machine has one).
Term type_term(const FleetTerm& ft) {
  Term type;
  type.spec = ft.spec;
  const std::size_t nb = basis_count(ft.spec.form, ft.spec.degree);
  // Coefficients are grouped by key with the basis innermost (collect()'s map order).
  for (const FleetCoefficient& c : ft.coefficients) {
    if (type.groups.empty() || type.groups.back() != c.group) {
      type.groups.push_back(c.group);
      type.coef.resize(type.groups.size() * nb, 0.0);
    }
    if (std::isfinite(c.effect.mean))
      type.coef[(type.groups.size() - 1) * nb + c.basis] = c.effect.mean;
  }
  return type;
}

bool usable_variance(double v) { return std::isfinite(v) && v > 0.0; }

/// Every coefficient of term `index[m]` of each machine's fit (index[m] < 0: not on machine m).
std::vector<FleetCoefficient> collect(const std::vector<MachineFit>& fits,
                                      const std::vector<int>& index) {
  std::map<std::pair<std::array<double, 2>, std::size_t>, FleetCoefficient> by_key;
  for (std::size_t m = 0; m < fits.size(); ++m) {
    if (index[m] < 0) continue;
    const auto t = static_cast<std::size_t>(index[m]);
    const Term& term = fits[m].model.terms()[t];
    const std::size_t nb = basis_count(term.spec.form, term.spec.degree);
    for (std::size_t g = 0; g < term.groups.size(); ++g) {
      for (std::size_t b = 0; b < nb; ++b) {
        FleetCoefficient& c = by_key[{term.groups[g], b}];
        if (c.estimate.empty()) {
          c.group = term.groups[g];
          c.basis = b;
          c.estimate.assign(fits.size(), kNaN);
          c.variance.assign(fits.size(), kNaN);
        }
        const double v = fits[m].variance[fits[m].offset[t] + g * nb + b];
        if (usable_variance(v)) {
          c.estimate[m] = term.coef[g * nb + b];
          c.variance[m] = v;
        }
      }
    }
  }
  std::vector<FleetCoefficient> out;
  for (auto& [key, c] : by_key) out.push_back(std::move(c));
  return out;
}

/// Fills c.effect over the machines with an estimate and not left out (`out[m]` != 0); BLUP NaN
/// elsewhere. Returns the number of machines used.
std::size_t shrink(FleetCoefficient& c, const std::vector<std::uint8_t>& out = {}) {
  std::vector<double> est;
  std::vector<double> var;
  std::vector<std::size_t> who;
  for (std::size_t m = 0; m < c.estimate.size(); ++m) {
    if ((m < out.size() && out[m] != 0U) || !usable_variance(c.variance[m])) continue;
    est.push_back(c.estimate[m]);
    var.push_back(c.variance[m]);
    who.push_back(m);
  }
  c.effect = RandomEffect{};
  c.effect.blup.assign(c.estimate.size(), kNaN);
  c.effect.own_weight.assign(c.estimate.size(), kNaN);
  if (est.empty()) return 0;
  const RandomEffect re = random_effect(est, var);
  c.effect.mean = re.mean;
  c.effect.mean_variance = re.mean_variance;
  c.effect.tau2 = re.tau2;
  for (std::size_t j = 0; j < who.size(); ++j) {
    c.effect.blup[who[j]] = re.blup[j];
    c.effect.own_weight[who[j]] = re.own_weight[j];
  }
  return who.size();
}

/// Upper-tail p of the Wald statistic Σ β² / v over `coef` (F with (K, dof)); 1 when any
/// coefficient is not estimable.
double wald_p(const std::vector<double>& coef, const std::vector<double>& var, double dof) {
  if (coef.empty() || !(dof > 0.0)) return 1.0;
  double chi2 = 0.0;
  for (std::size_t k = 0; k < coef.size(); ++k) {
    if (!usable_variance(var[k]) || !std::isfinite(coef[k])) return 1.0;
    chi2 += coef[k] * coef[k] / var[k];
  }
  const auto kk = static_cast<double>(coef.size());
  return f_distribution_upper_tail(chi2 / kk, kk, dof);
}

/// Test of the type mean of a term's coefficients over the machines except `skip`: F with
/// (K, machines − 1), the small-sample reference of a mean whose variance includes an
/// estimated τ².
double type_mean_p(std::vector<FleetCoefficient> coefs, std::size_t skip) {
  std::vector<std::uint8_t> out(coefs.empty() ? 0 : coefs[0].estimate.size(), 0);
  if (skip < out.size()) out[skip] = 1;
  std::vector<double> mean;
  std::vector<double> var;
  std::size_t used = 0;
  for (FleetCoefficient& c : coefs) {
    used = std::max(used, shrink(c, out));
    mean.push_back(c.effect.mean);
    var.push_back(c.effect.mean_variance);
  }
  if (used < 2) return 1.0;
  return wald_p(mean, var, static_cast<double>(used - 1));
}

ErrorStats rms_of(const Dataset& data, const Model& model, const std::vector<std::uint8_t>& use) {
  const std::vector<double> r = residuals(data, model);
  ErrorStats e;
  double ss = 0.0;
  for (std::size_t i = 0; i < r.size(); ++i) {
    if (use[i] == 0U || !std::isfinite(r[i])) continue;
    ss += r[i] * r[i];
    e.max_um = std::max(e.max_um, std::abs(r[i]));
    ++e.rows;
  }
  e.rms_um = e.rows > 0 ? std::sqrt(ss / static_cast<double>(e.rows)) : 0.0;
  return e;
}

}  // namespace

std::string_view fleet_role_name(FleetRole role) noexcept {
  switch (role) {
    case FleetRole::kDeclared:
      return "declared";
    case FleetRole::kCommon:
      return "common";
    case FleetRole::kMachine:
      return "machine";
    case FleetRole::kUnsupported:
      return "unsupported";
  }
  return "?";
}

RandomEffect random_effect(const std::vector<double>& estimate,
                           const std::vector<double>& variance) {
  const std::size_t k = estimate.size();
  if (k == 0 || variance.size() != k) throw AnalysisError("random effect: no estimates");
  double sw = 0.0;
  double sw2 = 0.0;
  double swb = 0.0;
  for (std::size_t i = 0; i < k; ++i) {
    if (!usable_variance(variance[i]) || !std::isfinite(estimate[i])) {
      throw AnalysisError("random effect: an estimate or its variance is not usable");
    }
    const double w = 1.0 / variance[i];
    sw += w;
    sw2 += w * w;
    swb += w * estimate[i];
  }
  const double fixed_mean = swb / sw;
  double q = 0.0;
  for (std::size_t i = 0; i < k; ++i) {
    const double d = estimate[i] - fixed_mean;
    q += d * d / variance[i];
  }
  RandomEffect re;
  // DerSimonian–Laird: Q's expectation is (k − 1) + τ² (Σw − Σw²/Σw).
  const double denominator = sw - sw2 / sw;
  re.tau2 = k > 1 && denominator > 0.0
                ? std::max(0.0, (q - static_cast<double>(k - 1)) / denominator)
                : 0.0;
  double sw_star = 0.0;
  double swb_star = 0.0;
  for (std::size_t i = 0; i < k; ++i) {
    const double w = 1.0 / (variance[i] + re.tau2);
    sw_star += w;
    swb_star += w * estimate[i];
  }
  re.mean = swb_star / sw_star;
  re.mean_variance = 1.0 / sw_star;
  for (std::size_t i = 0; i < k; ++i) {
    // One machine: nothing to shrink toward but itself.
    const double own = k == 1 ? 1.0 : re.tau2 / (re.tau2 + variance[i]);
    re.own_weight.push_back(own);
    re.blup.push_back(re.mean + own * (estimate[i] - re.mean));
  }
  return re;
}

FleetResult analyze_fleet(const std::vector<FleetMachine>& machines, const AnalysisConfig& config) {
  const std::size_t nm = machines.size();
  if (nm < 2) throw AnalysisError("a fleet needs at least two machines");
  std::set<std::string> ids;
  for (const FleetMachine& m : machines) {
    if (!ids.insert(m.id).second) throw AnalysisError("machine '" + m.id + "' given twice");
    if (m.data.extra_columns != machines[0].data.extra_columns) {
      throw AnalysisError("machine '" + m.id + "': other extra columns than machine '" +
                          machines[0].id + "'");
    }
  }
  FleetResult result;
  result.alpha = config.alpha;
  const std::vector<std::string>& extras = machines[0].data.extra_columns;

  // 1. Each machine searched on its own, at alpha / machines.
  AnalysisConfig per_machine = config;
  per_machine.alpha = config.alpha / static_cast<double>(nm);
  std::vector<std::vector<std::uint8_t>> use(nm);
  for (std::size_t m = 0; m < nm; ++m) {
    result.machines.push_back(machines[m].id);
    try {
      result.searches.push_back(analyze(machines[m].data, per_machine));
    } catch (const AnalysisError& e) {
      throw AnalysisError("machine '" + machines[m].id + "': " + e.what());
    }
    use[m] = fleet_rows(machines[m].data, config, result.searches[m]);
  }
  for (const TermSpec& s : config.declared) {
    FleetTerm t;
    t.spec = s;
    result.terms.push_back(std::move(t));
  }
  const std::size_t nd = result.terms.size();
  for (std::size_t m = 0; m < nm; ++m) {
    const AnalysisResult& search = result.searches[m];
    // The effect in the form and with the non-linear parameter of the search with the smallest
    // p-value.
    for (const AddedEffect& e : search.effects) {
      auto it =
          std::find_if(result.terms.begin() + static_cast<std::ptrdiff_t>(nd), result.terms.end(),
                       [&](const FleetTerm& t) { return same_effect(t.spec, e.spec); });
      if (it == result.terms.end()) {
        FleetTerm t;
        t.spec = e.spec;
        t.role = FleetRole::kUnsupported;
        t.type_p_value = e.p_value;  // the best p so far, replaced by the fleet's below
        result.terms.push_back(std::move(t));
        it = result.terms.end() - 1;
      } else if (e.p_value < it->type_p_value) {
        it->spec = e.spec;
        it->type_p_value = e.p_value;
      }
      if (it->found_on.empty() || it->found_on.back() != m) it->found_on.push_back(m);
    }
  }
  const std::size_t nf = result.terms.size() - nd;

  // 2. Where each found effect is, one after the other (those found by more machines first):
  //    each fitted on every machine together with the terms that machine already has.
  std::vector<std::size_t> order;
  for (std::size_t t = nd; t < result.terms.size(); ++t) order.push_back(t);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return result.terms[a].found_on.size() > result.terms[b].found_on.size();
  });
  std::vector<std::vector<TermSpec>> kept(nm, config.declared);
  const double tests = static_cast<double>(nm * nf);
  for (const std::size_t t : order) {
    FleetTerm& ft = result.terms[t];
    std::vector<MachineFit> fits;
    std::vector<int> index(nm);
    std::vector<std::string> collinear;
    std::size_t significant = 0;
    std::size_t where = 0;
    for (std::size_t m = 0; m < nm; ++m) {
      std::vector<TermSpec> specs = kept[m];
      index[m] = static_cast<int>(specs.size());
      specs.push_back(ft.spec);
      fits.push_back(fit_machine(machines[m], specs, use[m]));
      const MachineFit& f = fits.back();
      if (f.collinear) collinear.push_back(machines[m].id);
      const Term& term = f.model.terms().back();
      const auto first = static_cast<std::ptrdiff_t>(f.offset.back());
      const std::vector<double> var(
          f.variance.begin() + first,
          f.variance.begin() + first + static_cast<std::ptrdiff_t>(term.coef.size()));
      const double p = std::min(1.0, tests * wald_p(term.coef, var, f.dof));
      ft.p_value.push_back(p);
      ft.significant.push_back(static_cast<std::uint8_t>(p < config.alpha));
      if (p < config.alpha) {
        ++significant;
        where = m;
      }
    }
    if (!collinear.empty()) {
      std::string list;
      for (const auto& id : collinear) list += (list.empty() ? "" : ", ") + id;
      result.warnings.push_back(
          {"fleet_overlap", "effect '" + effect_label(ft.spec.name, ft.spec.per, extras) +
                                "' overlaps the terms already in the model of " + list +
                                " (collinear: a part of it is one of them, e.g. an "
                                "interaction's main effect): not tested there"});
    }
    const std::vector<FleetCoefficient> coefs = collect(fits, index);
    const std::size_t skip = significant == 1 ? where : std::numeric_limits<std::size_t>::max();
    ft.type_p_value = std::min(1.0, static_cast<double>(nf) * type_mean_p(coefs, skip));
    const bool type_mean = ft.type_p_value < config.alpha;
    if (significant == 1 && !type_mean) {
      ft.role = FleetRole::kMachine;
      ft.owner = where;
      kept[where].push_back(ft.spec);
    } else if (significant >= 2 || type_mean) {
      ft.role = FleetRole::kCommon;
      for (auto& k : kept) k.push_back(ft.spec);
    } else {
      ft.role = FleetRole::kUnsupported;
    }
  }

  // 3. Each machine fitted with its terms; the common effects' coefficients shrunk toward the
  //    type (BLUP).
  std::vector<MachineFit> fits;
  std::vector<std::vector<int>> index(result.terms.size(), std::vector<int>(nm, -1));
  for (std::size_t m = 0; m < nm; ++m) {
    std::vector<TermSpec> specs;
    for (std::size_t t = 0; t < result.terms.size(); ++t) {
      const FleetTerm& ft = result.terms[t];
      const bool on = ft.role == FleetRole::kDeclared || ft.role == FleetRole::kCommon ||
                      (ft.role == FleetRole::kMachine && ft.owner == m);
      if (!on) continue;
      index[t][m] = static_cast<int>(specs.size());
      specs.push_back(ft.spec);
    }
    fits.push_back(fit_machine(machines[m], specs, use[m]));
    if (fits.back().collinear) {
      result.warnings.push_back(
          {"fleet_collinear", "machine '" + machines[m].id +
                                  "': its terms are collinear on its rows: its coefficients do "
                                  "not enter the type's, its model has its own least-squares "
                                  "values"});
    }
  }
  std::vector<std::vector<Term>> common_blup(nm);
  std::vector<Term> common_type;
  for (std::size_t t = nd; t < result.terms.size(); ++t) {
    FleetTerm& ft = result.terms[t];
    if (ft.role != FleetRole::kCommon) continue;
    ft.coefficients = collect(fits, index[t]);
    for (FleetCoefficient& c : ft.coefficients) shrink(c);
    const std::size_t nb = basis_count(ft.spec.form, ft.spec.degree);
    for (std::size_t m = 0; m < nm; ++m) {
      Term term = fits[m].model.terms()[static_cast<std::size_t>(index[t][m])];
      for (std::size_t g = 0; g < term.groups.size(); ++g) {
        for (const FleetCoefficient& c : ft.coefficients) {
          if (c.group == term.groups[g] && std::isfinite(c.effect.blup[m])) {
            term.coef[g * nb + c.basis] = c.effect.blup[m];
          }
        }
      }
      common_blup[m].push_back(std::move(term));
    }
    common_type.push_back(type_term(ft));
  }
  // 4. With the common effects held at the machine's BLUP (its model) or at the type mean (the
  //    type's), the machine's declared terms and its own effects refitted: they are its set-up
  //    (checkpoint constants) and absorb, within the range of its rows, what the shrinkage moved.
  //    Shrinking them coefficient by coefficient would ignore how they co-vary with the shrunk
  //    ones (a constant and a slope in temp_c far from 0 °C) and break the machine's fit.
  std::vector<std::vector<Term>> machine_terms(nm);
  std::vector<MachineFit> type_fits;
  std::vector<std::uint8_t> has_own(nm, 0);
  for (std::size_t m = 0; m < nm; ++m) {
    std::vector<TermSpec> specs = config.declared;
    for (std::size_t t = nd; t < result.terms.size(); ++t) {
      const FleetTerm& ft = result.terms[t];
      if (ft.role == FleetRole::kMachine && ft.owner == m) {
        specs.push_back(ft.spec);
        has_own[m] = 1;
      }
    }
    machine_terms[m] = common_blup[m];
    if (specs.empty()) continue;
    const MachineFit own = fit_given(machines[m], Model(extras, common_blup[m]), specs, use[m]);
    for (const Term& t : own.model.terms()) machine_terms[m].push_back(t);
    type_fits.push_back(fit_given(machines[m], Model(extras, common_type), specs, use[m]));
  }
  std::vector<Term> type_terms;
  for (std::size_t t = 0; t < nd && !type_fits.empty(); ++t) {
    FleetTerm& ft = result.terms[t];
    ft.coefficients = collect(type_fits, std::vector<int>(nm, static_cast<int>(t)));
    // A machine's own effect is not centred (a wear curve from path 0, a polynomial about its
    // rows' mean): its constants carry part of it. The type's constants come from the other
    // machines while at least two are left.
    const auto plain = std::count(has_own.begin(), has_own.end(), 0);
    for (FleetCoefficient& c : ft.coefficients) {
      shrink(c, plain >= 2 ? has_own : std::vector<std::uint8_t>{});
      // Not shrunk: each machine's model has its own (step 4).
      std::fill(c.effect.blup.begin(), c.effect.blup.end(), kNaN);
      std::fill(c.effect.own_weight.begin(), c.effect.own_weight.end(), kNaN);
    }
    type_terms.push_back(type_term(ft));
  }
  for (Term& t : common_type) type_terms.push_back(std::move(t));
  result.type_model = Model(extras, type_terms);
  for (std::size_t m = 0; m < nm; ++m) {
    result.machine_models.push_back(Model(extras, machine_terms[m]));
    FleetFit f;
    f.own = rms_of(machines[m].data, result.machine_models[m], use[m]);
    f.type = rms_of(machines[m].data, result.type_model, use[m]);
    f.alone = rms_of(machines[m].data, result.searches[m].final_model, use[m]);
    result.fits.push_back(f);
    for (const Warning& w : result.searches[m].warnings) {
      result.warnings.push_back({w.code, "machine '" + machines[m].id + "': " + w.message});
    }
  }
  return result;
}

}  // namespace nccomp::core::model
