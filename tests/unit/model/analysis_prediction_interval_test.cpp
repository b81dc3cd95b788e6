// Issue 21, item 2, prediction interval: GIVEN generated logs with Gaussian probe noise and an
// effect the search finds WHEN analysed THEN the final model's 95 % prediction interval on the
// held-out rows holds a share of them within the binomial band of 95 %, and summary.json and
// report.md give it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>

#include "core/model/analysis.hpp"
#include "tests/unit/model/synth.hpp"
#include "tools/analyze/report.hpp"

namespace cm = nccomp::core::model;
namespace synth = nccomp::test::synth;

TEST(PredictionInterval, ItsCoverageOfGaussianHeldOutRowsIsWithinTheBinomialBandOf95Percent) {
  std::size_t rows = 0;
  double covered = 0.0;
  for (std::uint64_t seed = 61; seed <= 65; ++seed) {
    SCOPED_TRACE(seed);
    synth::Options opt;
    opt.seed = seed;
    opt.parts = 100;
    opt.points_per_part = 20;
    opt.noise_um = seed % 2 == 0 ? 0.3 : 1.0;
    opt.effects = {"position_x"};
    const cm::Dataset d = synth::generate(opt);
    const cm::AnalysisResult r = cm::analyze(d, synth::config(opt));
    ASSERT_FALSE(r.effects.empty());
    const cm::PredictionInterval& pi = r.prediction_interval;
    ASSERT_GE(pi.rows, 300U);
    EXPECT_DOUBLE_EQ(pi.level, 0.95);
    // Binomial: n rows each inside with p = 0.95; 3 standard deviations.
    const double n = static_cast<double>(pi.rows);
    EXPECT_NEAR(pi.coverage, 0.95, 3.0 * std::sqrt(0.95 * 0.05 / n)) << pi.rows << " rows";
    // With 2000 rows and 22 coefficients the interval is the noise's ±1.96 σ, a little wider.
    EXPECT_GT(pi.half_width_mean_um, 1.96 * opt.noise_um * 0.9);
    EXPECT_LT(pi.half_width_mean_um, 1.96 * opt.noise_um * 1.15);
    std::printf("seed %llu: %zu held-out rows, half-width %.4f µm, coverage %.4f\n",
                static_cast<unsigned long long>(seed), pi.rows, pi.half_width_mean_um, pi.coverage);
    rows += pi.rows;
    covered += pi.coverage * n;
    const std::string j = nccomp::tools::analyze::summary_json(d, r);
    EXPECT_NE(j.find(R"("prediction_interval": {"level": 0.95, "rows": )"), std::string::npos) << j;
    EXPECT_NE(j.find(R"(, "coverage": )"), std::string::npos) << j;
  }
  const double n = static_cast<double>(rows);
  EXPECT_NEAR(covered / n, 0.95, 3.0 * std::sqrt(0.95 * 0.05 / n)) << rows << " rows pooled";
}

// A log whose last sessions the fit never saw: their offsets are learned row by row, and the
// interval widens by the learned offset's variance, so it still holds about 95 %.
TEST(PredictionInterval, NewSessionsLearnedRowByRowKeepTheCoverage) {
  synth::Options opt;
  opt.seed = 66;
  opt.parts = 100;
  opt.points_per_part = 20;
  opt.noise_um = 0.5;
  opt.sessions = 10;
  opt.session_sigma_um = 4.0;
  const cm::AnalysisResult r = cm::analyze(synth::generate(opt), synth::config(opt));
  ASSERT_FALSE(r.effects.empty());
  ASSERT_EQ(r.effects[0].spec.name, "session_offset");
  const cm::PredictionInterval& pi = r.prediction_interval;
  ASSERT_GE(pi.rows, 300U);
  std::printf(
      "seed 66 (ten sessions, two unseen): %zu held-out rows, half-width %.4f µm (at most "
      "%.4f), coverage %.4f\n",
      pi.rows, pi.half_width_mean_um, pi.half_width_max_um, pi.coverage);
  const double n = static_cast<double>(pi.rows);
  EXPECT_NEAR(pi.coverage, 0.95, 3.0 * std::sqrt(0.95 * 0.05 / n)) << pi.rows << " rows";
}
