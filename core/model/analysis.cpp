#include "core/model/analysis.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <memory>
#include <numeric>
#include <tuple>
#include <utility>

namespace nccomp::core::model {

namespace {

constexpr std::size_t kMaxParameters = 600;
constexpr std::size_t kMaxGroupsPerTerm = 512;
constexpr std::size_t kRefitPerStep = 3;
// Candidates (best by BIC) put in the order of their rolling-origin error (rank_folds).
constexpr std::size_t kRankPool = 6;
// Most sessions of a session_offset candidate (one coefficient each in the fit).
constexpr std::size_t kMaxSessions = 256;

std::size_t uz(int i) { return static_cast<std::size_t>(i); }
double dz(std::size_t n) { return static_cast<double>(n); }

// Regularized incomplete beta I_x(a, b) by Lentz's continued fraction (Numerical Recipes §6.4).
double beta_cf(double a, double b, double x) {
  constexpr double kTiny = 1e-300;
  const double qab = a + b;
  const double qap = a + 1.0;
  const double qam = a - 1.0;
  double c = 1.0;
  double d = 1.0 - qab * x / qap;
  if (std::fabs(d) < kTiny) d = kTiny;
  d = 1.0 / d;
  double h = d;
  for (int m = 1; m <= 500; ++m) {
    const double md = m;
    const double m2 = 2.0 * md;
    double aa = md * (b - md) * x / ((qam + m2) * (a + m2));
    d = 1.0 + aa * d;
    if (std::fabs(d) < kTiny) d = kTiny;
    c = 1.0 + aa / c;
    if (std::fabs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    h *= d * c;
    aa = -(a + md) * (qab + md) * x / ((a + m2) * (qap + m2));
    d = 1.0 + aa * d;
    if (std::fabs(d) < kTiny) d = kTiny;
    c = 1.0 + aa / c;
    if (std::fabs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double del = d * c;
    h *= del;
    if (std::fabs(del - 1.0) < 1e-14) break;
  }
  return h;
}

double incomplete_beta(double a, double b, double x) {
  if (x <= 0.0) return 0.0;
  if (x >= 1.0) return 1.0;
  const double ln_front =
      std::lgamma(a + b) - std::lgamma(a) - std::lgamma(b) + a * std::log(x) + b * std::log1p(-x);
  const double front = std::exp(ln_front);
  if (x < (a + 1.0) / (a + b + 2.0)) return front * beta_cf(a, b, x) / a;
  return 1.0 - front * beta_cf(b, a, 1.0 - x) / b;
}

struct Entry {
  std::size_t index;
  double value;
};

// Per-term layout of the coefficient vector during a fit.
struct Layout {
  std::vector<std::vector<std::array<double, 2>>> groups;
  std::vector<std::size_t> offset;
  std::size_t parameters{0};
};

std::array<double, 2> group_key(const TermSpec& s, const Row& row, bool& ok) {
  std::array<double, 2> key{0.0, 0.0};
  ok = true;
  for (std::size_t k = 0; k < 2; ++k) {
    if (s.per[k] >= 0) {
      key[k] = row[uz(s.per[k])];
      if (!std::isfinite(key[k])) ok = false;
    }
  }
  return key;
}

// kWear terms take the wear a reference model predicts as their basis; it goes into the
// state's per-term slot (lag_value, otherwise used by kLag terms only).
void set_wear_aux(const std::vector<TermSpec>& specs, const Row& row, const Model* ref,
                  EvalState& state) {
  for (std::size_t t = 0; t < specs.size(); ++t) {
    if (specs[t].form != Form::kWear) continue;
    state.lag_value[t] = ref != nullptr ? ref->wear_reference(row, specs[t].center) : kUnknown;
  }
}

Layout discover_groups(const Dataset& data, const std::vector<TermSpec>& specs,
                       const std::vector<std::uint8_t>& use, const Model* wear_ref) {
  Layout layout;
  layout.groups.resize(specs.size());
  std::vector<std::map<std::array<double, 2>, int>> seen(specs.size());
  EvalState state;
  state.lag_value.assign(specs.size(), kUnknown);
  state.lag_input.assign(specs.size(), kUnknown);
  std::array<double, kMaxBasis> b{};
  for (std::size_t i = 0; i < data.rows(); ++i) {
    const Row row = data.row(i);
    advance_state(specs, row, state);
    if (use[i] == 0U) continue;
    set_wear_aux(specs, row, wear_ref, state);
    for (std::size_t t = 0; t < specs.size(); ++t) {
      if (term_basis(specs[t], row, state.lag_value[t], b) == 0) continue;
      bool ok = false;
      const auto key = group_key(specs[t], row, ok);
      if (!ok) continue;
      if (seen[t].emplace(key, 0).second) {
        if (seen[t].size() > kMaxGroupsPerTerm) {
          throw AnalysisError("term '" + specs[t].name + "' has more than " +
                              std::to_string(kMaxGroupsPerTerm) + " groups");
        }
      }
    }
  }
  for (std::size_t t = 0; t < specs.size(); ++t) {
    for (const auto& [key, unused] : seen[t]) layout.groups[t].push_back(key);
    layout.offset.push_back(layout.parameters);
    layout.parameters += layout.groups[t].size() * basis_count(specs[t].form, specs[t].degree);
  }
  if (layout.parameters > kMaxParameters) {
    throw AnalysisError("the model has " + std::to_string(layout.parameters) +
                        " coefficients; at most " + std::to_string(kMaxParameters) +
                        " are supported (fewer groups per term)");
  }
  return layout;
}

// The non-zero design-matrix entries of one row under `layout` (state already advanced).
std::size_t row_entries(const std::vector<TermSpec>& specs, const Layout& layout, const Row& row,
                        const EvalState& state, std::vector<Entry>& out) {
  out.clear();
  std::array<double, kMaxBasis> b{};
  for (std::size_t t = 0; t < specs.size(); ++t) {
    const std::size_t n = term_basis(specs[t], row, state.lag_value[t], b);
    if (n == 0) continue;
    const int g = find_group(specs[t], layout.groups[t], row);
    if (g < 0) continue;
    const std::size_t stride = basis_count(specs[t].form, specs[t].degree);
    for (std::size_t k = 0; k < n; ++k) {
      out.push_back({layout.offset[t] + uz(g) * stride + k, b[k]});
    }
  }
  return out.size();
}

// Minimum-norm least squares of the normal equations after equilibration (columns of very
// different scale: seconds since warm start next to a constant).
// `penalty` (empty = none): a ridge term added to the diagonal (the random effects of a session
// term, Henderson's mixed-model equations); `hat_diag` then gets the diagonal of
// (X'X + Λ)⁺ X'X, whose sum over a shrunk block is its effective number of parameters.
Eigen::VectorXd solve_normal(const Eigen::MatrixXd& a, const Eigen::VectorXd& rhs,
                             std::size_t* rank, std::vector<double>* variance,
                             const Eigen::VectorXd& penalty = {},
                             std::vector<double>* hat_diag = nullptr,
                             std::vector<double>* covariance = nullptr) {
  const Eigen::Index p = a.rows();
  Eigen::MatrixXd ap = a;
  if (penalty.size() == p) ap.diagonal() += penalty;
  Eigen::VectorXd d(p);
  for (Eigen::Index i = 0; i < p; ++i) {
    d(i) = ap(i, i) > 0.0 ? 1.0 / std::sqrt(ap(i, i)) : 0.0;
  }
  const Eigen::MatrixXd as = d.asDiagonal() * ap * d.asDiagonal();
  Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> cod(as);
  cod.setThreshold(1e-11);
  const Eigen::VectorXd z = cod.solve(d.asDiagonal() * rhs);
  if (rank != nullptr) *rank = static_cast<std::size_t>(cod.rank());
  if (variance != nullptr || hat_diag != nullptr || covariance != nullptr) {
    // (X'X)⁺ = D (D X'X D)⁺ D.
    const Eigen::MatrixXd inv = cod.pseudoInverse();
    if (variance != nullptr) {
      variance->resize(static_cast<std::size_t>(p));
      for (Eigen::Index i = 0; i < p; ++i) {
        (*variance)[static_cast<std::size_t>(i)] = d(i) * d(i) * inv(i, i);
      }
    }
    if (covariance != nullptr) {
      const Eigen::MatrixXd full = d.asDiagonal() * inv * d.asDiagonal();
      covariance->resize(static_cast<std::size_t>(p * p));
      for (Eigen::Index i = 0; i < p; ++i) {
        for (Eigen::Index j = 0; j < p; ++j) {
          (*covariance)[static_cast<std::size_t>(i * p + j)] = full(i, j);
        }
      }
    }
    if (hat_diag != nullptr) {
      // diag((A + Λ)⁺ A) = diag(D⁻¹ inv (D A D) D) = diag(inv (D A D)).
      const Eigen::MatrixXd h = inv * (d.asDiagonal() * a * d.asDiagonal());
      hat_diag->resize(static_cast<std::size_t>(p));
      for (Eigen::Index i = 0; i < p; ++i) (*hat_diag)[static_cast<std::size_t>(i)] = h(i, i);
    }
  }
  return d.asDiagonal() * z;
}

ErrorStats error_stats(const std::vector<double>& r, const std::vector<std::uint8_t>& mask,
                       std::uint8_t want) {
  ErrorStats s;
  double ss = 0.0;
  for (std::size_t i = 0; i < r.size(); ++i) {
    if (mask[i] != want || !std::isfinite(r[i])) continue;
    ss += r[i] * r[i];
    s.max_um = std::max(s.max_um, std::fabs(r[i]));
    ++s.rows;
  }
  s.rms_um = s.rows > 0 ? std::sqrt(ss / dz(s.rows)) : 0.0;
  return s;
}

std::size_t parameter_count(const Model& m) {
  std::size_t p = 0;
  for (const Term& t : m.terms()) p += t.coef.size();
  return p;
}

// `what` names the model in errors (the declared model, a candidate).
FitStats stats_of(const Dataset& data, const Model& model, const std::vector<std::uint8_t>& heldout,
                  std::vector<double>* residual_out, const std::string& what) {
  std::vector<double> r = residuals(data, model);
  for (std::size_t i = 0; i < r.size(); ++i) {
    // A prediction that overflowed would otherwise leave its row out of the RMS, silently.
    if (std::isfinite(data.target_um[i]) && !std::isfinite(r[i])) {
      throw AnalysisError(what + ": the prediction at " + data.where(i) +
                          " is not a finite number (a context value too large for the term)");
    }
  }
  FitStats s;
  s.fitted = error_stats(r, heldout, 0);
  s.heldout = error_stats(r, heldout, 1);
  s.rss = s.fitted.rms_um * s.fitted.rms_um * dz(s.fitted.rows);
  s.parameters = parameter_count(model);
  s.effective_parameters = dz(s.parameters);
  if (!std::isfinite(s.rss) || !std::isfinite(s.heldout.rms_um)) {
    throw AnalysisError(what + ": the RMS is not a finite number (values too large)");
  }
  if (residual_out != nullptr) *residual_out = std::move(r);
  return s;
}

std::vector<double> log_grid(double lo, double hi, std::size_t n) {
  std::vector<double> g;
  if (!(lo > 0.0) || !(hi > lo)) return g;
  for (std::size_t i = 0; i < n; ++i) {
    g.push_back(lo * std::pow(hi / lo, dz(i) / dz(n - 1)));
  }
  return g;
}

struct Range {
  double lo{std::numeric_limits<double>::infinity()};
  double hi{-std::numeric_limits<double>::infinity()};
  double mean{0.0};
  double sd{0.0};
  std::size_t n{0};
  std::size_t positive{0};
  [[nodiscard]] double span() const { return n > 0 ? hi - lo : 0.0; }
};

Range column_range(const Dataset& data, int column, const std::vector<std::uint8_t>& use,
                   std::uint8_t kind_mask) {
  Range r;
  const auto& c = data.column(column);
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  if (c.empty()) return r;
  double sum = 0.0;
  double ss = 0.0;
  for (std::size_t i = 0; i < c.size(); ++i) {
    if (use[i] == 0U || !std::isfinite(c[i])) continue;
    if (!kind.empty() && std::isfinite(kind[i]) && kind[i] >= 0.0 && kind[i] < 8.0 &&
        (kind_mask & (1U << static_cast<unsigned>(kind[i]))) == 0U) {
      continue;
    }
    r.lo = std::min(r.lo, c[i]);
    r.hi = std::max(r.hi, c[i]);
    sum += c[i];
    ss += c[i] * c[i];
    ++r.n;
    if (c[i] > 0.0) ++r.positive;
  }
  if (r.n > 0) {
    r.mean = sum / dz(r.n);
    r.sd = std::sqrt(std::max(0.0, ss / dz(r.n) - r.mean * r.mean));
  }
  return r;
}

// Distinct known values of `column` among the used rows of the kinds in kind_mask.
std::size_t count_groups(const Dataset& data, int column, const std::vector<std::uint8_t>& use,
                         std::uint8_t kind_mask) {
  const auto& c = data.column(column);
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  std::vector<double> v;
  for (std::size_t i = 0; i < c.size(); ++i) {
    if (use[i] == 0U || !std::isfinite(c[i])) continue;
    if (!kind.empty() && std::isfinite(kind[i]) && kind[i] >= 0.0 && kind[i] < 8.0 &&
        (kind_mask & (1U << static_cast<unsigned>(kind[i]))) == 0U) {
      continue;
    }
    v.push_back(c[i]);
  }
  std::sort(v.begin(), v.end());
  return static_cast<std::size_t>(std::unique(v.begin(), v.end()) - v.begin());
}

}  // namespace

std::vector<double> warm_start_values(const Dataset& data, int column,
                                      const std::vector<std::uint8_t>& use,
                                      std::uint8_t kind_mask) {
  const std::size_t n = data.rows();
  const auto& c = data.column(column);
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  const auto& t =
      data.order_s.size() == n ? data.order_s : data.column(static_cast<int>(Column::kTime));
  const bool sessions = data.row_session.size() == n;
  // Session → (time, value) of its earliest row so far.
  std::map<std::uint32_t, std::pair<double, double>> first;
  if (c.size() != n) return {};
  for (std::size_t i = 0; i < n; ++i) {
    if (i >= use.size() || use[i] == 0U || !std::isfinite(c[i])) continue;
    if (!kind.empty() && std::isfinite(kind[i]) && kind[i] >= 0.0 && kind[i] < 8.0 &&
        (kind_mask & (1U << static_cast<unsigned>(kind[i]))) == 0U) {
      continue;
    }
    const double t_s = t.size() == n && std::isfinite(t[i]) ? t[i] : static_cast<double>(i);
    const std::uint32_t s = sessions ? data.row_session[i] : 0U;
    const auto [it, inserted] = first.try_emplace(s, t_s, c[i]);
    if (!inserted && t_s < it->second.first) it->second = {t_s, c[i]};
  }
  std::vector<double> out;
  for (const auto& [s, tv] : first) out.push_back(tv.second);
  return out;
}

double linear_reference(const std::vector<double>& warm_start) {
  if (warm_start.empty()) return 0.0;
  double sum = 0.0;
  for (double v : warm_start) sum += v;
  return sum / static_cast<double>(warm_start.size());
}

namespace {

// Distinct sessions (Dataset::row_session) among the used rows of the kinds in kind_mask.
std::size_t count_sessions(const Dataset& data, const std::vector<std::uint8_t>& use,
                           std::uint8_t kind_mask) {
  if (data.row_session.size() != data.rows()) return data.rows() > 0 ? 1 : 0;
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  std::vector<std::uint32_t> v;
  for (std::size_t i = 0; i < data.rows(); ++i) {
    if (use[i] == 0U) continue;
    if (!kind.empty() && std::isfinite(kind[i]) && kind[i] >= 0.0 && kind[i] < 8.0 &&
        (kind_mask & (1U << static_cast<unsigned>(kind[i]))) == 0U) {
      continue;
    }
    v.push_back(data.row_session[i]);
  }
  std::sort(v.begin(), v.end());
  return static_cast<std::size_t>(std::unique(v.begin(), v.end()) - v.begin());
}

// Method of moments of the one-way random-effects model on the current residual e of the rows
// the session term applies to: the within-session mean square estimates σ², the between-session
// sum of squares B has E[B] = (S − 1) σ² + τ² (N − Σ n_s² / N) (unbalanced sessions). Sets
// spec.center = σ and spec.scale = τ (0 when B is no more than the noise explains).
void estimate_session_variances(const Dataset& data, const std::vector<std::uint8_t>& use,
                                const std::vector<double>& residual, TermSpec& spec) {
  std::map<double, std::array<double, 3>> acc;  // session → n, Σe, Σe²
  std::array<double, kMaxBasis> b{};
  for (std::size_t i = 0; i < data.rows(); ++i) {
    if (use[i] == 0U || !std::isfinite(residual[i])) continue;
    const Row row = data.row(i);
    if (term_basis(spec, row, kUnknown, b) == 0) continue;
    auto& a = acc[row[kSessionColumn]];
    a[0] += 1.0;
    a[1] += residual[i];
    a[2] += residual[i] * residual[i];
  }
  double n = 0.0;
  double sum = 0.0;
  double within = 0.0;
  double sum_n2 = 0.0;
  for (const auto& [session, a] : acc) {
    n += a[0];
    sum += a[1];
    within += std::max(0.0, a[2] - a[1] * a[1] / a[0]);
    sum_n2 += a[0] * a[0];
  }
  const double groups = dz(acc.size());
  spec.center = 0.0;
  spec.scale = 0.0;
  if (groups < 2.0 || n <= groups) return;
  double between = 0.0;
  for (const auto& [session, a] : acc) {
    const double d = a[1] / a[0] - sum / n;
    between += a[0] * d * d;
  }
  const double sigma2 = within / (n - groups);
  const double tau2 = (between - (groups - 1.0) * sigma2) / (n - sum_n2 / n);
  spec.center = std::sqrt(sigma2);
  spec.scale = tau2 > 0.0 ? std::sqrt(tau2) : 0.0;
}

// The shared and the per-group version of an effect are one term: once either is in the
// model, neither is tried again (and the daemon's [[model.apply]] finds it by name).
bool same_term(const TermSpec& a, const TermSpec& b) {
  return a.name == b.name && a.form == b.form && a.column == b.column;
}

// Subsample of the fitted rows for the non-linear search: design matrix of the current model,
// its orthonormal basis, and the current residual projected off it.
struct SearchSet {
  const Model* model{nullptr};  // the current model (the wear reference of kWear candidates)
  std::vector<std::size_t> rows;
  std::vector<Row> context;  // the rows' contexts, built once for the many grid evaluations
  Eigen::MatrixXd q;         // n_sub × rank, orthonormal
  Eigen::VectorXd r;         // residual ⟂ q
  double rss{0.0};
};

SearchSet make_search_set(const Dataset& data, const Model& model,
                          const std::vector<std::uint8_t>& use, const std::vector<double>& residual,
                          std::size_t max_rows) {
  SearchSet s;
  s.model = &model;
  std::size_t n_use = 0;
  for (auto u : use) n_use += u != 0U ? 1U : 0U;
  const std::size_t stride = std::max<std::size_t>(1, (n_use + max_rows - 1) / max_rows);
  // One row at a pseudo-random place (fixed seed) in each block of `stride` rows: every
  // stride-th row aliases with the log's cycle (20 checkpoints per part and a stride of 80 took
  // checkpoint 0 only, so a per-checkpoint candidate looked like the shared one).
  std::uint64_t lcg = 0x9E3779B97F4A7C15ULL;
  std::size_t pick = 0;
  std::size_t k = 0;
  for (std::size_t i = 0; i < data.rows(); ++i) {
    if (use[i] == 0U || !std::isfinite(residual[i])) continue;
    if (k % stride == 0) {
      lcg = lcg * 6364136223846793005ULL + 1442695040888963407ULL;
      pick = static_cast<std::size_t>((lcg >> 33) % stride);
    }
    if (k++ % stride == pick) s.rows.push_back(i);
  }
  s.context.reserve(s.rows.size());
  for (std::size_t i : s.rows) s.context.push_back(data.row(i));
  const auto n = static_cast<Eigen::Index>(s.rows.size());
  const std::vector<TermSpec>& specs = model.specs();
  Layout layout;
  layout.groups.resize(specs.size());
  for (std::size_t t = 0; t < specs.size(); ++t) {
    layout.groups[t] = model.terms()[t].groups;
    layout.offset.push_back(layout.parameters);
    layout.parameters += layout.groups[t].size() * basis_count(specs[t].form, specs[t].degree);
  }
  Eigen::MatrixXd x = Eigen::MatrixXd::Zero(n, static_cast<Eigen::Index>(layout.parameters));
  EvalState state = model.make_state();
  std::vector<Entry> entries;
  std::size_t j = 0;
  for (std::size_t i = 0; i < data.rows() && j < s.rows.size(); ++i) {
    const Row row = data.row(i);
    advance_state(specs, row, state);
    if (i != s.rows[j]) continue;
    set_wear_aux(specs, row, &model, state);
    row_entries(specs, layout, row, state, entries);
    for (const Entry& e : entries)
      x(static_cast<Eigen::Index>(j), static_cast<Eigen::Index>(e.index)) = e.value;
    ++j;
  }
  // Orthonormal basis of the design's column space (rank-revealing: groups may be collinear).
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(x);
  qr.setThreshold(1e-10);
  const Eigen::Index rank = x.cols() > 0 ? qr.rank() : 0;
  Eigen::MatrixXd q_full = qr.householderQ() * Eigen::MatrixXd::Identity(n, rank);
  s.q = std::move(q_full);
  s.r.resize(n);
  for (Eigen::Index i = 0; i < n; ++i) s.r(i) = residual[s.rows[static_cast<std::size_t>(i)]];
  s.r -= s.q * (s.q.transpose() * s.r);
  s.rss = s.r.squaredNorm();
  return s;
}

// Basis of a candidate over the search rows (lag: filter run over every row in order).
Eigen::MatrixXd candidate_basis(const Dataset& data, const SearchSet& set, const TermSpec& spec) {
  const auto n = static_cast<Eigen::Index>(set.rows.size());
  const auto k = static_cast<Eigen::Index>(basis_count(spec.form, spec.degree));
  // Per-group candidates get k columns per group found among the search rows.
  std::vector<int> group(set.rows.size(), 0);
  Eigen::Index groups = 1;
  if (spec.per[0] >= 0 || spec.per[1] >= 0) {
    std::map<std::array<double, 2>, int> ids;
    for (std::size_t j = 0; j < set.rows.size(); ++j) {
      bool ok = false;
      const auto key = group_key(spec, set.context[j], ok);
      group[j] = ok ? ids.emplace(key, static_cast<int>(ids.size())).first->second : -1;
    }
    groups = std::max<Eigen::Index>(1, static_cast<Eigen::Index>(ids.size()));
  }
  Eigen::MatrixXd b = Eigen::MatrixXd::Zero(n, k * groups);
  std::array<double, kMaxBasis> v{};
  if (spec.form == Form::kLag) {
    const std::vector<TermSpec> one{spec};
    EvalState state;
    state.lag_value.assign(1, kUnknown);
    state.lag_input.assign(1, kUnknown);
    std::size_t j = 0;
    for (std::size_t i = 0; i < data.rows() && j < set.rows.size(); ++i) {
      const Row row = data.row(i);
      advance_state(one, row, state);
      if (i != set.rows[j]) continue;
      if (group[j] >= 0 && term_basis(spec, row, state.lag_value[0], v) > 0) {
        b(static_cast<Eigen::Index>(j), group[j]) = v[0];
      }
      ++j;
    }
    return b;
  }
  for (Eigen::Index j = 0; j < n; ++j) {
    const Row& row = set.context[static_cast<std::size_t>(j)];
    const int g = group[static_cast<std::size_t>(j)];
    if (g < 0) continue;
    const double aux = spec.form == Form::kWear && set.model != nullptr
                           ? set.model->wear_reference(row, spec.center)
                           : kUnknown;
    const std::size_t m = term_basis(spec, row, aux, v);
    for (std::size_t c = 0; c < m; ++c) b(j, g * k + static_cast<Eigen::Index>(c)) = v[c];
  }
  return b;
}

// Squared norm of the residual's projection on the columns of b: an orthonormal basis of b by
// a rank-revealing QR, so the result never exceeds the residual's own SS (solving b'b for
// ill-conditioned columns gave shares of 10^10 on real data).
double projected_ss(const SearchSet& set, const Eigen::MatrixXd& b) {
  if (b.cols() == 0 || b.squaredNorm() <= 1e-12 * dz(set.rows.size())) return 0.0;
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(b);
  qr.setThreshold(1e-9);
  const Eigen::Index rank = qr.rank();
  if (rank == 0) return 0.0;
  const Eigen::VectorXd qtr = (qr.householderQ().transpose() * set.r).head(rank);
  return qtr.squaredNorm();
}

// RSS reduction on the search rows when the candidate joins the model (exact: the candidate's
// basis is orthogonalised against the model's columns first).
double exact_reduction(const SearchSet& set, Eigen::MatrixXd b) {
  if (set.q.cols() > 0) b -= set.q * (set.q.transpose() * b);
  return projected_ss(set, b);
}

// Cheap score for wide grids: projection of the residual on the centred candidate basis alone.
double cheap_reduction(const SearchSet& set, Eigen::MatrixXd b) {
  b.rowwise() -= b.colwise().mean();
  return projected_ss(set, b);
}

// Group index of each search row under spec.per (-1 where a per column is unknown) and the
// number of groups, found once per candidate (candidate_basis() finds them per call).
std::vector<int> search_row_groups(const SearchSet& set, const TermSpec& spec, int& count) {
  std::map<std::array<double, 2>, int> ids;
  std::vector<int> group(set.rows.size(), -1);
  for (std::size_t j = 0; j < set.rows.size(); ++j) {
    bool ok = false;
    const auto key = group_key(spec, set.context[j], ok);
    if (ok) group[j] = ids.emplace(key, static_cast<int>(ids.size())).first->second;
  }
  count = static_cast<int>(ids.size());
  return group;
}

// Score of a per-group candidate: the rows of different groups are disjoint, so the residual's
// projection on the per-group columns (each centred within its group, i.e. orthogonal to a
// constant per group) is the sum of the groups' own projections: k × k systems instead of a QR
// of k × groups columns. `b`: the shared basis (n × k). Each group's share is clamped to the
// group's residual SS, so an ill-conditioned system cannot score more than there is.
double grouped_reduction(const SearchSet& set, const Eigen::MatrixXd& b,
                         const std::vector<int>& group, int count) {
  const Eigen::Index k = b.cols();
  if (k == 0 || count <= 0 || k > static_cast<Eigen::Index>(kMaxBasis)) return 0.0;
  struct Acc {
    double n{0.0};
    double sr{0.0};
    double srr{0.0};
    Eigen::Vector3d sb{Eigen::Vector3d::Zero()};
    Eigen::Vector3d sbr{Eigen::Vector3d::Zero()};
    Eigen::Matrix3d sbb{Eigen::Matrix3d::Zero()};
  };
  std::vector<Acc> acc(static_cast<std::size_t>(count));
  for (Eigen::Index j = 0; j < b.rows(); ++j) {
    const int g = group[static_cast<std::size_t>(j)];
    if (g < 0) continue;
    Acc& a = acc[static_cast<std::size_t>(g)];
    const double r = set.r(j);
    a.n += 1.0;
    a.sr += r;
    a.srr += r * r;
    for (Eigen::Index u = 0; u < k; ++u) {
      const double bu = b(j, u);
      a.sb(u) += bu;
      a.sbr(u) += bu * r;
      for (Eigen::Index v = 0; v < k; ++v) a.sbb(u, v) += bu * b(j, v);
    }
  }
  double total = 0.0;
  for (const Acc& a : acc) {
    if (a.n < 2.0) continue;
    const Eigen::MatrixXd c =
        a.sbb.topLeftCorner(k, k) - a.sb.head(k) * a.sb.head(k).transpose() / a.n;
    const Eigen::VectorXd cr = a.sbr.head(k) - a.sb.head(k) * (a.sr / a.n);
    Eigen::VectorXd d(k);
    for (Eigen::Index u = 0; u < k; ++u) d(u) = c(u, u) > 1e-300 ? 1.0 / std::sqrt(c(u, u)) : 0.0;
    const Eigen::MatrixXd cs = d.asDiagonal() * c * d.asDiagonal();
    const Eigen::VectorXd crs = d.asDiagonal() * cr;
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(cs);
    const double top = es.eigenvalues().maxCoeff();
    double red = 0.0;
    for (Eigen::Index u = 0; u < k; ++u) {
      const double l = es.eigenvalues()(u);
      if (l > 1e-9 * top && l > 0.0) {
        const double p = es.eigenvectors().col(u).dot(crs);
        red += p * p / l;
      }
    }
    const double own = std::max(0.0, a.srr - a.sr * a.sr / a.n);
    if (std::isfinite(red)) total += std::clamp(red, 0.0, own);
  }
  return total;
}

void set_parameter(TermSpec& s, double v) {
  if (s.form == Form::kStep || s.form == Form::kHinge) {
    s.center = v;
  } else {
    s.scale = v;
  }
}

// The grid search of a per-group candidate: every grid point and the golden-section refinement
// scored by grouped_reduction() (cheap for many groups), the best one exactly.
std::pair<double, double> search_grouped(const Dataset& data, const SearchSet& set,
                                         const Candidate& cand) {
  int count = 0;
  const std::vector<int> group = search_row_groups(set, cand.spec, count);
  TermSpec shared = cand.spec;
  shared.per = {-1, -1};
  auto score = [&](double v) {
    TermSpec s = shared;
    set_parameter(s, v);
    return grouped_reduction(set, candidate_basis(data, set, s), group, count);
  };
  std::size_t best_i = 0;
  double best_score = -1.0;
  for (std::size_t i = 0; i < cand.grid.size(); ++i) {
    const double f = score(cand.grid[i]);
    if (f > best_score) {
      best_score = f;
      best_i = i;
    }
  }
  double best_v = cand.grid[best_i];
  if (cand.spec.form != Form::kStep && cand.spec.form != Form::kHinge) {
    double lo = cand.grid[best_i > 0 ? best_i - 1 : 0];
    double hi = cand.grid[std::min(best_i + 1, cand.grid.size() - 1)];
    const double phi = 0.5 * (std::sqrt(5.0) - 1.0);
    double a = hi - phi * (hi - lo);
    double b = lo + phi * (hi - lo);
    double fa = score(a);
    double fb = score(b);
    for (int it = 0; it < 16; ++it) {
      if (fa > fb) {
        hi = b;
        b = a;
        fb = fa;
        a = hi - phi * (hi - lo);
        fa = score(a);
      } else {
        lo = a;
        a = b;
        fa = fb;
        b = lo + phi * (hi - lo);
        fb = score(b);
      }
    }
    if (std::max(fa, fb) > best_score) best_v = fa > fb ? a : b;
  }
  TermSpec s = cand.spec;
  set_parameter(s, best_v);
  return {best_v, exact_reduction(set, candidate_basis(data, set, s))};
}

// Best non-linear parameter of a candidate on the search rows, and its RSS reduction there.
std::pair<double, double> search_candidate(const Dataset& data, const SearchSet& set,
                                           Candidate& cand) {
  if (cand.grid.empty()) return {0.0, exact_reduction(set, candidate_basis(data, set, cand.spec))};
  if (cand.grouped) return search_grouped(data, set, cand);
  const bool wide = cand.grid.size() > 60;
  std::vector<std::pair<double, std::size_t>> scored;
  for (std::size_t i = 0; i < cand.grid.size(); ++i) {
    TermSpec s = cand.spec;
    set_parameter(s, cand.grid[i]);
    const Eigen::MatrixXd b = candidate_basis(data, set, s);
    scored.emplace_back(wide ? cheap_reduction(set, b) : exact_reduction(set, b), i);
  }
  std::sort(scored.begin(), scored.end(), std::greater<>());
  if (scored.empty()) return {0.0, 0.0};
  // The best few grid points scored exactly, then a golden-section refinement between the
  // neighbours of the best (steps are piecewise constant: their grid is already fine).
  double best_v = cand.grid[scored[0].second];
  double best_score = -1.0;
  std::size_t best_i = scored[0].second;
  for (std::size_t k = 0; k < std::min<std::size_t>(wide ? 5 : 1, scored.size()); ++k) {
    TermSpec s = cand.spec;
    const std::size_t i = scored[k].second;
    set_parameter(s, cand.grid[i]);
    const double score =
        wide ? exact_reduction(set, candidate_basis(data, set, s)) : scored[k].first;
    if (score > best_score) {
      best_score = score;
      best_v = cand.grid[i];
      best_i = i;
    }
  }
  if (cand.spec.form != Form::kStep && cand.spec.form != Form::kHinge) {
    double lo = cand.grid[best_i > 0 ? best_i - 1 : 0];
    double hi = cand.grid[std::min(best_i + 1, cand.grid.size() - 1)];
    const double phi = 0.5 * (std::sqrt(5.0) - 1.0);
    auto eval = [&](double v) {
      TermSpec s = cand.spec;
      set_parameter(s, v);
      return exact_reduction(set, candidate_basis(data, set, s));
    };
    double a = hi - phi * (hi - lo);
    double b = lo + phi * (hi - lo);
    double fa = eval(a);
    double fb = eval(b);
    for (int it = 0; it < 16; ++it) {
      if (fa > fb) {
        hi = b;
        b = a;
        fb = fa;
        a = hi - phi * (hi - lo);
        fa = eval(a);
      } else {
        lo = a;
        a = b;
        fa = fb;
        b = lo + phi * (hi - lo);
        fb = eval(b);
      }
    }
    const double v = fa > fb ? a : b;
    const double f = std::max(fa, fb);
    if (f > best_score) {
      best_score = f;
      best_v = v;
    }
  }
  return {best_v, best_score};
}

// Periods of a sine candidate's grid that explain the residual within 2 % as well as the chosen
// one, away from its peak: positions on a lattice cannot tell them apart (aliasing).
std::vector<double> equivalent_periods(const Dataset& data, const SearchSet& set,
                                       const Candidate& cand) {
  std::vector<double> out;
  const auto& g = cand.grid;
  if (cand.spec.form != Form::kSine || g.size() < 3) return out;
  const double best = exact_reduction(set, candidate_basis(data, set, cand.spec));
  if (!(best > 0.0)) return out;
  std::vector<double> score(g.size());
  for (std::size_t i = 0; i < g.size(); ++i) {
    TermSpec s = cand.spec;
    s.scale = g[i];
    score[i] = cheap_reduction(set, candidate_basis(data, set, s));
  }
  const double df = std::fabs(1.0 / g[1] - 1.0 / g[0]);
  for (std::size_t i = 0; i < g.size(); ++i) {
    const bool peak =
        (i == 0 || score[i] >= score[i - 1]) && (i + 1 == g.size() || score[i] >= score[i + 1]);
    if (!peak || score[i] < 0.9 * best) continue;
    if (std::fabs(1.0 / g[i] - 1.0 / cand.spec.scale) <= 2.0 * df) continue;  // the chosen one
    TermSpec s = cand.spec;
    s.scale = g[i];
    if (exact_reduction(set, candidate_basis(data, set, s)) >= 0.98 * best) out.push_back(g[i]);
  }
  return out;
}

// Block of each row for --validate sessions with validate_block_s: whole blocks of block_s from
// the first known time (in the order over files); a row without a time keeps the block before it.
std::vector<std::uint32_t> time_blocks(const Dataset& data, double block_s) {
  const std::size_t n = data.rows();
  const auto& t =
      data.order_s.size() == n ? data.order_s : data.column(static_cast<int>(Column::kTime));
  std::vector<std::uint32_t> out(n, 0);
  if (t.size() != n) return out;
  double first = kUnknown;
  for (const double v : t) {
    if (std::isfinite(v) && !(v >= first)) first = v;
  }
  std::uint32_t block = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (std::isfinite(t[i]))
      block = static_cast<std::uint32_t>(std::floor((t[i] - first) / block_s));
    out[i] = block;
  }
  return out;
}

// Search rows in time order (order over files when the reader gave one), for the rolling origin.
std::vector<Eigen::Index> search_rows_by_time(const Dataset& data, const SearchSet& set) {
  const std::size_t n = data.rows();
  const auto& t =
      data.order_s.size() == n ? data.order_s : data.column(static_cast<int>(Column::kTime));
  std::vector<Eigen::Index> order;
  if (t.size() != n) return order;
  for (std::size_t j = 0; j < set.rows.size(); ++j) {
    if (!std::isfinite(t[set.rows[j]])) return {};  // no time order to validate in
    order.push_back(static_cast<Eigen::Index>(j));
  }
  std::stable_sort(order.begin(), order.end(), [&](Eigen::Index a, Eigen::Index b) {
    return t[set.rows[static_cast<std::size_t>(a)]] < t[set.rows[static_cast<std::size_t>(b)]];
  });
  return order;
}

// Rolling-origin validation of the current model plus the columns b on the search rows: the rows
// in time order are cut into folds + 1 blocks of equal count, and block f (1 … folds) is
// predicted by a fit to the blocks before it. Returns the summed squared prediction error.
// The target is the residual ⟂ q: it differs from the measurement by a vector of q's span, so
// the errors are those of refitting the measurement on the model's columns and b.
double rolling_origin_ss(const SearchSet& set, const std::vector<Eigen::Index>& order,
                         Eigen::MatrixXd b, std::size_t folds) {
  const auto n = static_cast<Eigen::Index>(order.size());
  const Eigen::Index p = set.q.cols();
  // Unit columns: the rank test of the QR compares pivots, and a column of rpm² (10⁷) would make
  // the model's unit columns look negligible.
  for (Eigen::Index c = 0; c < b.cols(); ++c) {
    const double norm = b.col(c).norm();
    if (norm > 0.0) b.col(c) /= norm;
  }
  Eigen::MatrixXd x(n, p + b.cols());
  Eigen::VectorXd y(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Index j = order[static_cast<std::size_t>(i)];
    x.row(i) << set.q.row(j), b.row(j);
    y(i) = set.r(j);
  }
  double ss = 0.0;
  const auto blocks = static_cast<Eigen::Index>(folds + 1);
  for (Eigen::Index f = 1; f < blocks; ++f) {
    const Eigen::Index from = n * f / blocks;
    const Eigen::Index to = n * (f + 1) / blocks;
    if (from == 0 || to <= from) continue;
    // Columns zero on the earlier blocks (a group or a level not seen yet) get no coefficient.
    Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(x.topRows(from));
    qr.setThreshold(1e-9);
    const Eigen::VectorXd coef = qr.solve(y.head(from));
    ss += (y.segment(from, to - from) - x.middleRows(from, to - from) * coef).squaredNorm();
  }
  return ss;
}

// Rolling-origin errors (rolling_origin_ss) of the candidates `which`, their non-linear parameter
// as the search set it; empty when the search rows have no time order.
std::vector<double> validation_errors(const Dataset& data, const SearchSet& set,
                                      const std::vector<Candidate>& cands,
                                      const std::vector<std::size_t>& which, std::size_t folds) {
  const std::vector<Eigen::Index> order = search_rows_by_time(data, set);
  std::vector<double> out;
  if (order.empty()) return out;
  for (const std::size_t c : which) {
    out.push_back(rolling_origin_ss(set, order, candidate_basis(data, set, cands[c].spec), folds));
  }
  return out;
}

}  // namespace

Dataset::Dataset() : columns(kStandardColumns) {}

Row Dataset::row(std::size_t i) const {
  Row r = unknown_row();
  for (std::size_t c = 0; c < columns.size() && c < kMaxColumns; ++c) {
    if (!columns[c].empty()) r[c] = columns[c][i];
  }
  r[kSessionColumn] = row_session.size() == rows() ? static_cast<double>(row_session[i]) : 0.0;
  return r;
}

std::string Dataset::where(std::size_t i) const {
  if (i < row_line.size() && i < row_file.size() && row_line[i] > 0 && row_file[i] < files.size()) {
    return files[row_file[i]] + ":" + std::to_string(row_line[i]);
  }
  return "row " + std::to_string(i + 1);
}

const std::vector<double>& Dataset::column(int index) const {
  static const std::vector<double> kEmpty;
  if (index < 0 || uz(index) >= columns.size()) return kEmpty;
  return columns[uz(index)];
}

namespace {

constexpr double kMaxTargetUm = 1e6;       // 1 m: no machine's deviation
constexpr double kMaxContextValue = 1e15;  // beyond it, squares of sums lose every digit

std::string fmt_g(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

// Values no measurement has are errors before they become an RMS of inf.
void check_magnitudes(const Dataset& data) {
  for (std::size_t i = 0; i < data.rows(); ++i) {
    const double y = data.target_um[i];
    if (std::isfinite(y) && std::fabs(y) > kMaxTargetUm) {
      throw AnalysisError(data.where(i) + ": measured_um + applied_um = " + fmt_g(y) +
                          " µm is beyond ±1e6 µm (1 m): not a deviation (check the value and its "
                          "[scale])");
    }
  }
  for (std::size_t c = 0; c < data.columns.size(); ++c) {
    const auto& v = data.columns[c];
    for (std::size_t i = 0; i < v.size(); ++i) {
      if (std::isfinite(v[i]) && std::fabs(v[i]) > kMaxContextValue) {
        throw AnalysisError(data.where(i) + ": column '" +
                            column_name(static_cast<int>(c), data.extra_columns) +
                            "' = " + std::to_string(v[i]) + " is beyond ±1e15");
      }
    }
  }
}

// Whether a term applies to row i by its kinds (kind_mask; a row without a valid kind: every
// term). kind: the dataset's kind column (empty: none).
bool term_applies(const TermSpec& s, const std::vector<double>& kind, std::size_t i) {
  return kind.empty() || !std::isfinite(kind[i]) || kind[i] < 0.0 || kind[i] > 7.0 ||
         (s.kind_mask & (1U << static_cast<unsigned>(kind[i]))) != 0U;
}

// Held-out rows of a group (of a declared term's `per` columns) that no fitted row has: the
// model fitted on the earlier rows predicts 0 for that term there, and the held-out error would
// measure the missing group, not the model. They are set to 2 (in neither part) and reported.
void leave_out_unseen_groups(const Dataset& data, const std::vector<TermSpec>& declared,
                             std::vector<std::uint8_t>& heldout, std::vector<Warning>& out) {
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  auto applies = [&](const TermSpec& s, std::size_t i) { return term_applies(s, kind, i); };
  std::string groups;
  std::size_t listed = 0;
  std::size_t rows = 0;
  std::vector<std::uint8_t> unseen(data.rows(), 0);
  for (const TermSpec& s : declared) {
    // A session term learns an unseen session from its own rows (Model::observe()).
    if ((s.per[0] < 0 && s.per[1] < 0) || s.form == Form::kSession) continue;
    std::map<std::array<double, 2>, int> fitted;  // 0 seen in fitted rows, 1 only held out
    for (int want : {0, 1}) {
      for (std::size_t i = 0; i < data.rows(); ++i) {
        if (heldout[i] != want || !std::isfinite(data.target_um[i]) || !applies(s, i)) continue;
        bool ok = false;
        const auto key = group_key(s, data.row(i), ok);
        if (!ok) continue;
        const auto [it, added] = fitted.emplace(key, want);
        if (it->second == 1) unseen[i] = 1;
        if (added && want == 1) {
          if (listed++ < 5) {
            groups += std::string(groups.empty() ? "" : ", ") + s.name + " " +
                      column_name(s.per[0], data.extra_columns) + " " + fmt_g(key[0]);
            if (s.per[1] >= 0) {
              groups += " " + column_name(s.per[1], data.extra_columns) + " " + fmt_g(key[1]);
            }
          }
        }
      }
    }
  }
  for (std::size_t i = 0; i < data.rows(); ++i) {
    if (unseen[i] != 0U) {
      heldout[i] = 2;
      ++rows;
    }
  }
  if (rows == 0) return;
  out.push_back({"heldout_unseen_group",
                 std::to_string(rows) + " held-out rows belong to " + std::to_string(listed) +
                     " groups no fitted row has (" + groups + (listed > 5 ? ", …" : "") +
                     "): fitted on the earlier rows, the model predicts nothing for them, so "
                     "they are left out of the held-out figures (the final model, fitted on all "
                     "rows, has these groups)"});
}

// Isolated spikes of the declared model's residual (a probe that hit a chip): a row that differs
// from both neighbours of its (kind, point, tool) series, in the same direction, by more than
// `sigmas` noise standard deviations. A step or a trend moves the neighbours too, so they stay.
std::vector<std::size_t> find_outliers(const Dataset& data, const std::vector<double>& residual,
                                       const std::vector<std::uint8_t>& heldout, double sigmas) {
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  const auto& point = data.column(static_cast<int>(Column::kPoint));
  const auto& tool = data.column(static_cast<int>(Column::kTool));
  std::map<std::tuple<double, double, double>, std::vector<std::size_t>> series;
  for (std::size_t i = 0; i < data.rows(); ++i) {
    if (heldout[i] == 2U || !std::isfinite(residual[i])) continue;
    series[std::make_tuple(kind.empty() ? 0.0 : kind[i], point.empty() ? 0.0 : point[i],
                           tool.empty() ? 0.0 : tool[i])]
        .push_back(i);
  }
  std::vector<double> diffs;
  for (const auto& [key, rows] : series) {
    for (std::size_t k = 1; k < rows.size(); ++k) {
      diffs.push_back(std::fabs(residual[rows[k]] - residual[rows[k - 1]]));
    }
  }
  std::vector<std::size_t> out;
  if (diffs.size() < 8) return out;
  const auto mid = diffs.begin() + static_cast<std::ptrdiff_t>(diffs.size() / 2);
  std::nth_element(diffs.begin(), mid, diffs.end());
  // Median |e_i − e_{i−1}| of normal noise σ√2 is 0.6745 σ√2; 1 nm: below any probe.
  const double sigma = *mid / (0.6745 * std::sqrt(2.0));
  const double limit = std::max(sigmas * sigma, 1e-3);
  for (const auto& [key, rows] : series) {
    for (std::size_t k = 1; k + 1 < rows.size(); ++k) {
      const double a = residual[rows[k]] - residual[rows[k - 1]];
      const double b = residual[rows[k]] - residual[rows[k + 1]];
      if (a * b > 0.0 && std::min(std::fabs(a), std::fabs(b)) > limit) out.push_back(rows[k]);
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Two-sided 95 % quantile of Student's t with df degrees of freedom (t² is F(1, df)).
double t95(double df) {
  double lo = 0.0;
  double hi = 1e3;
  for (int i = 0; i < 100; ++i) {
    const double mid = 0.5 * (lo + hi);
    (f_distribution_upper_tail(mid * mid, 1.0, df) > 0.05 ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

// coef_ci95 of each added effect: the model's fit on the fitted rows, its residual variance,
// the variance widened by (1 + ρ)/(1 − ρ) for an AR(1) residual like the F-test's rows.
void set_confidence_intervals(const Dataset& data, const std::vector<TermSpec>& specs,
                              const std::vector<std::uint8_t>& use,
                              const std::vector<double>& residual, const AnalysisConfig& config,
                              AnalysisResult& result) {
  if (result.effects.empty()) return;
  FitInfo info;
  info.want_variance = true;
  const Model m = fit_terms(data, specs, use, &info);
  double rss = 0.0;
  for (std::size_t i = 0; i < residual.size(); ++i) {
    if (use[i] != 0U && std::isfinite(residual[i])) rss += residual[i] * residual[i];
  }
  const double rho = config.ar1_correction
                         ? std::clamp(lag1_autocorrelation(data, residual, use), 0.0, 0.999)
                         : 0.0;
  const double df = (dz(info.rows) - dz(info.rank)) * (1.0 - rho) / (1.0 + rho);
  const bool known = df >= 1.0;
  const double s2 = known ? rss / (dz(info.rows) - dz(info.rank)) * (1.0 + rho) / (1.0 - rho) : 0.0;
  const double t = known ? t95(df) : 0.0;
  std::size_t offset = 0;
  const std::size_t first_effect = specs.size() - result.effects.size();
  for (std::size_t k = 0; k < specs.size(); ++k) {
    const Term& term = m.terms()[k];
    if (k >= first_effect) {
      auto& ci = result.effects[k - first_effect].coef_ci95;
      for (std::size_t j = 0; j < term.coef.size(); ++j) {
        const double half = known
                                ? t * std::sqrt(s2 * std::max(0.0, info.coef_variance[offset + j]))
                                : std::numeric_limits<double>::infinity();
        ci.push_back({term.coef[j] - half, term.coef[j] + half});
      }
    }
    offset += term.coef.size();
  }
}

// The validation error of the prediction interval (IntervalMethod::kValidation): the fitted rows
// cut by time (the order over files, else time_s) into kIntervalFolds + 1 blocks of equal count,
// as the held-out split is cut; for each of the latest kIntervalFoldsUsed blocks, the terms are
// refitted on the fitted rows before it and its rows are predicted (lag filters over all rows,
// a session the fit lacks learned from its earlier rows, as for the held-out rows). Rows of a
// group that fit has not seen (a per-group term's checkpoint or tool first met in the block) are
// left out, as heldout_unseen_group leaves them out of the held-out figures. Returns the summed
// squared prediction error and its rows ({0, 0} when there is no time order or no fold fits).
std::pair<double, std::size_t> interval_validation_error(const Dataset& data,
                                                         const std::vector<TermSpec>& specs,
                                                         const std::vector<std::uint8_t>& use) {
  const std::size_t n = data.rows();
  const auto& tc =
      data.order_s.size() == n ? data.order_s : data.column(static_cast<int>(Column::kTime));
  if (tc.size() != n) return {0.0, 0};
  std::vector<double> times;
  for (std::size_t i = 0; i < n; ++i) {
    if (use[i] != 0U && std::isfinite(tc[i])) times.push_back(tc[i]);
  }
  constexpr std::size_t kBlocks = kIntervalFolds + 1;
  if (times.size() < kBlocks) return {0.0, 0};
  std::sort(times.begin(), times.end());
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  auto applies = [&](const TermSpec& s, std::size_t i) { return term_applies(s, kind, i); };
  double ss = 0.0;
  std::size_t rows = 0;
  for (std::size_t f = kBlocks - kIntervalFoldsUsed; f < kBlocks; ++f) {
    const double from = times[times.size() * f / kBlocks];
    const double to = f + 1 < kBlocks ? times[times.size() * (f + 1) / kBlocks]
                                      : std::numeric_limits<double>::infinity();
    std::vector<std::uint8_t> earlier(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
      earlier[i] = use[i] != 0U && std::isfinite(tc[i]) && tc[i] < from ? 1 : 0;
    }
    Model m;
    try {
      m = fit_terms(data, specs, earlier);
    } catch (const AnalysisError&) {
      continue;  // too few earlier rows for these terms: this fold says nothing
    }
    const std::vector<double> r = residuals(data, m);
    for (std::size_t i = 0; i < n; ++i) {
      if (use[i] == 0U || !std::isfinite(tc[i]) || tc[i] < from || !(tc[i] < to)) continue;
      if (!std::isfinite(r[i])) continue;
      const Row row = data.row(i);
      bool unseen = false;
      for (const Term& t : m.terms()) {
        const TermSpec& s = t.spec;
        if ((s.per[0] < 0 && s.per[1] < 0) || s.form == Form::kSession || !applies(s, i)) continue;
        bool ok = false;
        group_key(s, row, ok);
        if (ok && find_group(s, t.groups, row) < 0) unseen = true;
      }
      if (unseen) continue;
      ss += r[i] * r[i];
      ++rows;
    }
  }
  return {ss, rows};
}

// The final model's 95 % prediction interval on each held-out row, from the fit on the fitted
// rows: t · sqrt(max(s² (1 + x'Cx ·(1 + ρ)/(1 − ρ)), e²) + v), C = (X'X + Λ)⁺, s² the
// residual variance, the coefficient part widened for an AR(1) residual as coef_ci95; e² the
// mean squared error of interval_validation_error (IntervalMethod::kValidation; else 0); v the
// variance of a learned session offset (τ²σ² / (nτ² + σ²) after n of the session's rows), and
// its measured coverage.
void set_prediction_interval(const Dataset& data, const std::vector<TermSpec>& specs,
                             const std::vector<std::uint8_t>& use, const AnalysisConfig& config,
                             AnalysisResult& result) {
  FitInfo info;
  info.want_covariance = true;
  const Model m = fit_terms(data, specs, use, &info);
  const std::vector<double> residual = residuals(data, m);
  double rss = 0.0;
  for (std::size_t i = 0; i < residual.size(); ++i) {
    if (use[i] != 0U && std::isfinite(residual[i])) rss += residual[i] * residual[i];
  }
  const double df = dz(info.rows) - info.effective_parameters;
  if (!(df >= 1.0)) return;
  PredictionInterval& pi = result.prediction_interval;
  const double s2 = rss / df;
  pi.sigma_in_sample_um = std::sqrt(s2);
  // The validation error's mean square: it already holds its refits' coefficient error, so it is
  // compared with the whole in-sample prediction variance of a row, not widened by x'Cx again.
  double v2 = 0.0;
  if (config.interval == IntervalMethod::kValidation) {
    const auto [ss, rows] = interval_validation_error(data, specs, use);
    if (rows > 0) {
      pi.method = IntervalMethod::kValidation;
      pi.validation_rows = rows;
      pi.validation_rms_um = std::sqrt(ss / dz(rows));
      v2 = ss / dz(rows);
    }
  }
  const double rho = config.ar1_correction
                         ? std::clamp(lag1_autocorrelation(data, residual, use), 0.0, 0.999)
                         : 0.0;
  const double inflate = (1.0 + rho) / (1.0 - rho);
  const double t = t95(df);
  Layout layout;
  layout.groups.resize(specs.size());
  for (std::size_t k = 0; k < specs.size(); ++k) {
    layout.groups[k] = m.terms()[k].groups;
    layout.offset.push_back(layout.parameters);
    layout.parameters += layout.groups[k].size() * basis_count(specs[k].form, specs[k].degree);
  }
  const std::size_t p = layout.parameters;
  if (info.coef_covariance.size() != p * p) return;
  const int st = m.session_term();
  // A row of a session the fit did not see: its learned offset takes the level of the other
  // terms too (their common shift against the fitted sessions' offsets), so their uncertainty
  // is that of a fit without the session term.
  std::vector<TermSpec> other_specs;
  for (std::size_t k = 0; k < specs.size(); ++k) {
    if (static_cast<int>(k) != st) other_specs.push_back(specs[k]);
  }
  FitInfo other_info;
  other_info.want_covariance = true;
  Model others;
  Layout other_layout;
  if (st >= 0 && !other_specs.empty()) {
    others = fit_terms(data, other_specs, use, &other_info);
    other_layout.groups.resize(other_specs.size());
    for (std::size_t k = 0; k < other_specs.size(); ++k) {
      other_layout.groups[k] = others.terms()[k].groups;
      other_layout.offset.push_back(other_layout.parameters);
      other_layout.parameters +=
          other_layout.groups[k].size() * basis_count(other_specs[k].form, other_specs[k].degree);
    }
  }
  const std::size_t po = other_layout.parameters;
  EvalState other_state = others.make_state();
  EvalState state = m.make_state();
  std::vector<Entry> x;
  std::array<double, kMaxBasis> b{};
  std::size_t covered = 0;
  double sum_half = 0.0;
  for (std::size_t i = 0; i < data.rows(); ++i) {
    const Row row = data.row(i);
    const double y = data.target_um[i];
    const double prediction = m.evaluate(row, state);
    if (st >= 0) others.evaluate(row, other_state);  // advances its lag filters
    if (result.heldout[i] == 1U && std::isfinite(y) && std::isfinite(prediction)) {
      const TermSpec* s = st >= 0 ? &specs[static_cast<std::size_t>(st)] : nullptr;
      const bool unseen = s != nullptr && term_basis(*s, row, kUnknown, b) > 0 &&
                          find_group(*s, layout.groups[static_cast<std::size_t>(st)], row) < 0;
      const bool use_others = unseen && po > 0 && other_info.coef_covariance.size() == po * po;
      EvalState aux = use_others ? other_state : state;  // kWear terms' basis in the lag slots
      set_wear_aux(use_others ? other_specs : specs, row, use_others ? &others : &m, aux);
      row_entries(use_others ? other_specs : specs, use_others ? other_layout : layout, row, aux,
                  x);
      const std::vector<double>& cov =
          use_others ? other_info.coef_covariance : info.coef_covariance;
      const std::size_t stride = use_others ? po : p;
      double q = 0.0;
      for (const Entry& u : x) {
        for (const Entry& v : x) q += u.value * v.value * cov[u.index * stride + v.index];
      }
      double v_session = 0.0;
      if (unseen) {
        const bool same_session = std::isfinite(state.session.session) &&
                                  !(state.session.session < row[kSessionColumn]) &&
                                  !(row[kSessionColumn] < state.session.session);
        const double n_s = same_session ? state.session.count : 0.0;
        const double tau2 = s->scale * s->scale;
        const double sigma2 = s->center * s->center;
        v_session = tau2 * sigma2 / std::max(n_s * tau2 + sigma2, 1e-300);
      }
      const double half =
          t * std::sqrt(std::max(s2 * (1.0 + std::max(0.0, q) * inflate), v2) + v_session);
      ++pi.rows;
      sum_half += half;
      pi.half_width_max_um = std::max(pi.half_width_max_um, half);
      if (std::fabs(y - prediction) <= half) ++covered;
    }
    m.observe(row, y, state);
  }
  if (pi.rows > 0) {
    pi.half_width_mean_um = sum_half / dz(pi.rows);
    pi.coverage = dz(covered) / dz(pi.rows);
  }
}

// --validate sessions: each session's rows predicted by the declared and the final terms fitted
// on the other sessions' rows (the outliers left out of every fit and figure, as elsewhere).
void validate_sessions(const Dataset& data, const std::vector<TermSpec>& declared,
                       const std::vector<TermSpec>& final_specs, AnalysisResult& result) {
  const std::size_t n = data.rows();
  std::uint32_t count = 0;
  for (const std::uint32_t s : result.session) count = std::max(count, s + 1);
  if (count < 2) {
    result.warnings.push_back(
        {"sessions_too_few", "--validate sessions: the rows form " + std::to_string(count) +
                                 " session: nothing to hold out (a session is a file, a warm "
                                 "start of a v2 log, or rows after a gap longer than "
                                 "session_gap_s)"});
    return;
  }
  std::vector<std::uint8_t> outlier(n, 0);
  for (const std::size_t i : result.outliers) outlier[i] = 1;
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  auto kind_applies = [&](const TermSpec& t, std::size_t i) { return term_applies(t, kind, i); };
  double ss_declared = 0.0;
  double ss_final = 0.0;
  for (std::uint32_t s = 0; s < count; ++s) {
    std::vector<std::uint8_t> use(n, 0);
    std::vector<std::uint8_t> mask(n, 0);
    SessionFold f;
    f.session = s;
    bool any = false;
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(data.target_um[i]) || outlier[i] != 0U) continue;
      (result.session[i] == s ? mask : use)[i] = 1;
      if (result.session[i] == s && !any) {
        f.first_row = i;
        any = true;
      }
    }
    if (!any) continue;
    // Groups of a per-group term that only this session has: fitted on the other sessions, the
    // term predicts 0 there, and the session's figure measures the missing group, not the model.
    std::size_t unseen_rows = 0;
    std::size_t listed = 0;
    std::string groups;
    std::vector<std::uint8_t> unseen(n, 0);
    for (const TermSpec& t : final_specs) {
      // A session term learns an unseen session from its own rows (Model::observe()).
      if ((t.per[0] < 0 && t.per[1] < 0) || t.form == Form::kSession) continue;
      std::map<std::array<double, 2>, bool> groups_of;  // true: in the other sessions' rows
      for (int pass : {0, 1}) {
        for (std::size_t i = 0; i < n; ++i) {
          if ((pass == 0 ? use[i] : mask[i]) == 0U || !kind_applies(t, i)) continue;
          bool ok = false;
          const auto key = group_key(t, data.row(i), ok);
          if (!ok) continue;
          const auto [it, added] = groups_of.emplace(key, pass == 0);
          if (it->second) continue;
          if (unseen[i] == 0U) ++unseen_rows;
          unseen[i] = 1;
          if (added && listed++ < 5) {
            groups += std::string(groups.empty() ? "" : ", ") + t.name + " " +
                      column_name(t.per[0], data.extra_columns) + " " + fmt_g(key[0]);
            if (t.per[1] >= 0) {
              groups += " " + column_name(t.per[1], data.extra_columns) + " " + fmt_g(key[1]);
            }
          }
        }
      }
    }
    if (unseen_rows > 0) {
      result.warnings.push_back(
          {"heldout_unseen_group",
           "--validate sessions: session " + std::to_string(s + 1) + " (from " +
               data.where(f.first_row) + ") held out: " + std::to_string(unseen_rows) +
               " of its rows belong to " + std::to_string(listed) +
               (listed == 1 ? " group" : " groups") + " no other session has (" + groups +
               (listed > 5 ? ", …" : "") +
               "): fitted on the other sessions, the model predicts nothing for them, so this "
               "session's figures measure the missing groups, not the model"});
    }
    try {
      f.declared = error_stats(residuals(data, fit_terms(data, declared, use)), mask, 1);
      f.final_model = error_stats(residuals(data, fit_terms(data, final_specs, use)), mask, 1);
    } catch (const AnalysisError& e) {
      result.warnings.push_back({"session_fold_failed", "--validate sessions: session " +
                                                            std::to_string(s + 1) + " (from " +
                                                            data.where(f.first_row) +
                                                            ") held out: " + e.what()});
      continue;
    }
    auto add = [](ErrorStats& total, double& ss, const ErrorStats& e) {
      ss += e.rms_um * e.rms_um * dz(e.rows);
      total.rows += e.rows;
      total.max_um = std::max(total.max_um, e.max_um);
      total.rms_um = total.rows > 0 ? std::sqrt(ss / dz(total.rows)) : 0.0;
    };
    add(result.sessions_declared, ss_declared, f.declared);
    add(result.sessions_final, ss_final, f.final_model);
    result.session_folds.push_back(f);
  }
}

void warn_fit(const FitInfo& info, const std::string& what, std::vector<Warning>& out) {
  if (info.parameters >= info.rows) {
    out.push_back({"saturated", what + " has " + std::to_string(info.parameters) +
                                    " coefficients for " + std::to_string(info.rows) +
                                    " fitted rows: its fitted RMS says nothing (it can be 0 for "
                                    "any data); only held-out figures do"});
  } else if (info.rank < info.parameters) {
    out.push_back({"collinear", what + " has " + std::to_string(info.parameters) +
                                    " coefficients but the data determine only " +
                                    std::to_string(info.rank) +
                                    " combinations: some terms (or groups) cannot be told apart, "
                                    "their coefficients are one of many equally good splits"});
  }
}

}  // namespace

double f_distribution_upper_tail(double f, double d1, double d2) {
  if (!(f > 0.0)) return 1.0;
  if (!std::isfinite(f)) return 0.0;
  const double x = d2 / (d2 + d1 * f);
  return incomplete_beta(0.5 * d2, 0.5 * d1, x);
}

Model fit_terms(const Dataset& data, const std::vector<TermSpec>& specs,
                const std::vector<std::uint8_t>& use, FitInfo* info) {
  // Terms proportional to the tool wear: the wear terms are fitted first on the tool_wear rows
  // (they see no other rows, so this is their joint fit too), and their prediction is the basis.
  std::unique_ptr<Model> wear_ref;
  if (std::any_of(specs.begin(), specs.end(),
                  [](const TermSpec& s) { return s.form == Form::kWear; })) {
    std::vector<TermSpec> base;
    for (const TermSpec& s : specs) {
      if (s.form != Form::kWear) base.push_back(s);
    }
    std::vector<std::uint8_t> use_wear(use);
    const auto& kind = data.column(static_cast<int>(Column::kKind));
    bool any = false;
    for (std::size_t i = 0; i < use_wear.size(); ++i) {
      const bool wear_row = !kind.empty() && std::isfinite(kind[i]) && kind[i] < 0.5;
      use_wear[i] = use_wear[i] != 0U && wear_row ? 1 : 0;
      any = any || use_wear[i] != 0U;
    }
    if (any && !base.empty()) {
      try {
        wear_ref = std::make_unique<Model>(fit_terms(data, base, use_wear));
      } catch (const AnalysisError&) {
        wear_ref.reset();  // no wear term fits the tool_wear rows: the wear basis is unknown
      }
    }
  }
  const Layout layout = discover_groups(data, specs, use, wear_ref.get());
  const auto p = static_cast<Eigen::Index>(layout.parameters);
  if (p == 0) throw AnalysisError("no term applies to any fitted row");
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(p, p);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(p);
  EvalState state;
  state.lag_value.assign(specs.size(), kUnknown);
  state.lag_input.assign(specs.size(), kUnknown);
  std::vector<Entry> entries;
  entries.reserve(specs.size() * kMaxBasis);
  std::size_t fitted_rows = 0;
  for (std::size_t i = 0; i < data.rows(); ++i) {
    const Row row = data.row(i);
    advance_state(specs, row, state);
    if (use[i] == 0U || !std::isfinite(data.target_um[i])) continue;
    ++fitted_rows;
    set_wear_aux(specs, row, wear_ref.get(), state);
    row_entries(specs, layout, row, state, entries);
    const double y = data.target_um[i];
    for (std::size_t u = 0; u < entries.size(); ++u) {
      const auto iu = static_cast<Eigen::Index>(entries[u].index);
      rhs(iu) += entries[u].value * y;
      for (std::size_t v = u; v < entries.size(); ++v) {
        const auto iv = static_cast<Eigen::Index>(entries[v].index);
        const double w = entries[u].value * entries[v].value;
        // Entries of one row are distinct indices; the upper triangle is mirrored below.
        if (iu <= iv) {
          a(iu, iv) += w;
        } else {
          a(iv, iu) += w;
        }
      }
    }
  }
  a.triangularView<Eigen::StrictlyLower>() = a.transpose().triangularView<Eigen::StrictlyLower>();
  // Session terms are random effects: their coefficients shrunk toward 0 by the ridge
  // λ = σ² / τ² (the BLUP for the term's noise σ and between-session τ).
  Eigen::VectorXd penalty;
  for (std::size_t t = 0; t < specs.size(); ++t) {
    if (specs[t].form != Form::kSession) continue;
    if (penalty.size() == 0) penalty = Eigen::VectorXd::Zero(p);
    const double tau = specs[t].scale;
    const double sigma = specs[t].center;
    const std::size_t n = layout.groups[t].size();
    for (std::size_t k = 0; k < n; ++k) {
      const auto i = static_cast<Eigen::Index>(layout.offset[t] + k);
      // τ = 0: no between-session variance, the offsets are held at 0.
      penalty(i) = tau > 0.0 ? sigma * sigma / (tau * tau) : 1e12 * (1.0 + a(i, i));
    }
  }
  std::size_t rank = 0;
  std::vector<double> variance;
  std::vector<double> hat;
  const bool want_variance = info != nullptr && info->want_variance;
  const bool want_covariance = info != nullptr && info->want_covariance;
  std::vector<double> covariance;
  const bool shrunk = penalty.size() == p;
  const Eigen::VectorXd beta =
      solve_normal(a, rhs, &rank, want_variance ? &variance : nullptr, penalty,
                   shrunk ? &hat : nullptr, want_covariance ? &covariance : nullptr);
  if (info != nullptr) {
    *info = FitInfo{fitted_rows,     layout.parameters,    rank,
                    want_variance,   std::move(variance),  dz(layout.parameters),
                    want_covariance, std::move(covariance)};
    for (std::size_t t = 0; t < specs.size() && shrunk; ++t) {
      if (specs[t].form != Form::kSession) continue;
      for (std::size_t k = 0; k < layout.groups[t].size(); ++k) {
        info->effective_parameters -= 1.0 - std::clamp(hat[layout.offset[t] + k], 0.0, 1.0);
      }
    }
  }
  std::vector<Term> terms;
  for (std::size_t t = 0; t < specs.size(); ++t) {
    Term term;
    term.spec = specs[t];
    term.groups = layout.groups[t];
    const std::size_t n = layout.groups[t].size() * basis_count(specs[t].form, specs[t].degree);
    for (std::size_t k = 0; k < n; ++k) {
      term.coef.push_back(beta(static_cast<Eigen::Index>(layout.offset[t] + k)));
      if (!std::isfinite(term.coef.back())) {
        throw AnalysisError("term '" + specs[t].name + "' (" +
                            term_column_name(specs[t], data.extra_columns) + ", " +
                            std::string(form_name(specs[t].form)) +
                            "): a coefficient is not a finite number (values too large)");
      }
    }
    terms.push_back(std::move(term));
  }
  return Model(data.extra_columns, std::move(terms));
}

std::vector<double> residuals(const Dataset& data, const Model& model) {
  std::vector<double> r(data.rows());
  EvalState state = model.make_state();
  for (std::size_t i = 0; i < data.rows(); ++i) {
    const Row row = data.row(i);
    r[i] = data.target_um[i] - model.evaluate(row, state);
    // A session the fit did not see is predicted as the daemon would: learned from its own
    // earlier rows, each row predicted before it is taken.
    model.observe(row, data.target_um[i], state);
  }
  return r;
}

double noise_floor_um(const Dataset& data, const std::vector<double>& residual,
                      const std::vector<std::uint8_t>& use) {
  std::map<std::tuple<double, double, double>, double> last;
  double ss = 0.0;
  std::size_t n = 0;
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  const auto& point = data.column(static_cast<int>(Column::kPoint));
  const auto& tool = data.column(static_cast<int>(Column::kTool));
  for (std::size_t i = 0; i < data.rows(); ++i) {
    if (use[i] == 0U || !std::isfinite(residual[i])) continue;
    const auto key = std::make_tuple(kind.empty() ? 0.0 : kind[i], point.empty() ? 0.0 : point[i],
                                     tool.empty() ? 0.0 : tool[i]);
    auto it = last.find(key);
    if (it != last.end()) {
      const double d = residual[i] - it->second;
      ss += d * d;
      ++n;
      it->second = residual[i];
    } else {
      last.emplace(key, residual[i]);
    }
  }
  // E[(e_i − e_{i−1})²] = 2σ² for independent noise.
  return n > 0 ? std::sqrt(ss / (2.0 * dz(n))) : 0.0;
}

double lag1_autocorrelation(const Dataset& data, const std::vector<double>& residual,
                            const std::vector<std::uint8_t>& use) {
  std::map<std::tuple<double, double, double>, double> last;
  double num = 0.0;
  double den = 0.0;
  const auto& kind = data.column(static_cast<int>(Column::kKind));
  const auto& point = data.column(static_cast<int>(Column::kPoint));
  const auto& tool = data.column(static_cast<int>(Column::kTool));
  for (std::size_t i = 0; i < data.rows(); ++i) {
    if (use[i] == 0U || !std::isfinite(residual[i])) continue;
    den += residual[i] * residual[i];
    const auto key = std::make_tuple(kind.empty() ? 0.0 : kind[i], point.empty() ? 0.0 : point[i],
                                     tool.empty() ? 0.0 : tool[i]);
    auto it = last.find(key);
    if (it != last.end()) {
      num += residual[i] * it->second;
      it->second = residual[i];
    } else {
      last.emplace(key, residual[i]);
    }
  }
  return den > 0.0 ? num / den : 0.0;
}

bool is_temperature_column(int column, const std::vector<std::string>& extras,
                           const SearchOptions& options) {
  for (const auto& [c, temperature] : options.column_is_temperature) {
    if (c == column) return temperature;
  }
  if (column == static_cast<int>(Column::kTemp)) return true;
  const std::string name = column_name(column, extras);
  return name.size() > 2 && name.compare(name.size() - 2, 2, "_c") == 0;
}

std::string effect_label(const std::string& name, const std::array<int, 2>& per,
                         const std::vector<std::string>& extras) {
  // A session term is per session by what it is.
  if (per[0] < 0 || per[0] == static_cast<int>(kSessionColumn)) return name;
  std::string out = name + " per=" + column_name(per[0], extras);
  if (per[1] >= 0) out += "+" + column_name(per[1], extras);
  return out;
}

std::string linear_effect_name(int column, const std::vector<std::string>& extras,
                               const SearchOptions& options) {
  return is_temperature_column(column, extras, options) ? "thermal_drift"
                                                        : "linear_" + column_name(column, extras);
}

std::vector<Candidate> make_candidates(const Dataset& data, const std::vector<std::uint8_t>& use,
                                       const SearchOptions& options,
                                       const std::vector<TermSpec>& declared) {
  std::vector<Candidate> out;
  auto excluded = [&](const std::string& name) {
    return std::find(options.exclude.begin(), options.exclude.end(), name) != options.exclude.end();
  };
  auto add = [&](const std::string& name, Form form, int column, int degree, Candidate c) {
    if (excluded(name)) return;
    c.spec.name = name;
    c.spec.form = form;
    c.spec.column = column;
    c.spec.degree = degree;
    c.spec.kind_mask = options.kind_mask;
    c.spec.per = options.per;
    out.push_back(std::move(c));
  };
  auto varies = [](const Range& r) { return r.n >= 8 && r.span() > 0.0; };
  const std::uint8_t km = options.kind_mask;
  const Range time = column_range(data, static_cast<int>(Column::kTime), use, km);
  const std::size_t n_fit = time.n;

  // Time: warm-up, level change.
  if (varies(time) && time.hi > 0.0) {
    Candidate c;
    c.grid = log_grid(time.hi / 200.0, time.hi * 2.0, 40);
    c.multiplicity = 1.0 + 3.0 * std::log10(400.0);
    add("thermal_drift", Form::kExpRise, static_cast<int>(Column::kTime), 1, c);
    Candidate s;
    // Change points between the 3 % and 97 % time quantiles of the fitted rows.
    std::vector<double> t;
    const auto& tc = data.column(static_cast<int>(Column::kTime));
    for (std::size_t i = 0; i < tc.size(); ++i) {
      if (use[i] != 0U && std::isfinite(tc[i])) t.push_back(tc[i]);
    }
    std::sort(t.begin(), t.end());
    for (std::size_t q = 3; q <= 97; ++q) {
      const double v = t[std::min(t.size() - 1, t.size() * q / 100)];
      if (s.grid.empty() || v > s.grid.back()) s.grid.push_back(v);
    }
    // Sup-F over change points: about 2 ln(n) effectively independent tests.
    s.multiplicity = std::max(1.0, 2.0 * std::log(dz(std::max<std::size_t>(n_fit, 3))));
    if (s.grid.size() >= 2) add("level_change", Form::kStep, static_cast<int>(Column::kTime), 1, s);
  }
  const Range temp = column_range(data, static_cast<int>(Column::kTemp), use, km);
  // A temperature's 0 °C means nothing to the machine: its linear term is counted from the
  // warm start, so that the term the daemon applies alone carries no intercept.
  auto linear = [&](const std::string& name, int col) {
    Candidate c;
    if (is_temperature_column(col, data.extra_columns, options)) {
      c.spec.center = linear_reference(warm_start_values(data, col, use, km));
    }
    add(name, Form::kLinear, col, 1, c);
  };
  if (varies(temp)) linear("thermal_drift", static_cast<int>(Column::kTemp));
  for (int col : options.linear_columns) {
    if (varies(column_range(data, col, use, km))) {
      linear(linear_effect_name(col, data.extra_columns, options), col);
    }
  }
  for (int col : options.lag_columns) {
    if (varies(column_range(data, col, use, km)) && varies(time)) {
      Candidate c;
      c.grid = log_grid(time.span() / 500.0, time.span(), 40);
      c.multiplicity = 1.0 + 3.0 * std::log10(500.0);
      add("thermal_drift", Form::kLag, col, 1, c);
    }
  }
  // Position: polynomial and periodic in each coordinate.
  const std::array<std::pair<Column, std::string>, 3> axes = {
      std::pair{Column::kX, std::string("x")}, std::pair{Column::kY, std::string("y")},
      std::pair{Column::kZ, std::string("z")}};
  for (const auto& [col, axis] : axes) {
    const Range r = column_range(data, static_cast<int>(col), use, km);
    if (!varies(r) || r.sd <= 0.0) continue;
    Candidate poly;
    poly.spec.center = r.mean;
    poly.spec.scale = r.sd;
    add("position_" + axis, Form::kPoly, static_cast<int>(col), 2, poly);
    const double f_lo = 2.0 / r.span();
    const double f_hi = 1.0 / std::max(options.period_min_mm, 1e-6);
    if (f_hi > f_lo) {
      Candidate c;
      // Frequencies 4× finer than the Fourier spacing 1/span, so no peak falls between points.
      const double df = 1.0 / (4.0 * r.span());
      const std::size_t count =
          std::min<std::size_t>(4000, static_cast<std::size_t>((f_hi - f_lo) / df) + 1);
      for (std::size_t i = 0; i < count; ++i) c.grid.push_back(1.0 / (f_hi - dz(i) * df));
      c.multiplicity = std::max(1.0, (f_hi - f_lo) * r.span());
      add("periodic_" + axis, Form::kSine, static_cast<int>(col), 1, c);
    }
  }
  // Interactions of a position with a temperature or with time (ball-screw growth ∝ position ×
  // temperature rise): one term with both main effects, named a*b.
  std::vector<int> drivers;
  if (varies(temp)) drivers.push_back(static_cast<int>(Column::kTemp));
  for (int col : options.linear_columns) {
    if (is_temperature_column(col, data.extra_columns, options) &&
        varies(column_range(data, col, use, km))) {
      drivers.push_back(col);
    }
  }
  if (varies(time)) drivers.push_back(static_cast<int>(Column::kTime));
  for (const auto& [col, axis] : axes) {
    const Range r = column_range(data, static_cast<int>(col), use, km);
    if (!varies(r)) continue;
    for (int d : drivers) {
      Candidate c;
      c.spec.center = column_range(data, d, use, km).mean;
      c.spec.column_b = static_cast<int>(col);
      c.spec.center_b = r.mean;
      add(column_name(d, data.extra_columns) + "*" +
              column_name(static_cast<int>(col), data.extra_columns),
          Form::kInteraction, d, 1, c);
    }
  }
  // Path: wear linear and non-linear (break-in, acceleration).
  const Range path = column_range(data, static_cast<int>(Column::kPath), use, km);
  if (varies(path)) {
    add("tool_wear", Form::kLinear, static_cast<int>(Column::kPath), 1, {});
    if (path.hi > 0.0) {
      Candidate c;
      c.grid = log_grid(path.hi / 200.0, path.hi * 2.0, 40);
      c.multiplicity = 1.0 + 3.0 * std::log10(400.0);
      add("wear_nonlinear", Form::kExpRise, static_cast<int>(Column::kPath), 1, c);
    }
    if (path.hi > 0.0) {
      // Accelerating wear towards the end of tool life (scale lengths within the data range).
      Candidate c;
      c.grid = log_grid(path.hi / 20.0, path.hi * 4.0, 30);
      c.multiplicity = 1.0 + 3.0 * std::log10(80.0);
      add("wear_nonlinear", Form::kExpGrowth, static_cast<int>(Column::kPath), 1, c);
    }
    {
      // A change of the wear rate at an unknown path (break-in → steady → accelerated wear).
      Candidate h;
      std::vector<double> v;
      const auto& pc = data.column(static_cast<int>(Column::kPath));
      for (std::size_t i = 0; i < pc.size(); ++i) {
        if (use[i] != 0U && std::isfinite(pc[i])) v.push_back(pc[i]);
      }
      std::sort(v.begin(), v.end());
      for (std::size_t q = 3; q <= 97; ++q) {
        const double x = v[std::min(v.size() - 1, v.size() * q / 100)];
        if (h.grid.empty() || x > h.grid.back()) h.grid.push_back(x);
      }
      h.multiplicity = std::max(1.0, 2.0 * std::log(dz(std::max<std::size_t>(v.size(), 3))));
      if (h.grid.size() >= 2)
        add("wear_nonlinear", Form::kHinge, static_cast<int>(Column::kPath), 1, h);
    }
    if (path.sd > 0.0) {
      Candidate q;
      q.spec.center = path.mean;
      q.spec.scale = path.sd;
      add("wear_nonlinear", Form::kPoly, static_cast<int>(Column::kPath), 2, q);
    }
  }
  // Proportional to the tool wear the model predicts (its terms on the tool_wear rows, e.g. a
  // declared wear curve per tool): one coefficient for the contour / calib rows, whatever shape
  // the wear has. Needs measured tool wear among the fitted rows.
  const bool wear_declared = std::any_of(declared.begin(), declared.end(), [](const TermSpec& s) {
    return (s.kind_mask & 1U) != 0U && s.form != Form::kWear && s.form != Form::kLag;
  });
  const std::uint8_t other_kinds = static_cast<std::uint8_t>(options.kind_mask & 0x6U);
  if (wear_declared && other_kinds != 0U &&
      varies(column_range(data, static_cast<int>(Column::kPath), use, other_kinds))) {
    const auto& kind = data.column(static_cast<int>(Column::kKind));
    const auto& point = data.column(static_cast<int>(Column::kPoint));
    std::size_t wear_rows = 0;
    double first_point = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < data.rows() && !kind.empty(); ++i) {
      if (use[i] == 0U || !std::isfinite(kind[i]) || kind[i] > 0.5) continue;
      ++wear_rows;
      if (!point.empty() && std::isfinite(point[i])) first_point = std::min(first_point, point[i]);
    }
    if (wear_rows >= 8 && !excluded("tool_wear")) {
      Candidate w;
      w.spec.name = "tool_wear";
      w.spec.form = Form::kWear;
      w.spec.column = static_cast<int>(Column::kPath);
      w.spec.kind_mask = other_kinds;
      w.spec.per = options.per;
      // The edge support point whose wear is the reference: the lowest one measured.
      w.spec.center = std::isfinite(first_point) ? first_point : 0.0;
      out.push_back(std::move(w));
    }
  }
  if (varies(column_range(data, static_cast<int>(Column::kPart), use, km))) {
    add("part_trend", Form::kLinear, static_cast<int>(Column::kPart), 1, {});
  }
  const Range angle = column_range(data, static_cast<int>(Column::kAngle), use, km);
  if (varies(angle) && angle.sd > 0.0) {
    Candidate c;
    c.spec.center = angle.mean;
    c.spec.scale = angle.sd;
    add("contact_angle", Form::kPoly, static_cast<int>(Column::kAngle), 2, c);
    if (varies(path)) {
      // Edge wear concentrated at some engagement angles grows with the wear: the angle
      // profile 1, u, u² times the cut path.
      Candidate pw = c;
      pw.spec.column_b = static_cast<int>(Column::kPath);
      add("contact_angle*tool_wear", Form::kProfileWear, static_cast<int>(Column::kAngle), 1, pw);
    }
  }
  // Per-group versions of every candidate (one coefficient set per axis, checkpoint, tool, …):
  // a rate of opposite signs per group averages out in the shared version.
  if (options.per[0] < 0 && options.per[1] < 0) {
    const std::size_t shared = out.size();
    for (int g : options.group_columns) {
      const std::size_t groups = count_groups(data, g, use, km);
      if (groups < 2 || groups > kMaxSearchGroups) continue;
      for (std::size_t i = 0; i < shared; ++i) {
        Candidate c = out[i];
        c.spec.per = {g, -1};
        c.grouped = true;
        out.push_back(std::move(c));
      }
    }
  }
  // One offset per session (a machine re-homed or warmed up each morning): a random effect,
  // its variances estimated when it is tried (estimate_session_variances()).
  const std::size_t sessions = count_sessions(data, use, km);
  if (sessions >= 2 && sessions <= kMaxSessions && !excluded("session_offset")) {
    Candidate c;
    c.spec.name = "session_offset";
    c.spec.form = Form::kSession;
    c.spec.column = static_cast<int>(kSessionColumn);
    c.spec.per = {static_cast<int>(kSessionColumn), -1};
    c.spec.kind_mask = km;
    c.spec.scale = 0.0;  // τ: not known before it is tried
    out.push_back(std::move(c));
  }
  return out;
}

namespace {

AnalysisResult analyze_numbered(const Dataset& data, const AnalysisConfig& config) {
  const std::size_t n = data.rows();
  if (n < 10) throw AnalysisError("the log has " + std::to_string(n) + " rows; at least 10 needed");
  check_magnitudes(data);
  AnalysisResult result;
  // Time-ordered split: the latest rows are held out of every fit (in the order over all
  // files when the reader gave one: time_s starts again at every warm start).
  std::vector<double> times;
  const auto& tc =
      data.order_s.size() == n ? data.order_s : data.column(static_cast<int>(Column::kTime));
  // Rows without a measurement are in neither part: they would move the split.
  for (std::size_t i = 0; i < tc.size(); ++i) {
    if (std::isfinite(tc[i]) && std::isfinite(data.target_um[i])) times.push_back(tc[i]);
  }
  result.heldout.assign(n, 0);
  if (!times.empty() && config.heldout_fraction > 0.0) {
    std::sort(times.begin(), times.end());
    const auto k = static_cast<std::size_t>(dz(times.size()) * (1.0 - config.heldout_fraction));
    result.split_time_s = times[std::min(k, times.size() - 1)];
    for (std::size_t i = 0; i < n; ++i) {
      if (std::isfinite(tc[i]) && tc[i] >= result.split_time_s) result.heldout[i] = 1;
    }
  }
  leave_out_unseen_groups(data, config.declared, result.heldout, result.warnings);
  std::vector<std::uint8_t> use(n);
  for (std::size_t i = 0; i < n; ++i) {
    use[i] = result.heldout[i] == 0U && std::isfinite(data.target_um[i]) ? 1 : 0;
  }

  std::vector<TermSpec> specs = config.declared;
  FitInfo info;
  Model model = fit_terms(data, specs, use, &info);
  if (config.outlier_sigmas > 0.0) {
    result.outliers =
        find_outliers(data, residuals(data, model), result.heldout, config.outlier_sigmas);
    if (!result.outliers.empty()) {
      for (std::size_t i : result.outliers) {
        result.heldout[i] = 2;
        use[i] = 0;
      }
      model = fit_terms(data, specs, use, &info);
    }
  }
  warn_fit(info, "the declared model", result.warnings);
  std::vector<double> residual;
  FitStats current = stats_of(data, model, result.heldout, &residual, "the declared model");
  current.effective_parameters = info.effective_parameters;
  result.declared = current;
  result.declared_residual_um = residual;
  if (current.heldout.rows == 0) {
    result.warnings.push_back(
        {"heldout_empty",
         times.empty() ? "no row has both time_s and a measurement: nothing is held out, no "
                         "held-out figure is given and only the F-test decides"
                       : "heldout_fraction = 0: nothing is held out, no held-out figure is given "
                         "and only the F-test decides"});
  }

  std::vector<Candidate> all = make_candidates(data, use, config.search, config.declared);
  for (int g : config.search.group_columns) {
    const std::size_t groups = count_groups(data, g, use, config.search.kind_mask);
    if (groups >= 2 && groups <= kMaxSearchGroups) continue;
    result.warnings.push_back(
        {"group_column_unused", "group_columns: '" + column_name(g, data.extra_columns) + "' has " +
                                    std::to_string(groups) + " values among the fitted rows (2 … " +
                                    std::to_string(kMaxSearchGroups) +
                                    " needed): no per-group candidate of it was tried"});
  }
  if (const std::size_t sessions = count_sessions(data, use, config.search.kind_mask);
      sessions > kMaxSessions) {
    result.warnings.push_back(
        {"session_offset_unused", "the fitted rows form " + std::to_string(sessions) +
                                      " sessions, more than " + std::to_string(kMaxSessions) +
                                      ": session_offset was not tried"});
  }
  struct Ranked {
    double bic;
    std::size_t index;
    double reduction;
    double validation{0.0};  // rolling-origin squared error (rank_folds), 0 when not computed
  };
  // Ranks the candidates not yet in the model by BIC on the search rows.
  auto rank = [&](const std::vector<TermSpec>& in_model, const Model& m,
                  const std::vector<double>& res, std::vector<Candidate>& cands,
                  std::vector<TriedCandidate>& tried) {
    cands.clear();
    tried.clear();
    std::vector<Ranked> ranked;
    for (const Candidate& c : all) {
      const auto present = std::count_if(in_model.begin(), in_model.end(),
                                         [&](const TermSpec& s) { return same_term(s, c.spec); });
      // A lag may be taken twice: two heat paths of one source with different time constants.
      if (present == 0 || (c.spec.form == Form::kLag && present == 1)) cands.push_back(c);
    }
    if (cands.empty()) return ranked;
    const SearchSet set = make_search_set(data, m, use, res, config.search_rows);
    const double n_sub = dz(set.rows.size());
    if (set.rss <= 0.0 || n_sub < 8.0) return ranked;
    for (std::size_t c = 0; c < cands.size(); ++c) {
      const auto [v, red] = search_candidate(data, set, cands[c]);
      if (!cands[c].grid.empty()) set_parameter(cands[c].spec, v);
      const double df = static_cast<double>(candidate_basis(data, set, cands[c].spec).cols()) +
                        (cands[c].grid.empty() ? 0.0 : 1.0);
      const double rss1 = std::max(set.rss - red, 1e-300);
      ranked.push_back({n_sub * std::log(rss1 / n_sub) + df * std::log(n_sub), c, red});
    }
    std::sort(ranked.begin(), ranked.end(),
              [](const Ranked& a, const Ranked& b) { return a.bic < b.bic; });
    // The best few by BIC in the order of their error on later hours predicted from earlier ones
    // (rank_folds): a candidate that fits the past but extrapolates badly is refitted last.
    if (config.rank_folds > 0) {
      const std::size_t pool = std::min(kRankPool, ranked.size());
      std::vector<std::size_t> which;
      for (std::size_t k = 0; k < pool; ++k) which.push_back(ranked[k].index);
      const std::vector<double> err = validation_errors(data, set, cands, which, config.rank_folds);
      for (std::size_t k = 0; k < err.size(); ++k) ranked[k].validation = err[k];
      std::stable_sort(
          ranked.begin(), ranked.begin() + static_cast<std::ptrdiff_t>(err.size()),
          [](const Ranked& a, const Ranked& b) { return a.validation < b.validation; });
    }
    for (const Ranked& rk : ranked) {
      const Candidate& c = cands[rk.index];
      TriedCandidate t_out;
      t_out.name = c.spec.name;
      t_out.column = term_column_name(c.spec, data.extra_columns);
      t_out.per = c.spec.per;
      t_out.form = c.spec.form;
      t_out.degree = c.spec.degree;
      t_out.parameter =
          c.spec.form == Form::kStep || c.spec.form == Form::kHinge || c.spec.form == Form::kWear
              ? c.spec.center
              : c.spec.scale;
      t_out.rss_reduction_fraction = rk.reduction / set.rss;
      // A projection cannot remove more than the residual: anything else is a numerical failure,
      // and must not rank first.
      if (!(t_out.rss_reduction_fraction >= 0.0 && t_out.rss_reduction_fraction <= 1.0 + 1e-9)) {
        throw AnalysisError("candidate '" + t_out.name + "' (" + t_out.column + ", " +
                            std::string(form_name(t_out.form)) +
                            "): share of the residual removed " +
                            fmt_g(t_out.rss_reduction_fraction) +
                            " is not within [0, 1] (numerically unusable columns)");
      }
      tried.push_back(t_out);
    }
    return ranked;
  };
  struct Trial {
    std::vector<TermSpec> specs;
    Model model;
    std::vector<double> residual;
    FitStats stats;
    FitInfo info;
    double p_adj{1.0};
    double f{0.0};
  };
  // Refits with one more term; nested F-test against `base`, Bonferroni-adjusted.
  auto trial = [&](const std::vector<TermSpec>& base_specs, const FitStats& base,
                   const std::vector<double>& base_residual, const Candidate& c,
                   std::size_t n_cands) {
    Trial t;
    t.specs = base_specs;
    t.specs.push_back(c.spec);
    if (c.spec.form == Form::kSession) {
      estimate_session_variances(data, use, base_residual, t.specs.back());
    }
    t.model = fit_terms(data, t.specs, use, &t.info);
    t.stats = stats_of(data, t.model, result.heldout, &t.residual,
                       "candidate '" + c.spec.name + "' (" +
                           term_column_name(c.spec, data.extra_columns) + ", " +
                           std::string(form_name(c.spec.form)) + ")");
    t.stats.effective_parameters = t.info.effective_parameters;
    // The non-linear parameter, or the session term's between-session variance, is one more.
    const double extra = c.grid.empty() && c.spec.form != Form::kSession ? 0.0 : 1.0;
    // A shrunk term adds its effective degrees of freedom (below its coefficient count).
    const double gained = t.stats.effective_parameters - base.effective_parameters;
    const double df1 = (gained > 0.0 ? gained : 1.0) + extra;
    // Rows sampled densely in time (a gauge every 15 s) have correlated residuals: the F-test
    // would count them as independent. Scale to the effective number of rows of an AR(1)
    // residual, n (1 − ρ) / (1 + ρ); independent rows (ρ ≈ 0) keep the plain test.
    const double rho = config.ar1_correction
                           ? std::clamp(lag1_autocorrelation(data, t.residual, use), 0.0, 0.999)
                           : 0.0;
    const double shrink = (1.0 - rho) / (1.0 + rho);
    const double df2 = dz(t.stats.fitted.rows) * shrink - t.stats.effective_parameters - extra;
    if (df2 > 0.0 && t.stats.rss < base.rss) {
      t.f = ((base.rss - t.stats.rss) / df1) / (std::max(t.stats.rss, 1e-300) / df2);
      const double p = f_distribution_upper_tail(t.f, df1, df2);
      t.p_adj = std::min(1.0, p * c.multiplicity * dz(n_cands));
    }
    return t;
  };
  auto heldout_better = [&](const FitStats& after, const FitStats& before) {
    return before.heldout.rows == 0 || after.heldout.rms_um < before.heldout.rms_um;
  };
  auto accept = [&](const Candidate& c, const Trial& t) {
    if (c.spec.form == Form::kSine) {
      const SearchSet set = make_search_set(data, model, use, residual, config.search_rows);
      const std::vector<double> alias = equivalent_periods(data, set, c);
      if (!alias.empty()) {
        const std::string col = column_name(c.spec.column, data.extra_columns);
        std::string list;
        for (double p : alias) list += (list.empty() ? "" : ", ") + fmt_g(p);
        result.warnings.push_back(
            {"period_ambiguous",
             c.spec.name + ": periods " + list + " (" + col + ") fit the samples as well as the " +
                 fmt_g(c.spec.scale) + " chosen (within 2 %): the " + col +
                 " positions measured cannot tell them apart (aliasing); measure between them"});
      }
    }
    AddedEffect e;
    e.spec = t.specs.back();  // with what the trial estimated (a session term's variances)
    e.before = current;
    e.after = t.stats;
    e.p_value = t.p_adj;
    e.f_statistic = t.f;
    result.effects.push_back(e);
    specs = t.specs;
    model = t.model;
    info = t.info;
    residual = t.residual;
    current = t.stats;
  };

  std::vector<Candidate> cands;
  std::vector<TriedCandidate> tried;
  while (result.effects.size() < config.max_effects) {
    const std::vector<Ranked> ranked = rank(specs, model, residual, cands, tried);
    bool added = false;
    for (std::size_t k = 0; k < std::min(kRefitPerStep, ranked.size()) && !added; ++k) {
      const Candidate c = cands[ranked[k].index];
      const Trial t = trial(specs, current, residual, c, cands.size());
      const bool better = heldout_better(t.stats, current);
      tried[k].p_value = t.p_adj;
      tried[k].heldout_improved = better;
      tried[k].refitted = true;
      if (t.p_adj >= config.alpha) continue;
      if (better) {
        accept(c, t);
        added = true;
        break;
      }
      // Significant on the fitted rows but worse on the held-out ones: a real effect can be
      // masked by a second one that dominates the later rows (wear break-in vs. acceleration).
      // Look one step ahead: accept the pair only if the second term is significant given the
      // first and the pair lowers the held-out error.
      if (!config.lookahead || result.effects.size() + 2 > config.max_effects) continue;
      std::vector<Candidate> cands2;
      std::vector<TriedCandidate> tried2;
      const std::vector<Ranked> ranked2 = rank(t.specs, t.model, t.residual, cands2, tried2);
      for (std::size_t k2 = 0; k2 < std::min(kRefitPerStep, ranked2.size()) && !added; ++k2) {
        const Candidate c2 = cands2[ranked2[k2].index];
        const Trial t2 = trial(t.specs, t.stats, t.residual, c2, cands2.size());
        tried2[k2].p_value = t2.p_adj;
        tried2[k2].heldout_improved = heldout_better(t2.stats, current);
        tried2[k2].refitted = true;
        if (t2.p_adj < config.alpha && heldout_better(t2.stats, current)) {
          result.steps.push_back(tried);
          accept(c, t);
          tried = std::move(tried2);
          accept(c2, t2);
          added = true;
        }
      }
    }
    result.steps.push_back(std::move(tried));
    if (!added) break;
  }
  result.final_stats = current;
  result.final_residual_um = residual;
  result.noise_floor_um = noise_floor_um(data, residual, use);
  std::vector<std::uint8_t> all_rows(n);
  for (std::size_t i = 0; i < n; ++i) all_rows[i] = std::isfinite(data.target_um[i]) ? 1 : 0;
  for (const std::size_t i : result.outliers) all_rows[i] = 0;  // reported, never fitted
  result.fitted_model = model;
  set_confidence_intervals(data, specs, use, residual, config, result);
  set_prediction_interval(data, specs, use, config, result);
  result.final_model = fit_terms(data, specs, all_rows);
  if (!result.effects.empty()) warn_fit(info, "the final model", result.warnings);
  result.session = config.validate_block_s > 0.0 ? time_blocks(data, config.validate_block_s)
                                                 : sessions_of(data, config.session_gap_s);
  if (config.validate_sessions) validate_sessions(data, config.declared, specs, result);
  return result;
}

}  // namespace

AnalysisResult analyze(const Dataset& data, const AnalysisConfig& config) {
  // Rows carry their session (kSessionColumn) as sessions_of() numbers it: a copy of the rows
  // only where that differs from the reader's numbering (a gap rule that splits a session).
  std::vector<std::uint32_t> sessions = sessions_of(data, config.session_gap_s);
  const bool same =
      data.row_session.size() == data.rows()
          ? data.row_session == sessions
          : std::all_of(sessions.begin(), sessions.end(), [](std::uint32_t s) { return s == 0U; });
  if (same) return analyze_numbered(data, config);
  Dataset numbered = data;
  numbered.row_session = std::move(sessions);
  return analyze_numbered(numbered, config);
}

std::vector<std::uint32_t> sessions_of(const Dataset& data, double gap_s) {
  const std::size_t n = data.rows();
  const auto& t =
      data.order_s.size() == n ? data.order_s : data.column(static_cast<int>(Column::kTime));
  const bool by_reader = data.row_session.size() == n;
  // Reader session → time of its previous row, and the session that row is in.
  std::map<std::uint32_t, std::pair<double, std::uint32_t>> last;
  std::vector<std::uint32_t> out(n, 0);
  std::uint32_t next = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t reader = by_reader ? data.row_session[i] : 0U;
    const double t_s = t.size() == n ? t[i] : kUnknown;
    auto it = last.find(reader);
    if (it == last.end()) {
      it = last.emplace(reader, std::make_pair(t_s, next++)).first;
    } else if (gap_s > 0.0 && std::isfinite(t_s) && std::isfinite(it->second.first) &&
               t_s - it->second.first > gap_s) {
      it->second.second = next++;
    }
    if (std::isfinite(t_s)) it->second.first = t_s;
    out[i] = it->second.second;
  }
  return out;
}

}  // namespace nccomp::core::model
