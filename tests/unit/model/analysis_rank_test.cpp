// Issue 21, ranking by out-of-sample error (rank_folds): GIVEN a gauge that follows a noisy
// temperature sensor, flat with small swings for 70 % of the run and rising from there on, WHEN
// analysed THEN the search takes the temperature, not a level change near the end of the fitted
// hours (which explains those hours better but predicts the later rise as flat); without the
// ranking (rank_folds = 0) the level change is taken first and the held-out error is worse.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <string>

#include "core/model/analysis.hpp"

namespace cm = nccomp::core::model;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr std::size_t kRows = 2000;
constexpr int kTempColumn = static_cast<int>(cm::kStandardColumns);  // the extra column a_c

// One gauge reading a minute; the machine's temperature T swings by ±0.5 K and rises by 12 K over
// the last 30 % of the run; the gauge reads T (1 µm/K) with 0.5 µm noise, the sensor T with
// 0.5 K noise.
cm::Dataset late_rise_log(std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> gauge(0.0, 0.5);
  std::normal_distribution<double> sensor(0.0, 0.5);
  cm::Dataset d;
  d.extra_columns = {"a_c"};
  d.columns.assign(cm::kStandardColumns + 1, {});
  for (std::size_t i = 0; i < kRows; ++i) {
    const double u = static_cast<double>(i) / static_cast<double>(kRows);
    const double t = 0.5 * std::sin(2.0 * kPi * u / 0.1) + 12.0 * std::max(0.0, u - 0.7) / 0.3;
    d.columns[static_cast<std::size_t>(cm::Column::kTime)].push_back(60.0 * static_cast<double>(i));
    d.columns[static_cast<std::size_t>(cm::Column::kKind)].push_back(2.0);  // calib
    d.columns[static_cast<std::size_t>(cm::Column::kPoint)].push_back(1.0);
    d.columns[cm::kStandardColumns].push_back(20.0 + t + sensor(rng));
    d.target_um.push_back(t + gauge(rng));
  }
  return d;
}

cm::AnalysisConfig config(std::size_t rank_folds) {
  cm::AnalysisConfig c;
  cm::TermSpec offset;
  offset.name = "offset";
  offset.form = cm::Form::kConstant;
  c.declared = {offset};
  c.max_effects = 3;
  c.search.linear_columns = {kTempColumn};
  c.rank_folds = rank_folds;
  return c;
}

}  // namespace

TEST(RankByValidation, TheTemperatureIsTakenNotALevelChangeThatFitsOnlyTheFittedHours) {
  for (const std::uint32_t seed : {3U}) {
    const cm::Dataset d = late_rise_log(seed);
    const cm::AnalysisResult ranked = cm::analyze(d, config(3));
    ASSERT_FALSE(ranked.effects.empty()) << "seed " << seed;
    EXPECT_EQ(ranked.effects[0].spec.form, cm::Form::kLinear) << "seed " << seed;
    EXPECT_EQ(ranked.effects[0].spec.column, kTempColumn) << "seed " << seed;
    for (const auto& e : ranked.effects) EXPECT_NE(e.spec.form, cm::Form::kStep) << "seed " << seed;

    // The same log ranked by the fit to the fitted hours alone: the level change comes first
    // (it is significant and lowers the held-out error, so the held-out veto keeps it).
    const cm::AnalysisResult by_fit = cm::analyze(d, config(0));
    ASSERT_FALSE(by_fit.effects.empty()) << "seed " << seed;
    EXPECT_EQ(by_fit.effects[0].spec.form, cm::Form::kStep) << "seed " << seed;
    EXPECT_LT(ranked.final_stats.heldout.rms_um, 0.8 * by_fit.final_stats.heldout.rms_um)
        << "seed " << seed;
  }
}

// A log without a time order cannot be validated in time: the candidates keep their BIC order
// and the search finds the same as without the ranking.
TEST(RankByValidation, WithoutTimeTheOrderIsTheFitsOrder) {
  cm::Dataset d = late_rise_log(4);
  d.columns[static_cast<std::size_t>(cm::Column::kTime)].clear();
  cm::AnalysisConfig with = config(3);
  cm::AnalysisConfig without = config(0);
  const cm::AnalysisResult a = cm::analyze(d, with);
  const cm::AnalysisResult b = cm::analyze(d, without);
  ASSERT_EQ(a.effects.size(), b.effects.size());
  for (std::size_t k = 0; k < a.effects.size(); ++k) {
    EXPECT_EQ(a.effects[k].spec.name, b.effects[k].spec.name);
    EXPECT_EQ(a.effects[k].spec.column, b.effects[k].spec.column);
  }
}
