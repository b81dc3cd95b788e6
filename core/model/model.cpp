#include "core/model/model.hpp"

#include <cmath>
#include <numbers>
#include <utility>

namespace nccomp::core::model {

namespace {
constexpr std::array<std::string_view, 12> kFormNames = {
    "constant", "linear",     "poly",  "exp_rise", "sine",        "step",
    "lag",      "exp_growth", "hinge", "wear",     "interaction", "session"};

bool same(double a, double b) noexcept {
  // Group keys are integers (tool, point, kind) stored as doubles; exact equality is intended.
  return !(a < b) && !(b < a);
}

// The session learned is the row's (never before the first one: NaN is no session).
bool same_session(double learned, double row) noexcept {
  return std::isfinite(learned) && same(learned, row);
}
}  // namespace

Row unknown_row() noexcept {
  Row r;
  r.fill(kUnknown);
  return r;
}

std::string_view form_name(Form f) noexcept { return kFormNames[static_cast<std::size_t>(f)]; }

bool parse_form(std::string_view name, Form& out) noexcept {
  for (std::size_t i = 0; i < kFormNames.size(); ++i) {
    if (kFormNames[i] == name) {
      out = static_cast<Form>(i);
      return true;
    }
  }
  return false;
}

std::size_t basis_count(Form f, int degree) noexcept {
  switch (f) {
    case Form::kSine:
      return 2;
    case Form::kInteraction:
      return 3;
    case Form::kPoly:
      return degree < 1 ? 1 : (degree > 3 ? 3 : static_cast<std::size_t>(degree));
    default:
      return 1;
  }
}

bool has_nonlinear_parameter(Form f) noexcept {
  return f == Form::kExpRise || f == Form::kSine || f == Form::kStep || f == Form::kLag ||
         f == Form::kExpGrowth || f == Form::kHinge;
}

std::size_t term_basis(const TermSpec& spec, const Row& row, double aux,
                       std::span<double, kMaxBasis> out) noexcept {
  const double kind = row[static_cast<std::size_t>(Column::kKind)];
  if (!std::isfinite(kind) || kind < 0.0 || kind > 7.0) return 0;
  if ((spec.kind_mask & (1U << static_cast<unsigned>(kind))) == 0U) return 0;
  if (spec.form == Form::kConstant) {
    out[0] = 1.0;
    return 1;
  }
  if (spec.column < 0 || static_cast<std::size_t>(spec.column) >= row.size()) return 0;
  const double v = row[static_cast<std::size_t>(spec.column)];
  if (!std::isfinite(v)) return 0;
  switch (spec.form) {
    case Form::kConstant:
      break;
    case Form::kLinear:
      out[0] = v;
      return 1;
    case Form::kPoly: {
      const double u = (v - spec.center) / spec.scale;
      const std::size_t n = basis_count(Form::kPoly, spec.degree);
      double p = 1.0;
      for (std::size_t i = 0; i < n; ++i) {
        p *= u;
        out[i] = p;
      }
      return n;
    }
    case Form::kExpRise:
      out[0] = v > 0.0 ? -std::expm1(-v / spec.scale) : 0.0;
      return 1;
    case Form::kSine: {
      const double phase = 2.0 * std::numbers::pi * v / spec.scale;
      out[0] = std::sin(phase);
      out[1] = std::cos(phase);
      return 2;
    }
    case Form::kStep:
      out[0] = v >= spec.center ? 1.0 : 0.0;
      return 1;
    case Form::kHinge:
      out[0] = v > spec.center ? v - spec.center : 0.0;
      return 1;
    case Form::kExpGrowth:
      // Clamped so that a value far beyond the fitted range cannot overflow.
      out[0] = v > 0.0 ? std::expm1(std::min(v / spec.scale, 50.0)) : 0.0;
      return 1;
    case Form::kLag:
    case Form::kWear:
      if (!std::isfinite(aux)) return 0;
      out[0] = aux;
      return 1;
    case Form::kInteraction: {
      if (spec.column_b < 0 || static_cast<std::size_t>(spec.column_b) >= row.size()) return 0;
      const double w = row[static_cast<std::size_t>(spec.column_b)];
      if (!std::isfinite(w)) return 0;
      const double a = v - spec.center;
      const double b = w - spec.center_b;
      out[0] = a;
      out[1] = b;
      out[2] = a * b;
      return 3;
    }
    case Form::kSession:
      out[0] = 1.0;
      return 1;
  }
  return 0;
}

int find_group(const TermSpec& spec, const std::vector<std::array<double, 2>>& groups,
               const Row& row) noexcept {
  std::array<double, 2> key{0.0, 0.0};
  for (std::size_t k = 0; k < 2; ++k) {
    if (spec.per[k] >= 0) {
      key[k] = row[static_cast<std::size_t>(spec.per[k])];
      if (!std::isfinite(key[k])) return -1;
    }
  }
  for (std::size_t g = 0; g < groups.size(); ++g) {
    if (same(groups[g][0], key[0]) && same(groups[g][1], key[1])) return static_cast<int>(g);
  }
  return -1;
}

void advance_state(std::span<const TermSpec> specs, const Row& row, EvalState& state) noexcept {
  const double t_s = row[static_cast<std::size_t>(Column::kTime)];
  const bool restart = !state.started || (std::isfinite(t_s) && t_s < state.last_time_s);
  const double dt_s = restart || !std::isfinite(t_s) ? 0.0 : t_s - state.last_time_s;
  for (std::size_t i = 0; i < specs.size() && i < state.lag_value.size(); ++i) {
    const TermSpec& s = specs[i];
    if (s.form != Form::kLag || s.column < 0) continue;
    const double u = row[static_cast<std::size_t>(s.column)];
    if (restart) {
      // Start in equilibrium with the first known input: the machine was at rest before.
      state.lag_value[i] = u;
      state.lag_input[i] = u;
      continue;
    }
    if (!std::isfinite(state.lag_value[i])) state.lag_value[i] = u;
    if (!std::isfinite(state.lag_input[i])) state.lag_input[i] = u;
    const double held = state.lag_input[i];
    if (std::isfinite(held) && dt_s > 0.0) {
      const double decay = std::exp(-dt_s / s.scale);
      state.lag_value[i] = held + (state.lag_value[i] - held) * decay;
    }
    if (std::isfinite(u)) state.lag_input[i] = u;
  }
  if (std::isfinite(t_s)) {
    state.last_time_s = t_s;
    state.started = true;
  }
}

Model::Model(std::vector<std::string> extra_columns, std::vector<Term> terms)
    : extra_columns_(std::move(extra_columns)), terms_(std::move(terms)) {
  specs_.reserve(terms_.size());
  for (const Term& t : terms_) {
    if (t.spec.form == Form::kSession && session_term_ < 0) {
      session_term_ = static_cast<int>(specs_.size());
    }
    specs_.push_back(t.spec);
  }
}

double session_posterior_um(double count, double sum_um, double between_sigma_um,
                            double noise_sigma_um) noexcept {
  if (!(count > 0.0) || !(between_sigma_um > 0.0)) return 0.0;
  const double tau2 = between_sigma_um * between_sigma_um;
  return tau2 * sum_um / (count * tau2 + noise_sigma_um * noise_sigma_um);
}

void Model::observe(const Row& row, double target_um, EvalState& state) const noexcept {
  if (session_term_ < 0 || !std::isfinite(target_um)) return;
  const auto k = static_cast<std::size_t>(session_term_);
  const Term& t = terms_[k];
  std::array<double, kMaxBasis> b{};
  if (term_basis(t.spec, row, kUnknown, b) == 0) return;
  if (find_group(t.spec, t.groups, row) >= 0) return;  // fitted: nothing to learn
  const double s = row[kSessionColumn];
  if (!same_session(state.session.session, s)) state.session = SessionLearning{s, 0.0, 0.0};
  double others_um = 0.0;
  for (std::size_t i = 0; i < terms_.size(); ++i) {
    if (i != k) others_um += evaluate_term(i, row, state);
  }
  const double r_um = target_um - others_um;
  if (!std::isfinite(r_um)) return;
  state.session.count += 1.0;
  state.session.sum_um += r_um;
}

EvalState Model::make_state() const {
  EvalState s;
  s.lag_value.assign(terms_.size(), kUnknown);
  s.lag_input.assign(terms_.size(), kUnknown);
  return s;
}

double Model::wear_reference(const Row& row, double point) const noexcept {
  Row r = row;
  r[static_cast<std::size_t>(Column::kKind)] = 0.0;  // tool_wear
  r[static_cast<std::size_t>(Column::kPoint)] = point;
  const EvalState none{};
  double sum = 0.0;
  for (std::size_t i = 0; i < terms_.size(); ++i) {
    const TermSpec& s = terms_[i].spec;
    if ((s.kind_mask & 1U) == 0U || s.form == Form::kWear || s.form == Form::kLag) continue;
    sum += evaluate_term(i, r, none);
  }
  return sum;
}

double Model::evaluate_term(std::size_t index, const Row& row,
                            const EvalState& state) const noexcept {
  const Term& t = terms_[index];
  std::array<double, kMaxBasis> b{};
  double aux = kUnknown;
  if (t.spec.form == Form::kWear) {
    aux = wear_reference(row, t.spec.center);
  } else if (index < state.lag_value.size()) {
    aux = state.lag_value[index];
  }
  const std::size_t n = term_basis(t.spec, row, aux, b);
  if (n == 0) return 0.0;
  const int g = find_group(t.spec, t.groups, row);
  if (g < 0 && t.spec.form == Form::kSession) {
    // A session the fit did not see: what its own measurements have taught so far.
    if (!same_session(state.session.session, row[kSessionColumn])) return 0.0;
    return session_posterior_um(state.session.count, state.session.sum_um, t.spec.scale,
                                t.spec.center);
  }
  if (g < 0) return 0.0;
  const std::size_t stride = basis_count(t.spec.form, t.spec.degree);
  const double* c = t.coef.data() + static_cast<std::size_t>(g) * stride;
  double sum = 0.0;
  for (std::size_t i = 0; i < n; ++i) sum += c[i] * b[i];
  return sum;
}

double Model::evaluate(const Row& row, EvalState& state) const noexcept {
  advance_state(specs_, row, state);
  double sum = 0.0;
  for (std::size_t i = 0; i < terms_.size(); ++i) sum += evaluate_term(i, row, state);
  return sum;
}

int column_index(std::string_view name, const std::vector<std::string>& extras) noexcept {
  for (std::size_t i = 0; i < kStandardColumnNames.size(); ++i) {
    if (kStandardColumnNames[i] == name) return static_cast<int>(i);
  }
  for (std::size_t i = 0; i < extras.size(); ++i) {
    if (extras[i] == name) return static_cast<int>(kStandardColumns + i);
  }
  return -1;
}

std::string term_column_name(const TermSpec& spec, const std::vector<std::string>& extras) {
  if (spec.form == Form::kInteraction) {
    return column_name(spec.column, extras) + "*" + column_name(spec.column_b, extras);
  }
  return column_name(spec.column, extras);
}

std::string column_name(int index, const std::vector<std::string>& extras) {
  if (index == static_cast<int>(kSessionColumn)) return "session";
  if (index >= 0 && static_cast<std::size_t>(index) < kStandardColumns) {
    return std::string(kStandardColumnNames[static_cast<std::size_t>(index)]);
  }
  const std::size_t e = static_cast<std::size_t>(index) - kStandardColumns;
  if (index >= 0 && e < extras.size()) return extras[e];
  return "?";
}

}  // namespace nccomp::core::model
