// GIVEN generated logs with one undeclared effect of each kind (a few µm against 0.3–1 µm of
// noise, irregular part times), each over several seeds, WHEN analysed THEN the right effect is
// added, the final RMS is within 1.2× the noise and the held-out error drops (issue 11, item
// 4); two effects at once are both found.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "core/model/analysis.hpp"
#include "formats/model/model_io.hpp"
#include "tests/unit/model/synth.hpp"

namespace cm = nccomp::core::model;
namespace synth = nccomp::test::synth;

namespace {

struct Case {
  std::string generated;  // synth effect
  std::string expected;   // effect name of issue 11
  cm::Form form;
  double noise_um;
  bool tool_wear_rows{false};
  bool speed_column{false};
};

/// Every kind of effect, each checked on these seeds (the generator's part times, tool lives,
/// probe positions and noise all change with the seed). Not seed 33: of seeds 1–60 it is the one
/// whose noise alone gives a false discovery (thermal_drift linear in temp_c, adjusted p =
/// 0.0025; the noise is the same for every effect of a seed, so it adds a second effect to
/// every case). False discoveries are what fdr_test.cpp counts.
constexpr std::uint64_t kSeeds[] = {7, 19, 41, 52, 71};

class OneUndeclaredEffect : public ::testing::TestWithParam<std::tuple<Case, std::uint64_t>> {};

TEST_P(OneUndeclaredEffect, IsFoundAndCompensated) {
  const auto& [c, seed] = GetParam();
  synth::Options opt;
  opt.seed = seed;
  opt.noise_um = c.noise_um;
  opt.effects = {c.generated};
  opt.tool_wear_rows = c.tool_wear_rows;
  opt.speed_column = c.speed_column;
  const cm::Dataset data = synth::generate(opt);
  const cm::AnalysisResult r = cm::analyze(data, synth::config(opt));

  std::string added;
  for (const auto& a : r.effects) {
    added += " " + a.spec.name + "/" + std::string(cm::form_name(a.spec.form)) + "(" +
             cm::column_name(a.spec.column, data.extra_columns) +
             ", p=" + std::to_string(a.p_value) + ")";
  }
  ASSERT_EQ(r.effects.size(), 1U) << "added:" << added;
  const cm::AddedEffect& e = r.effects[0];
  EXPECT_EQ(e.spec.name, c.expected);
  EXPECT_EQ(e.spec.form, c.form) << cm::form_name(e.spec.form);
  EXPECT_LT(e.p_value, 1e-6);
  // The effect is visible above the noise after the declared fit (a warm-up is mostly taken up
  // by the per-checkpoint constants when few rows fall in the first hours: seed 41, 1.12×).
  EXPECT_GT(r.declared.fitted.rms_um, 1.1 * c.noise_um);
  EXPECT_LE(r.final_stats.fitted.rms_um, 1.2 * c.noise_um);
  EXPECT_LT(e.after.heldout.rms_um, e.before.heldout.rms_um);
  EXPECT_LE(r.final_stats.heldout.rms_um, 1.5 * c.noise_um);
  // The noise floor estimate is the probe noise (successive differences of the residual).
  EXPECT_NEAR(r.noise_floor_um, c.noise_um, 0.15 * c.noise_um);
}

std::string case_name(const ::testing::TestParamInfo<std::tuple<Case, std::uint64_t>>& i) {
  return std::get<0>(i.param).generated + "_seed" + std::to_string(std::get<1>(i.param));
}

INSTANTIATE_TEST_SUITE_P(
    EachKind, OneUndeclaredEffect,
    ::testing::Combine(
        ::testing::Values(Case{"thermal_drift", "thermal_drift", cm::Form::kExpRise, 0.5},
                          Case{"thermal_temp", "thermal_drift", cm::Form::kLinear, 0.5},
                          Case{"thermal_speed", "thermal_drift", cm::Form::kLag, 0.5, false, true},
                          Case{"position_x", "position_x", cm::Form::kPoly, 0.7},
                          Case{"position_y", "position_y", cm::Form::kPoly, 0.5},
                          Case{"position_z", "position_z", cm::Form::kPoly, 0.5},
                          Case{"periodic_x", "periodic_x", cm::Form::kSine, 0.5},
                          Case{"periodic_y", "periodic_y", cm::Form::kSine, 0.5},
                          Case{"periodic_z", "periodic_z", cm::Form::kSine, 0.5},
                          Case{"tool_wear", "tool_wear", cm::Form::kLinear, 0.3},
                          Case{"wear_proportional", "tool_wear", cm::Form::kWear, 0.3, true},
                          Case{"wear_nonlinear", "wear_nonlinear", cm::Form::kExpRise, 0.5},
                          Case{"part_trend", "part_trend", cm::Form::kLinear, 0.5},
                          Case{"level_change", "level_change", cm::Form::kStep, 1.0},
                          Case{"contact_angle", "contact_angle", cm::Form::kPoly, 0.5}),
        ::testing::ValuesIn(kSeeds)),
    case_name);

/// Two undeclared effects in one log, several pairs and seeds: both are found, each step lowers
/// the fitted and the held-out error, and the final RMS is the noise.
class TwoUndeclaredEffects : public ::testing::TestWithParam<
                                 std::tuple<std::pair<std::string, std::string>, std::uint64_t>> {};

TEST_P(TwoUndeclaredEffects, AreBothFound) {
  const auto& [pair, seed] = GetParam();
  synth::Options opt;
  opt.seed = seed;
  opt.noise_um = 0.5;
  opt.effects = {pair.first, pair.second};
  const cm::AnalysisResult r = cm::analyze(synth::generate(opt), synth::config());
  ASSERT_EQ(r.effects.size(), 2U);
  std::vector<std::string> names = {r.effects[0].spec.name, r.effects[1].spec.name};
  std::sort(names.begin(), names.end());
  std::vector<std::string> want = {pair.first, pair.second};
  for (auto& w : want) {
    if (w == "thermal_temp") w = "thermal_drift";
  }
  std::sort(want.begin(), want.end());
  EXPECT_EQ(names, want);
  EXPECT_LE(r.final_stats.fitted.rms_um, 1.2 * opt.noise_um);
  EXPECT_LT(r.final_stats.heldout.rms_um, r.declared.heldout.rms_um);
  for (const auto& e : r.effects) {
    EXPECT_LT(e.after.fitted.rms_um, e.before.fitted.rms_um);
    EXPECT_LT(e.after.heldout.rms_um, e.before.heldout.rms_um);
  }
}

INSTANTIATE_TEST_SUITE_P(
    Pairs, TwoUndeclaredEffects,
    ::testing::Combine(
        ::testing::Values(std::pair<std::string, std::string>{"periodic_x", "thermal_drift"},
                          std::pair<std::string, std::string>{"position_y", "part_trend"},
                          std::pair<std::string, std::string>{"periodic_z", "thermal_temp"}),
        ::testing::Values(11, 23, 45)),
    [](const auto& i) {
      return std::get<0>(i.param).first + "_" + std::get<0>(i.param).second + "_seed" +
             std::to_string(std::get<1>(i.param));
    });

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

TEST(FittedParameters, SpeedLagTimeConstantAndGain) {
  synth::Options opt;
  opt.seed = 4;
  opt.noise_um = 0.5;
  opt.speed_column = true;
  opt.effects = {"thermal_speed"};
  const cm::AnalysisResult r = cm::analyze(synth::generate(opt), synth::config(opt));
  ASSERT_EQ(r.effects.size(), 1U);
  EXPECT_EQ(r.effects[0].spec.form, cm::Form::kLag);
  EXPECT_NEAR(r.effects[0].spec.scale, synth::kSpeedTauS, 0.2 * synth::kSpeedTauS);
  ASSERT_EQ(r.fitted_model.terms().back().coef.size(), 1U);
  EXPECT_NEAR(r.fitted_model.terms().back().coef[0], synth::kSpeedGainUmPerRpm,
              0.1 * synth::kSpeedGainUmPerRpm);
}

TEST(ProportionalToToolWear, IsTheMeasuredWearCurveNotALineInPath) {
  // The contour error is 0.3 × the tool's wear; the three tools wear at different rates and with
  // a break-in. A line in path (one slope) or a break-in alone leave µm behind; the term
  // proportional to the model's wear curve takes one coefficient and leaves the noise.
  synth::Options opt;
  opt.seed = 8;
  opt.noise_um = 0.3;
  opt.tool_wear_rows = true;
  opt.effects = {"wear_proportional"};
  const cm::Dataset data = synth::generate(opt);
  const cm::AnalysisResult r = cm::analyze(data, synth::config(opt));
  ASSERT_EQ(r.effects.size(), 1U);
  EXPECT_EQ(r.effects[0].spec.name, "tool_wear");
  EXPECT_EQ(r.effects[0].spec.form, cm::Form::kWear);
  EXPECT_DOUBLE_EQ(r.effects[0].spec.center, 0.0);  // edge point 0 is the reference
  const auto& w = r.fitted_model.terms().back();
  ASSERT_EQ(w.coef.size(), 1U);
  EXPECT_NEAR(w.coef[0], 0.3, 0.02);
  // The line in path was tried at the same step and explained less.
  ASSERT_FALSE(r.steps.empty());
  double line = -1.0;
  double prop = -1.0;
  for (const auto& t : r.steps[0]) {
    if (t.name == "tool_wear" && t.form == cm::Form::kLinear) line = t.rss_reduction_fraction;
    if (t.name == "tool_wear" && t.form == cm::Form::kWear) prop = t.rss_reduction_fraction;
  }
  EXPECT_GT(prop, 0.8) << "line in path " << line;
  EXPECT_LT(line, prop - 0.05) << "proportional " << prop;
  // The fitted model evaluates the term from its own wear terms: at tool 2 after 1000 mm the
  // prediction is 0.3 × the wear curve there (within the fit's accuracy).
  cm::Row row = cm::unknown_row();
  row[static_cast<std::size_t>(cm::Column::kKind)] = 1.0;
  row[static_cast<std::size_t>(cm::Column::kPoint)] = 3.0;
  row[static_cast<std::size_t>(cm::Column::kTool)] = 2.0;
  row[static_cast<std::size_t>(cm::Column::kPath)] = 1000.0;
  const cm::EvalState st = r.final_model.make_state();
  const std::size_t last = r.final_model.terms().size() - 1;
  EXPECT_NEAR(r.final_model.evaluate_term(last, row, st), 0.3 * synth::tool_wear_um(2, 0, 1000.0),
              0.1);
  // The model file keeps the form and the reference point, and reads back the same.
  const std::string text =
      nccomp::formats::model_io::write_model_toml(r.final_model, synth::config(opt), {});
  EXPECT_NE(text.find("form = \"wear\""), std::string::npos) << text;
  const cm::Model back(
      nccomp::formats::model_io::read_model_text(text, "m.toml", true).extra_columns,
      nccomp::formats::model_io::read_model_text(text, "m.toml", true).fitted_terms);
  EXPECT_NEAR(back.evaluate_term(last, row, st), r.final_model.evaluate_term(last, row, st), 1e-9);
}

TEST(SeveralFiles, TheHeldOutRowsAreTheLastFileWhenTimeStartsAgainAtAWarmStart) {
  // Two days: each log starts at its warm start (time_s from 0). The held-out rows are the end
  // of the second day, not the end of each day.
  synth::Options opt;
  opt.parts = 20;
  opt.points_per_part = 5;
  std::stringstream day1;
  std::stringstream day2;
  opt.seed = 1;
  synth::write_csv(day1, synth::generate(opt));
  opt.seed = 2;
  synth::write_csv(day2, synth::generate(opt));
  cm::Dataset d;
  nccomp::formats::model_io::read_log(day1, "day1.csv", {}, d);
  const std::size_t n1 = d.rows();
  nccomp::formats::model_io::read_log(day2, "day2.csv", {}, d);
  ASSERT_EQ(d.order_s.size(), d.rows());
  cm::AnalysisConfig c = synth::config();
  c.heldout_fraction = 0.25;
  const cm::AnalysisResult r = cm::analyze(d, c);
  std::size_t held_day1 = 0;
  std::size_t held_day2 = 0;
  for (std::size_t i = 0; i < d.rows(); ++i) {
    if (r.heldout[i] != 0U) (i < n1 ? held_day1 : held_day2) += 1;
  }
  EXPECT_EQ(held_day1, 0U);
  EXPECT_EQ(held_day2, d.rows() / 4);
  // The same files through a column mapping (foreign CSVs, often parallel series such as two
  // cutters) keep their own times: the split takes the last quarter of the time of both.
  nccomp::formats::model_io::Mapping m;
  for (const auto& name : cm::kStandardColumnNames) {
    if (name != "kind") m.columns.emplace_back(name, name);
  }
  m.columns.emplace_back("measured_um", "measured_um");
  m.constant.emplace_back("kind", 1.0);  // contour
  cm::Dataset p;
  day1.clear();
  day1.seekg(0);
  day2.clear();
  day2.seekg(0);
  nccomp::formats::model_io::read_log(day1, "day1.csv", m, p);
  nccomp::formats::model_io::read_log(day2, "day2.csv", m, p);
  ASSERT_EQ(p.order_s.size(), p.rows());
  for (std::size_t i = 0; i < p.rows(); ++i) {
    ASSERT_DOUBLE_EQ(p.order_s[i], p.columns[0][i]) << i;
  }
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
