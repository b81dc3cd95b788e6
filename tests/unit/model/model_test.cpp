// GIVEN a fitted model WHEN it is evaluated THEN it returns the sum of its terms, allocation-free.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "core/model/analysis.hpp"
#include "core/model/model.hpp"
#include "tests/support/alloc_counter.hpp"

namespace cm = nccomp::core::model;

namespace {

cm::Term term(const std::string& name, cm::Form form, int column, double scale,
              std::vector<std::array<double, 2>> groups, std::vector<double> coef) {
  cm::Term t;
  t.spec.name = name;
  t.spec.form = form;
  t.spec.column = column;
  t.spec.scale = scale;
  t.groups = std::move(groups);
  t.coef = std::move(coef);
  return t;
}

cm::Row contour_row(double t_s, double point, double x_mm) {
  cm::Row r = cm::unknown_row();
  r[0] = t_s;
  r[3] = 1.0;
  r[4] = point;
  r[5] = x_mm;
  return r;
}

}  // namespace

TEST(ModelEvaluate, SumsTermsPerGroupAndIsAllocationFree) {
  cm::Term offset =
      term("offset", cm::Form::kConstant, -1, 1.0, {{1.0, 0.0}, {2.0, 0.0}}, {3.0, -2.0});
  offset.spec.per = {static_cast<int>(cm::Column::kPoint), -1};
  cm::Term warm = term("thermal_drift", cm::Form::kExpRise, 0, 1800.0, {{0.0, 0.0}}, {4.0});
  cm::Term per = term("periodic_x", cm::Form::kSine, 5, 25.0, {{0.0, 0.0}}, {2.0, 1.0});
  cm::Term lag = term("thermal_drift", cm::Form::kLag, 5, 100.0, {{0.0, 0.0}}, {0.5});
  const cm::Model model({}, {offset, warm, per, lag});
  cm::EvalState state = model.make_state();

  const cm::Row r0 = contour_row(0.0, 1.0, 10.0);
  const cm::Row r1 = contour_row(900.0, 2.0, 10.0);
  const cm::Row r2 = contour_row(1000.0, 7.0, 10.0);  // a checkpoint never fitted
  double v0 = 0.0;
  double v1 = 0.0;
  double v2 = 0.0;
  {
    nccomp::test::AllocationScope scope;
    v0 = model.evaluate(r0, state);
    v1 = model.evaluate(r1, state);
    v2 = model.evaluate(r2, state);
    EXPECT_EQ(scope.count(), 0U);
  }
  const double s = 2.0 * std::sin(2.0 * std::numbers::pi * 10.0 / 25.0) +
                   std::cos(2.0 * std::numbers::pi * 10.0 / 25.0);
  // The lag starts in equilibrium with its input (x = 10 mm) and stays there.
  EXPECT_NEAR(v0, 3.0 + 0.0 + s + 0.5 * 10.0, 1e-12);
  EXPECT_NEAR(v1, -2.0 + 4.0 * (1.0 - std::exp(-0.5)) + s + 5.0, 1e-12);
  EXPECT_NEAR(v2, 4.0 * (1.0 - std::exp(-1000.0 / 1800.0)) + s + 5.0, 1e-12);
}

TEST(ModelEvaluate, LagFollowsAStepOfItsInputWithItsTimeConstant) {
  const cm::Term lag = term("thermal_drift", cm::Form::kLag, 11, 600.0, {{0.0, 0.0}}, {1.0});
  const cm::Model model({"spindle_rpm"}, {lag});
  cm::EvalState state = model.make_state();
  cm::Row r = contour_row(0.0, 0.0, 0.0);
  r[11] = 0.0;
  EXPECT_DOUBLE_EQ(model.evaluate(r, state), 0.0);
  r[0] = 1.0;
  r[11] = 1000.0;  // speed step; the held input before it was 0
  EXPECT_DOUBLE_EQ(model.evaluate(r, state), 0.0);
  r[0] = 601.0;
  EXPECT_NEAR(model.evaluate(r, state), 1000.0 * (1.0 - std::exp(-1.0)), 1e-9);
  r[0] = 0.0;  // time going backwards: a new file, the filter restarts at its input
  EXPECT_DOUBLE_EQ(model.evaluate(r, state), 1000.0);
}

TEST(ModelEvaluate, TermAppliesOnlyToItsKindsAndKnownValues) {
  cm::Term lin = term("tool_wear", cm::Form::kLinear, 9, 1.0, {{0.0, 0.0}}, {0.01});
  lin.spec.kind_mask = 0x1;  // tool_wear rows only
  const cm::Model model({}, {lin});
  cm::EvalState state = model.make_state();
  cm::Row r = contour_row(0.0, 0.0, 0.0);
  r[9] = 1000.0;
  EXPECT_DOUBLE_EQ(model.evaluate(r, state), 0.0);
  r[3] = 0.0;
  EXPECT_DOUBLE_EQ(model.evaluate(r, state), 10.0);
  r[9] = cm::kUnknown;
  EXPECT_DOUBLE_EQ(model.evaluate(r, state), 0.0);
}

TEST(FDistribution, MatchesTabulatedQuantiles) {
  // Tables: F(1, 10) 0.95 quantile 4.9646; F(2, 100) 0.99 quantile 4.8239. P(F(3, 30) > 3)
  // = 0.046064 by numerical integration of the density (numpy, trapezoid, 2e6 steps).
  EXPECT_NEAR(cm::f_distribution_upper_tail(4.9646, 1, 10), 0.05, 2e-4);
  EXPECT_NEAR(cm::f_distribution_upper_tail(4.8239, 2, 100), 0.01, 1e-4);
  EXPECT_NEAR(cm::f_distribution_upper_tail(3.0, 3, 30), 0.046064, 1e-5);
  EXPECT_DOUBLE_EQ(cm::f_distribution_upper_tail(0.0, 3, 30), 1.0);
}

TEST(FitTerms, RecoversCoefficientsPerGroupExactly) {
  cm::Dataset d;
  for (int i = 0; i < 200; ++i) {
    const double tool = 1.0 + (i % 2);
    const double path = 10.0 * i;
    d.columns[0].push_back(i);
    d.columns[2].push_back(tool);
    d.columns[3].push_back(0.0);
    d.columns[9].push_back(path);
    d.target_um.push_back((tool < 1.5 ? 5.0 : 9.0) + (tool < 1.5 ? 0.002 : 0.004) * path);
  }
  cm::TermSpec off;
  off.name = "offset";
  off.per = {2, -1};
  cm::TermSpec wear;
  wear.name = "wear";
  wear.form = cm::Form::kLinear;
  wear.column = 9;
  wear.per = {2, -1};
  const std::vector<std::uint8_t> use(d.rows(), 1);
  const cm::Model m = cm::fit_terms(d, {off, wear}, use);
  ASSERT_EQ(m.terms()[0].coef.size(), 2U);
  EXPECT_NEAR(m.terms()[0].coef[0], 5.0, 1e-9);
  EXPECT_NEAR(m.terms()[0].coef[1], 9.0, 1e-9);
  EXPECT_NEAR(m.terms()[1].coef[0], 0.002, 1e-12);
  EXPECT_NEAR(m.terms()[1].coef[1], 0.004, 1e-12);
  for (double r : cm::residuals(d, m)) EXPECT_NEAR(r, 0.0, 1e-9);
}
