// Issue 21, item 2, prediction interval: GIVEN generated logs with Gaussian probe noise and an
// effect the search finds WHEN analysed THEN the final model's 95 % prediction interval on the
// held-out rows holds a share of them within the binomial band of 95 %, with either scale
// ([model] interval = "in_sample" or "validation"), the validation scale no wider on such
// stationary logs, and summary.json and report.md give it. GIVEN logs with a drift no term of
// the search can follow THEN the in-sample interval holds far fewer than 95 % of the held-out rows
// and the validation interval rises toward 95 %.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "core/model/analysis.hpp"
#include "tests/unit/model/synth.hpp"
#include "tools/analyze/report.hpp"

namespace cm = nccomp::core::model;
namespace synth = nccomp::test::synth;

namespace {

cm::AnalysisConfig config_with(const synth::Options& opt, cm::IntervalMethod method) {
  cm::AnalysisConfig c = synth::config(opt);
  c.interval = method;
  return c;
}

const char* name_of(cm::IntervalMethod m) {
  return m == cm::IntervalMethod::kValidation ? "validation" : "in_sample";
}

// A drift the search cannot follow: a random walk of the contour's level from part to part
// (steps of 0.25 µm, N(0, 0.25²) per part: about 2.5 µm after 100 parts) on top of noise 0.5 µm.
// The fit follows the walk on the fitted parts with what it finds (steps, warm-ups, trends), and
// the held-out parts wander off: the in-sample residual scale is too small for them.
cm::Dataset drift_log(std::uint64_t seed, synth::Options& opt) {
  opt.seed = seed;
  opt.parts = 100;
  opt.points_per_part = 20;
  opt.noise_um = 0.5;
  opt.effects = {"position_x"};
  cm::Dataset d = synth::generate(opt);
  std::mt19937_64 rng(seed * 31U + 7U);
  std::normal_distribution<double> step(0.0, 0.25);
  std::vector<double> walk(opt.parts + 2, 0.0);
  for (std::size_t p = 1; p < walk.size(); ++p) walk[p] = walk[p - 1] + step(rng);
  for (std::size_t i = 0; i < d.rows(); ++i) {
    d.target_um[i] += walk[static_cast<std::size_t>(d.row(i)[1])];
  }
  return d;
}

}  // namespace

TEST(PredictionInterval, TheDefaultScaleIsTheValidationOne) {
  EXPECT_EQ(cm::AnalysisConfig{}.interval, cm::IntervalMethod::kValidation);
}

TEST(PredictionInterval, ItsCoverageOfGaussianHeldOutRowsIsWithinTheBinomialBandOf95Percent) {
  for (const cm::IntervalMethod method :
       {cm::IntervalMethod::kInSample, cm::IntervalMethod::kValidation}) {
    SCOPED_TRACE(name_of(method));
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
      const cm::AnalysisResult r = cm::analyze(d, config_with(opt, method));
      ASSERT_FALSE(r.effects.empty());
      const cm::PredictionInterval& pi = r.prediction_interval;
      ASSERT_GE(pi.rows, 300U);
      EXPECT_DOUBLE_EQ(pi.level, 0.95);
      EXPECT_EQ(pi.method, method);
      if (method == cm::IntervalMethod::kValidation) {
        // The latest two of five blocks of the 1600 fitted rows.
        EXPECT_GE(pi.validation_rows, 600U);
      }
      // Binomial: n rows each inside with p = 0.95; 3 standard deviations.
      const double n = static_cast<double>(pi.rows);
      EXPECT_NEAR(pi.coverage, 0.95, 3.0 * std::sqrt(0.95 * 0.05 / n)) << pi.rows << " rows";
      // With 2000 rows and 22 coefficients the interval is the noise's ±1.96 σ, a little wider.
      EXPECT_GT(pi.half_width_mean_um, 1.96 * opt.noise_um * 0.9);
      EXPECT_LT(pi.half_width_mean_um, 1.96 * opt.noise_um * 1.15);
      std::printf(
          "%s, seed %llu: %zu held-out rows, half-width %.4f µm, coverage %.4f (s %.4f µm, "
          "validation %.4f µm over %zu rows)\n",
          name_of(method), static_cast<unsigned long long>(seed), pi.rows, pi.half_width_mean_um,
          pi.coverage, pi.sigma_in_sample_um, pi.validation_rms_um, pi.validation_rows);
      rows += pi.rows;
      covered += pi.coverage * n;
      const std::string j = nccomp::tools::analyze::summary_json(d, r);
      EXPECT_NE(j.find(R"("prediction_interval": {"level": 0.95, "rows": )"), std::string::npos)
          << j;
      EXPECT_NE(j.find(R"(, "coverage": )"), std::string::npos) << j;
      EXPECT_NE(j.find(std::string(R"("method": ")") + name_of(method) + "\""), std::string::npos)
          << j;
    }
    const double n = static_cast<double>(rows);
    EXPECT_NEAR(covered / n, 0.95, 3.0 * std::sqrt(0.95 * 0.05 / n)) << rows << " rows pooled";
  }
}

// Stationary logs: the validation scale is an estimate of the same noise from fewer rows and
// fits, taken only where it is larger, so it widens the interval a little at most: the RMS of
// 640 rows has a relative standard deviation of 1/sqrt(2 · 640) = 2.8 %, the maximum of the two
// adds at most about three of them, the smaller fits' coefficients 1–2 %.
TEST(PredictionInterval, TheValidationScaleDoesNotWidenItOnStationaryLogs) {
  double sum_in = 0.0;
  double sum_val = 0.0;
  for (std::uint64_t seed = 61; seed <= 65; ++seed) {
    SCOPED_TRACE(seed);
    synth::Options opt;
    opt.seed = seed;
    opt.parts = 100;
    opt.points_per_part = 20;
    opt.noise_um = seed % 2 == 0 ? 0.3 : 1.0;
    opt.effects = {"position_x"};
    const cm::Dataset d = synth::generate(opt);
    const double in = cm::analyze(d, config_with(opt, cm::IntervalMethod::kInSample))
                          .prediction_interval.half_width_mean_um;
    const double val = cm::analyze(d, config_with(opt, cm::IntervalMethod::kValidation))
                           .prediction_interval.half_width_mean_um;
    EXPECT_GE(val, in);  // max(s, validation)
    EXPECT_LT(val, 1.10 * in);
    sum_in += in;
    sum_val += val;
  }
  std::printf("mean half-width over seeds 61–65: in_sample %.4f, validation %.4f (ratio %.4f)\n",
              sum_in / 5.0, sum_val / 5.0, sum_val / sum_in);
  EXPECT_LT(sum_val, 1.05 * sum_in);
}

// The drift logs (drift_log above).
TEST(PredictionInterval, ALogWithADriftTheModelLacksRaisesTheValidationCoverageToward95Percent) {
  std::size_t rows = 0;
  double covered_in = 0.0;
  double covered_val = 0.0;
  double half_in = 0.0;
  double half_val = 0.0;
  for (std::uint64_t seed = 71; seed <= 75; ++seed) {
    SCOPED_TRACE(seed);
    synth::Options opt;
    const cm::Dataset d = drift_log(seed, opt);
    const cm::PredictionInterval in =
        cm::analyze(d, config_with(opt, cm::IntervalMethod::kInSample)).prediction_interval;
    const cm::PredictionInterval val =
        cm::analyze(d, config_with(opt, cm::IntervalMethod::kValidation)).prediction_interval;
    ASSERT_GE(in.rows, 300U);
    ASSERT_EQ(in.rows, val.rows);
    EXPECT_EQ(val.method, cm::IntervalMethod::kValidation);
    std::printf(
        "drift, seed %llu: %zu held-out rows; in_sample half-width %.4f µm, coverage %.4f; "
        "validation half-width %.4f µm (at most %.4f), coverage %.4f (s %.4f, validation %.4f "
        "µm)\n",
        static_cast<unsigned long long>(seed), in.rows, in.half_width_mean_um, in.coverage,
        val.half_width_mean_um, val.half_width_max_um, val.coverage, val.sigma_in_sample_um,
        val.validation_rms_um);
    EXPECT_GE(val.coverage, in.coverage);
    const double n = static_cast<double>(in.rows);
    rows += in.rows;
    covered_in += in.coverage * n;
    covered_val += val.coverage * n;
    half_in += in.half_width_mean_um;
    half_val += val.half_width_mean_um;
  }
  const double n = static_cast<double>(rows);
  std::printf(
      "drift, pooled over %zu rows: in_sample %.4f (half-width %.4f µm), validation %.4f "
      "(half-width %.4f µm)\n",
      rows, covered_in / n, half_in / 5.0, covered_val / n, half_val / 5.0);
  // The setting is one where the in-sample interval promises too much (below the binomial band,
  // 3 standard deviations, of 95 % over the pooled rows) ...
  EXPECT_LT(covered_in / n, 0.95 - 3.0 * std::sqrt(0.95 * 0.05 / n));
  // ... and the validation interval comes nearer to its 95 %.
  EXPECT_GT(covered_val / n, covered_in / n + 0.05);
  EXPECT_GT(covered_val / n, 0.80);
}

// The validation error comes from refits on fewer rows and so already holds their coefficients'
// error: it is compared with a row's whole in-sample prediction variance s²(1 + x'Cx), not
// widened by x'Cx once more. Where it is well above s (the drift logs of seeds 71–73: 1.3–1.9 s)
// every held-out row's half-width is t × the validation error, t of 1 600 degrees of freedom
// (1.9615); widened again it was 1.3–1.8 % more and differed from row to row.
TEST(PredictionInterval, AValidationErrorAboveThePredictionErrorIsNotWidenedAgainByTheLeverage) {
  for (std::uint64_t seed = 71; seed <= 73; ++seed) {
    SCOPED_TRACE(seed);
    synth::Options opt;
    const cm::Dataset d = drift_log(seed, opt);
    const cm::PredictionInterval val =
        cm::analyze(d, config_with(opt, cm::IntervalMethod::kValidation)).prediction_interval;
    ASSERT_EQ(val.method, cm::IntervalMethod::kValidation);
    ASSERT_GT(val.validation_rms_um, 1.3 * val.sigma_in_sample_um);
    EXPECT_NEAR(val.half_width_mean_um / val.validation_rms_um, 1.9615, 0.001);
    EXPECT_NEAR(val.half_width_max_um, val.half_width_mean_um, 1e-9);
  }
}

// A log whose last sessions the fit never saw: their offsets are learned row by row, and the
// interval widens by the learned offset's variance, so it still holds about 95 %.
TEST(PredictionInterval, NewSessionsLearnedRowByRowKeepTheCoverage) {
  for (const cm::IntervalMethod method :
       {cm::IntervalMethod::kInSample, cm::IntervalMethod::kValidation}) {
    SCOPED_TRACE(name_of(method));
    synth::Options opt;
    opt.seed = 66;
    opt.parts = 100;
    opt.points_per_part = 20;
    opt.noise_um = 0.5;
    opt.sessions = 10;
    opt.session_sigma_um = 4.0;
    const cm::AnalysisResult r = cm::analyze(synth::generate(opt), config_with(opt, method));
    ASSERT_FALSE(r.effects.empty());
    ASSERT_EQ(r.effects[0].spec.name, "session_offset");
    const cm::PredictionInterval& pi = r.prediction_interval;
    ASSERT_GE(pi.rows, 300U);
    std::printf(
        "%s, seed 66 (ten sessions, two unseen): %zu held-out rows, half-width %.4f µm (at most "
        "%.4f), coverage %.4f (s %.4f, validation %.4f µm)\n",
        name_of(method), pi.rows, pi.half_width_mean_um, pi.half_width_max_um, pi.coverage,
        pi.sigma_in_sample_um, pi.validation_rms_um);
    const double n = static_cast<double>(pi.rows);
    EXPECT_NEAR(pi.coverage, 0.95, 3.0 * std::sqrt(0.95 * 0.05 / n)) << pi.rows << " rows";
  }
}
