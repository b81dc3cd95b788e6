// GIVEN generated logs with one undeclared effect of each kind (a few µm against 0.3–1 µm of
// noise, irregular part times) WHEN analysed THEN the right effect is added, the final RMS is
// within 1.2× the noise and the held-out error drops (issue 11, item 4).
#include <gtest/gtest.h>

#include <string>

#include "core/model/analysis.hpp"
#include "tests/unit/model/synth.hpp"

namespace cm = nccomp::core::model;
namespace synth = nccomp::test::synth;

namespace {

struct Case {
  std::string generated;  // synth effect
  std::string expected;   // effect name of issue 11
  cm::Form form;
  double noise_um;
};

class OneUndeclaredEffect : public ::testing::TestWithParam<Case> {};

TEST_P(OneUndeclaredEffect, IsFoundAndCompensated) {
  const Case& c = GetParam();
  synth::Options opt;
  opt.seed = 7;
  opt.noise_um = c.noise_um;
  opt.effects = {c.generated};
  const cm::Dataset data = synth::generate(opt);
  const cm::AnalysisResult r = cm::analyze(data, synth::config());

  ASSERT_EQ(r.effects.size(), 1U) << "first: "
                                  << (r.effects.empty() ? "none" : r.effects[0].spec.name);
  const cm::AddedEffect& e = r.effects[0];
  EXPECT_EQ(e.spec.name, c.expected);
  EXPECT_EQ(e.spec.form, c.form);
  EXPECT_LT(e.p_value, 1e-6);
  EXPECT_GT(r.declared.fitted.rms_um, 1.5 * c.noise_um);
  EXPECT_LE(r.final_stats.fitted.rms_um, 1.2 * c.noise_um);
  EXPECT_LT(e.after.heldout.rms_um, e.before.heldout.rms_um);
  EXPECT_LE(r.final_stats.heldout.rms_um, 1.5 * c.noise_um);
  // The noise floor estimate is the probe noise (successive differences of the residual).
  EXPECT_NEAR(r.noise_floor_um, c.noise_um, 0.15 * c.noise_um);
}

INSTANTIATE_TEST_SUITE_P(
    EachKind, OneUndeclaredEffect,
    ::testing::Values(Case{"thermal_drift", "thermal_drift", cm::Form::kExpRise, 0.5},
                      Case{"thermal_temp", "thermal_drift", cm::Form::kLinear, 0.5},
                      Case{"position_x", "position_x", cm::Form::kPoly, 0.7},
                      Case{"periodic_x", "periodic_x", cm::Form::kSine, 0.5},
                      Case{"tool_wear", "tool_wear", cm::Form::kLinear, 0.3},
                      Case{"wear_nonlinear", "wear_nonlinear", cm::Form::kExpRise, 0.5},
                      Case{"part_trend", "part_trend", cm::Form::kLinear, 0.5},
                      Case{"level_change", "level_change", cm::Form::kStep, 1.0},
                      Case{"contact_angle", "contact_angle", cm::Form::kPoly, 0.5}),
    [](const ::testing::TestParamInfo<Case>& i) { return i.param.generated; });

TEST(TwoUndeclaredEffects, AreBothFound) {
  synth::Options opt;
  opt.seed = 11;
  opt.noise_um = 0.5;
  opt.effects = {"periodic_x", "thermal_drift"};
  const cm::AnalysisResult r = cm::analyze(synth::generate(opt), synth::config());
  ASSERT_EQ(r.effects.size(), 2U);
  std::vector<std::string> names = {r.effects[0].spec.name, r.effects[1].spec.name};
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names[0], "periodic_x");
  EXPECT_EQ(names[1], "thermal_drift");
  EXPECT_LE(r.final_stats.fitted.rms_um, 1.2 * opt.noise_um);
  EXPECT_LT(r.final_stats.heldout.rms_um, r.declared.heldout.rms_um);
  // Each step lowers both errors.
  for (const auto& e : r.effects) {
    EXPECT_LT(e.after.fitted.rms_um, e.before.fitted.rms_um);
    EXPECT_LT(e.after.heldout.rms_um, e.before.heldout.rms_um);
  }
}

TEST(FittedParameters, AreTheGeneratedOnes) {
  synth::Options opt;
  opt.seed = 3;
  opt.noise_um = 0.5;
  opt.effects = {"periodic_x"};
  const cm::AnalysisResult r = cm::analyze(synth::generate(opt), synth::config());
  ASSERT_EQ(r.effects.size(), 1U);
  EXPECT_NEAR(r.effects[0].spec.scale, 25.0, 0.05);  // period [mm]
  // Amplitude 2.5 µm from the sine and cosine coefficients of the fitted term.
  const auto& t = r.fitted_model.terms().back();
  ASSERT_EQ(t.coef.size(), 2U);
  EXPECT_NEAR(std::hypot(t.coef[0], t.coef[1]), 2.5, 0.1);
}

TEST(FinalModel, EvaluatesToTheFittedPrediction) {
  synth::Options opt;
  opt.seed = 5;
  opt.parts = 30;
  opt.effects = {"thermal_drift"};
  const cm::Dataset d = synth::generate(opt);
  const cm::AnalysisResult r = cm::analyze(d, synth::config());
  // Residual of the final model (fitted on all rows) over all rows stays at the noise.
  const auto res = cm::residuals(d, r.final_model);
  double ss = 0.0;
  for (double v : res) ss += v * v;
  EXPECT_LT(std::sqrt(ss / static_cast<double>(res.size())), 1.2 * opt.noise_um);
}

TEST(Analyze, RefusesTooFewRows) {
  synth::Options opt;
  opt.parts = 1;
  opt.points_per_part = 5;
  EXPECT_THROW(cm::analyze(synth::generate(opt), synth::config()), cm::AnalysisError);
}

}  // namespace
