// Fleet analysis (core/model/fleet.hpp): the random-effects estimate against its closed form
// for balanced data, a fleet with one shared and one machine's own effect, and a fleet without
// any undeclared effect over 50 seeds.
#include "core/model/fleet.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "tests/unit/model/synth.hpp"

namespace cm = nccomp::core::model;
namespace synth = nccomp::test::synth;

namespace {

constexpr int kTemp = static_cast<int>(cm::Column::kTemp);
constexpr int kPoint = static_cast<int>(cm::Column::kPoint);

double mean_of(const std::vector<double>& v) {
  return std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
}

double sample_variance(const std::vector<double>& v) {
  const double m = mean_of(v);
  double s = 0.0;
  for (double x : v) s += (x - m) * (x - m);
  return s / static_cast<double>(v.size() - 1);
}

// One machine's log: synth's parts (per-checkpoint constants of its own, noise 0.5 µm) with a
// thermal error slope_um_per_k · (temp_c − 20) and synth's named effects.
cm::Dataset machine_log(std::uint64_t seed, double slope_um_per_k,
                        const std::vector<std::string>& effects = {}) {
  synth::Options opt;
  opt.seed = seed;
  opt.parts = 30;
  opt.points_per_part = 12;
  opt.noise_um = 0.5;
  opt.effects = effects;
  cm::Dataset d = synth::generate(opt);
  const auto& temp = d.column(kTemp);
  for (std::size_t i = 0; i < d.rows(); ++i) d.target_um[i] += slope_um_per_k * (temp[i] - 20.0);
  return d;
}

const cm::FleetTerm* find_term(const cm::FleetResult& r, const std::string& name, int column) {
  for (const auto& t : r.terms) {
    if (t.spec.name == name && t.spec.column == column) return &t;
  }
  return nullptr;
}

}  // namespace

// GIVEN five estimates with one variance v WHEN combined THEN τ² = max(0, s² − v), μ = their
// mean and each BLUP = μ + τ² / (τ² + v) · (β − μ), the closed form of balanced data.
TEST(RandomEffect, BalancedDataMatchClosedForm) {
  const std::vector<double> beta = {0.8, 1.25, 0.95, 1.4, 1.1};
  for (const double v : {0.001, 0.02, 0.5}) {
    const std::vector<double> var(beta.size(), v);
    const cm::RandomEffect re = cm::random_effect(beta, var);
    const double s2 = sample_variance(beta);  // 0.05625
    const double tau2 = std::max(0.0, s2 - v);
    EXPECT_NEAR(re.tau2, tau2, 1e-12) << "v " << v;
    EXPECT_NEAR(re.mean, mean_of(beta), 1e-12);
    EXPECT_NEAR(re.mean_variance, (tau2 + v) / static_cast<double>(beta.size()), 1e-12);
    for (std::size_t i = 0; i < beta.size(); ++i) {
      const double w = tau2 / (tau2 + v);
      EXPECT_NEAR(re.own_weight[i], w, 1e-12);
      EXPECT_NEAR(re.blup[i], mean_of(beta) + w * (beta[i] - mean_of(beta)), 1e-12);
    }
  }
  // v above the spread: no between-machine variance, every machine gets the type mean.
  const cm::RandomEffect flat = cm::random_effect(beta, std::vector<double>(beta.size(), 0.5));
  EXPECT_EQ(flat.tau2, 0.0);
  for (double b : flat.blup) EXPECT_NEAR(b, mean_of(beta), 1e-12);
}

// GIVEN unequal variances WHEN combined THEN the precise machine keeps more of its own estimate,
// one machine alone keeps its estimate, and an unusable variance is refused.
TEST(RandomEffect, UnbalancedAndDegenerateInputs) {
  const cm::RandomEffect re = cm::random_effect({0.5, 1.5, 1.0}, {0.01, 0.04, 0.16});
  EXPECT_GT(re.tau2, 0.0);
  EXPECT_GT(re.own_weight[0], re.own_weight[1]);
  EXPECT_GT(re.own_weight[1], re.own_weight[2]);
  const cm::RandomEffect one = cm::random_effect({2.0}, {0.3});
  EXPECT_EQ(one.blup[0], 2.0);
  EXPECT_EQ(one.mean, 2.0);
  EXPECT_THROW(cm::random_effect({1.0, 2.0}, {0.1, 0.0}), cm::AnalysisError);
  EXPECT_THROW(cm::random_effect({1.0, 2.0}, {0.1, NAN}), cm::AnalysisError);
  EXPECT_THROW(cm::random_effect({}, {}), cm::AnalysisError);
}

// GIVEN five machines with the same rows, the same noise, their own checkpoint constants and an
// undeclared thermal slope each of 0.8 … 1.4 µm/K, WHEN the fleet is analysed THEN thermal_drift
// is common, every machine's slope estimate is its slope + the same noise term with one
// variance v = σ² / Sxx (σ² from the residual of the within-checkpoint regression, computed
// here), τ², μ and the BLUPs are those of the closed form, and the models carry them.
TEST(Fleet, BalancedShrinkageMatchesClosedForm) {
  const std::vector<double> slope = {0.8, 1.4, 1.1, 0.95, 1.25};
  const cm::Dataset base = machine_log(7, 0.0);
  std::mt19937_64 rng(99);
  std::uniform_real_distribution<double> uni(-3.0, 3.0);
  const cm::AnalysisConfig config = synth::config();
  std::vector<cm::FleetMachine> fleet;
  for (std::size_t m = 0; m < slope.size(); ++m) {
    cm::FleetMachine fm{"m" + std::to_string(m + 1), base};
    std::vector<double> offset(12);
    for (auto& o : offset) o = uni(rng);
    const auto& temp = base.column(kTemp);
    const auto& point = base.column(kPoint);
    for (std::size_t i = 0; i < base.rows(); ++i) {
      // base.target_um: its own constants + noise; the same noise on every machine.
      fm.data.target_um[i] +=
          offset[static_cast<std::size_t>(point[i])] + slope[m] * (temp[i] - 20.0);
    }
    fleet.push_back(std::move(fm));
  }
  const cm::FleetResult r = cm::analyze_fleet(fleet, config);
  const cm::FleetTerm* t = find_term(r, "thermal_drift", kTemp);
  ASSERT_NE(t, nullptr);
  EXPECT_EQ(t->role, cm::FleetRole::kCommon);
  EXPECT_EQ(r.terms.size(), 2U) << "the search found more than the thermal effect";
  ASSERT_EQ(t->coefficients.size(), 1U);
  const cm::FleetCoefficient& c = t->coefficients[0];

  // The within-checkpoint regression of the base rows, by hand.
  const auto& temp = base.column(kTemp);
  const auto& point = base.column(kPoint);
  std::vector<double> st(12, 0.0);
  std::vector<double> sy(12, 0.0);
  std::vector<double> n(12, 0.0);
  for (std::size_t i = 0; i < base.rows(); ++i) {
    const auto p = static_cast<std::size_t>(point[i]);
    st[p] += temp[i];
    sy[p] += base.target_um[i];
    n[p] += 1.0;
  }
  double sxx = 0.0;
  double sxy = 0.0;
  for (std::size_t i = 0; i < base.rows(); ++i) {
    const auto p = static_cast<std::size_t>(point[i]);
    const double dt = temp[i] - st[p] / n[p];
    sxx += dt * dt;
    sxy += dt * (base.target_um[i] - sy[p] / n[p]);
  }
  const double noise_slope = sxy / sxx;
  double rss = 0.0;
  for (std::size_t i = 0; i < base.rows(); ++i) {
    const auto p = static_cast<std::size_t>(point[i]);
    const double e = base.target_um[i] - sy[p] / n[p] - noise_slope * (temp[i] - st[p] / n[p]);
    rss += e * e;
  }
  const double v = rss / (static_cast<double>(base.rows()) - 13.0) / sxx;
  std::vector<double> estimate;
  for (std::size_t m = 0; m < slope.size(); ++m) {
    EXPECT_NEAR(c.estimate[m], slope[m] + noise_slope, 1e-9) << r.machines[m];
    EXPECT_NEAR(c.variance[m], v, 1e-9 * v) << r.machines[m];
    estimate.push_back(slope[m] + noise_slope);
  }
  const double tau2 = std::max(0.0, sample_variance(estimate) - v);
  const double mu = mean_of(estimate);
  EXPECT_GT(tau2, 0.0);
  EXPECT_NEAR(c.effect.tau2, tau2, 1e-9);
  EXPECT_NEAR(c.effect.mean, mu, 1e-9);
  for (std::size_t m = 0; m < slope.size(); ++m) {
    const double blup = mu + tau2 / (tau2 + v) * (estimate[m] - mu);
    EXPECT_NEAR(c.effect.blup[m], blup, 1e-9);
    // The machine's model carries the BLUP, the type's the mean.
    const cm::Term* term = nullptr;
    for (const auto& x : r.machine_models[m].terms()) {
      if (x.spec.name == "thermal_drift") term = &x;
    }
    ASSERT_NE(term, nullptr);
    EXPECT_NEAR(term->coef[0], blup, 1e-9);
  }
  ASSERT_EQ(r.type_model.terms().size(), 2U);
  EXPECT_EQ(r.type_model.terms()[1].spec.name, "thermal_drift");
  EXPECT_NEAR(r.type_model.terms()[1].coef[0], mu, 1e-9);
}

// GIVEN five machines with the same undeclared thermal effect at 0.8 … 1.4 µm/K and machine m4
// with a position-dependent error of its own (synth's position_x, up to 7 µm) WHEN the fleet
// is analysed THEN thermal_drift is common to the type with a mean near 1.1 µm/K, position_x
// belongs to m4 alone (in m4's model, in no other and not in the type's), and nothing else is
// called a machine's own.
TEST(Fleet, FindsTheSharedEffectAndTheOddMachine) {
  const std::vector<double> slope = {0.8, 1.4, 1.1, 0.95, 1.25};
  std::vector<cm::FleetMachine> fleet;
  for (std::size_t m = 0; m < slope.size(); ++m) {
    const std::vector<std::string> effects =
        m == 3 ? std::vector<std::string>{"position_x"} : std::vector<std::string>{};
    fleet.push_back({"m" + std::to_string(m + 1), machine_log(100 + m, slope[m], effects)});
  }
  const cm::FleetResult r = cm::analyze_fleet(fleet, synth::config());
  for (const auto& t : r.terms) {  // for the test's log
    std::printf("%s col %d form %d role %d:", t.spec.name.c_str(), t.spec.column,
                static_cast<int>(t.spec.form), static_cast<int>(t.role));
    for (double p : t.p_value) std::printf(" %g", p);
    std::printf(" type %g found", t.type_p_value);
    for (auto m : t.found_on) std::printf(" %zu", m);
    std::printf("\n");
  }
  for (const auto& w : r.warnings) std::printf("%s %s\n", w.code.c_str(), w.message.c_str());
  const cm::FleetTerm* thermal = find_term(r, "thermal_drift", kTemp);
  ASSERT_NE(thermal, nullptr);
  EXPECT_EQ(thermal->role, cm::FleetRole::kCommon);
  ASSERT_EQ(thermal->coefficients.size(), 1U);
  const cm::FleetCoefficient& c = thermal->coefficients[0];
  EXPECT_NEAR(c.effect.mean, 1.1, 0.25);
  for (std::size_t m = 0; m < slope.size(); ++m) {
    // Shrunk toward the mean, never past it.
    EXPECT_LE(std::abs(c.effect.blup[m] - c.effect.mean),
              std::abs(c.estimate[m] - c.effect.mean) + 1e-12);
    EXPECT_NEAR(c.effect.blup[m], slope[m], 0.2) << r.machines[m];
  }
  const cm::FleetTerm* position = find_term(r, "position_x", static_cast<int>(cm::Column::kX));
  ASSERT_NE(position, nullptr);
  EXPECT_EQ(position->role, cm::FleetRole::kMachine);
  EXPECT_EQ(r.machines[position->owner], "m4");
  for (const auto& t : r.terms) {
    if (&t != position) {
      EXPECT_NE(t.role, cm::FleetRole::kMachine) << t.spec.name;
    }
  }
  for (std::size_t m = 0; m < slope.size(); ++m) {
    bool has = false;
    for (const auto& x : r.machine_models[m].terms()) has = has || x.spec.name == "position_x";
    EXPECT_EQ(has, m == 3) << r.machines[m];
  }
  for (const auto& x : r.type_model.terms()) EXPECT_NE(x.spec.name, "position_x");
  // m4's own effect is compensated on m4: its fleet model is as good as its own search.
  EXPECT_LT(r.fits[3].own.rms_um, 1.2 * r.fits[3].alone.rms_um);
}

// GIVEN fleets of five machines without any undeclared effect (only their own checkpoint
// constants and noise) WHEN analysed with 50 seeds THEN at most 5 % find an effect of one
// machine's own.
TEST(Fleet, NoEffectFleetFindsNothingPerMachineInFiftySeeds) {
  constexpr int kSeeds = 50;
  int own = 0;
  int common = 0;
  for (int seed = 1; seed <= kSeeds; ++seed) {
    std::vector<cm::FleetMachine> fleet;
    for (std::uint64_t m = 0; m < 5; ++m) {
      fleet.push_back({"m" + std::to_string(m + 1),
                       machine_log(static_cast<std::uint64_t>(seed) * 10 + m + 20000, 0.0)});
    }
    const cm::FleetResult r = cm::analyze_fleet(fleet, synth::config());
    bool any_own = false;
    for (const auto& t : r.terms) {
      if (t.role == cm::FleetRole::kMachine) {
        any_own = true;
        std::printf("seed %d: %s of %s\n", seed, t.spec.name.c_str(), r.machines[t.owner].c_str());
      }
      if (t.role == cm::FleetRole::kCommon) ++common;
    }
    own += any_own ? 1 : 0;
  }
  std::printf("fleets with an effect of one machine's own: %d of %d; common effects: %d\n", own,
              kSeeds, common);
  EXPECT_LE(own, kSeeds * 5 / 100);
}
