// GIVEN logs with no undeclared effect (only the declared per-checkpoint constants, the declared
// tool wear where the log has tool measurements, and noise) WHEN analysed with 50 seeds THEN at
// most 5 % of the runs add an effect (issue 11, item 3).
#include <gtest/gtest.h>

#include <cstdio>

#include "core/model/analysis.hpp"
#include "tests/unit/model/synth.hpp"

namespace cm = nccomp::core::model;
namespace synth = nccomp::test::synth;

namespace {

constexpr int kSeeds = 50;

// Analyses kSeeds logs without an undeclared effect (30 parts × 12 points, noise 0.3 or 1 µm in
// turn; every fourth log also has laser measurements of the tool and a declared wear curve, so
// the term proportional to the tool wear is among the candidates too) and returns how many add
// an effect. `adjust` sets up the variant: the log's options and the analysis config.
template <class Adjust>
int false_discoveries(std::uint64_t seed_base, const Adjust& adjust) {
  int discoveries = 0;
  for (int seed = 1; seed <= kSeeds; ++seed) {
    synth::Options opt;
    opt.seed = seed_base + static_cast<std::uint64_t>(seed);
    opt.parts = 30;
    opt.points_per_part = 12;
    opt.noise_um = seed % 2 == 0 ? 0.3 : 1.0;
    opt.tool_wear_rows = seed % 4 == 0;
    cm::AnalysisConfig c;
    adjust(opt, c);
    const cm::AnalysisResult r = cm::analyze(synth::generate(opt), c);
    if (!r.effects.empty()) {
      ++discoveries;
      std::printf("seed %d: false discovery %s (column %d) p=%g\n", seed,
                  r.effects[0].spec.name.c_str(), r.effects[0].spec.column, r.effects[0].p_value);
    }
    // Without an effect the residual is the noise: the fit neither gains nor loses much.
    EXPECT_LE(r.final_stats.fitted.rms_um, 1.2 * opt.noise_um) << "seed " << seed;
  }
  return discoveries;
}

}  // namespace

TEST(FalseDiscoveries, AtMostFivePercentOverFiftySeeds) {
  const int discoveries = false_discoveries(
      1000, [](const synth::Options& opt, cm::AnalysisConfig& c) { c = synth::config(opt); });
  std::printf("false discoveries: %d of %d\n", discoveries, kSeeds);
  EXPECT_LE(discoveries, kSeeds * 5 / 100);
}

// The two real-data write-ups (bench/results/model.md) run with ar1_correction = false and offer
// extra columns to the search (a lag and a linear term of a speed column). The same guarantee must
// hold there: GIVEN logs with no undeclared effect, a spindle-speed column that nothing depends
// on, and the F-test taking the rows as independent (only the held-out check guards), WHEN
// analysed with 50 seeds THEN at most 5 % add an effect.
TEST(FalseDiscoveries, AtMostFivePercentWithoutTheAr1CorrectionAndWithExtraColumns) {
  const int discoveries = false_discoveries(5000, [](synth::Options& opt, cm::AnalysisConfig& c) {
    opt.speed_column = true;
    c = synth::config(opt);
    c.ar1_correction = false;
    c.search.linear_columns = c.search.lag_columns;
  });
  std::printf("false discoveries without the AR(1) correction, with extra columns: %d of %d\n",
              discoveries, kSeeds);
  EXPECT_LE(discoveries, kSeeds * 5 / 100);
}

// Pins the AR(1) correction of the F-test (ar1_correction, on by default). GIVEN logs with no
// undeclared effect whose probe noise is serially correlated from part to part (each
// checkpoint's noise an AR(1) series, ρ = 0.9: a slow wander that looks like a drift over a few
// parts) WHEN analysed with 50 seeds THEN at most 5 % add an effect. With the rows taken as
// independent, 9 of these 50 seeds add one (part_trend, level_change, thermal_drift) that the
// held-out check lets through; at ρ = 0.7 or 0.8 only 3.
TEST(FalseDiscoveries, AtMostFivePercentWithSeriallyCorrelatedNoise) {
  const int discoveries = false_discoveries(9000, [](synth::Options& opt, cm::AnalysisConfig& c) {
    opt.noise_ar1_rho = 0.9;
    c = synth::config(opt);
  });
  std::printf("false discoveries with AR(1) noise (rho 0.9): %d of %d\n", discoveries, kSeeds);
  EXPECT_LE(discoveries, kSeeds * 5 / 100);
}

// Pins the multiplicity of the per-group candidates (group_columns): every candidate is also
// tried per checkpoint and per tool, so the best of three times as many candidates, each per-group
// one with up to 12 times the coefficients, must not pass for an effect. GIVEN logs with no
// undeclared effect WHEN analysed with group_columns = [point, tool] over 50 seeds THEN at most
// 5 % add an effect.
TEST(FalseDiscoveries, AtMostFivePercentWithPerGroupCandidates) {
  const int discoveries = false_discoveries(17000, [](synth::Options& opt, cm::AnalysisConfig& c) {
    c = synth::config(opt);
    c.search.group_columns = {static_cast<int>(cm::Column::kPoint),
                              static_cast<int>(cm::Column::kTool)};
  });
  std::printf("false discoveries with per-group candidates: %d of %d\n", discoveries, kSeeds);
  EXPECT_LE(discoveries, kSeeds * 5 / 100);
}

// Pins the held-out check (rule 3 of analysis.hpp). GIVEN logs whose contour rows drift by up
// to 3 µm over parts 1–24 and not at all in parts 25–30, the held-out rows (a drift that was gone
// by then: the machine re-referenced, say) WHEN analysed THEN the trend candidates are highly
// significant on the fitted rows but raise the held-out error, and none of them is added: every
// added effect lowers the held-out error, the final held-out error is not above the declared
// model's.
TEST(FalseDiscoveries, AStructureOnlyInTheFittedRowsFailsTheHeldOutCheck) {
  for (std::uint64_t seed = 301; seed <= 303; ++seed) {
    SCOPED_TRACE(seed);
    synth::Options opt;
    opt.seed = seed;
    opt.parts = 30;
    opt.points_per_part = 12;
    opt.noise_um = 0.5;
    cm::Dataset d = synth::generate(opt);
    const auto& part = d.column(static_cast<int>(cm::Column::kPart));
    for (std::size_t i = 0; i < d.rows(); ++i) {
      if (part[i] <= 24.0) d.target_um[i] += 3.0 * part[i] / 24.0;
    }
    const cm::AnalysisConfig c = synth::config(opt);
    const cm::AnalysisResult r = cm::analyze(d, c);
    // The held-out fifth of the rows is parts 25–30: the drift is absent from all of them.
    for (std::size_t i = 0; i < d.rows(); ++i) {
      ASSERT_EQ(r.heldout[i] != 0U, part[i] > 24.0) << "row " << i;
    }
    // The best-ranked candidate passes the F-test by far and fails on the held-out rows.
    ASSERT_FALSE(r.steps.empty());
    ASSERT_FALSE(r.steps[0].empty());
    const cm::TriedCandidate& best = r.steps[0][0];
    EXPECT_TRUE(best.refitted);
    EXPECT_LT(best.p_value, 1e-20) << best.name;
    EXPECT_FALSE(best.heldout_improved) << best.name;
    for (const cm::AddedEffect& e : r.effects) {
      EXPECT_LT(e.after.heldout.rms_um, e.before.heldout.rms_um) << e.spec.name;
    }
    EXPECT_LE(r.final_stats.heldout.rms_um, r.declared.heldout.rms_um);
  }
}

// Pins the multiple-testing correction. GIVEN logs with no undeclared effect and no held-out rows
// (heldout_fraction 0: nothing but the F-test decides) WHEN analysed with 50 seeds THEN at most 5 %
// add an effect: the best of the candidates is tested against alpha times their number
// (Bonferroni), not as if it were the only one tried.
TEST(FalseDiscoveries, AtMostFivePercentWithoutHeldOutRows) {
  const int discoveries = false_discoveries(13000, [](synth::Options& opt, cm::AnalysisConfig& c) {
    c = synth::config(opt);
    c.heldout_fraction = 0.0;
  });
  std::printf("false discoveries without held-out rows: %d of %d\n", discoveries, kSeeds);
  EXPECT_LE(discoveries, kSeeds * 5 / 100);
}

// Pins the look-ahead's rule (analysis.hpp: both terms must be significant). GIVEN logs (noise 2
// µm) whose contour rows drift by up to 3 µm over parts 1–23 and not from part 24 on WHEN analysed
// THEN the best candidate is significant on the fitted rows but raises the held-out error, so the
// look-ahead tries it with a second term; a pair is added only if the second term is significant
// too: every added effect has p below alpha. (A level change at the drift's end rescues the trend
// on the held-out rows of seeds 401 and 402 with p = 0.13 and 0.31; seed 403's pair is
// significant.)
TEST(FalseDiscoveries, TheLookAheadAddsAPairOnlyIfItsSecondTermIsSignificant) {
  for (std::uint64_t seed = 401; seed <= 403; ++seed) {
    SCOPED_TRACE(seed);
    synth::Options opt;
    opt.seed = seed;
    opt.parts = 30;
    opt.points_per_part = 12;
    opt.noise_um = 2.0;
    cm::Dataset d = synth::generate(opt);
    const auto& part = d.column(static_cast<int>(cm::Column::kPart));
    for (std::size_t i = 0; i < d.rows(); ++i) {
      if (part[i] <= 23.0) d.target_um[i] += 3.0 * part[i] / 24.0;
    }
    const cm::AnalysisConfig c = synth::config(opt);
    const cm::AnalysisResult r = cm::analyze(d, c);
    ASSERT_FALSE(r.steps.empty());
    ASSERT_FALSE(r.steps[0].empty());
    const cm::TriedCandidate& best = r.steps[0][0];
    EXPECT_LT(best.p_value, c.alpha) << best.name;
    EXPECT_FALSE(best.heldout_improved) << best.name;
    for (const cm::AddedEffect& e : r.effects) {
      EXPECT_LT(e.p_value, c.alpha) << e.spec.name;
    }
    EXPECT_LE(r.final_stats.heldout.rms_um, r.declared.heldout.rms_um);
  }
}

// Pins the significance of session_offset (a random effect counted by its effective degrees of
// freedom). GIVEN logs in six sessions with no offset between them (the session structure
// absent) and no other undeclared effect WHEN analysed with 50 seeds THEN session_offset is
// tried in every run (it competes in the search) and at most 5 % of the runs add any effect.
TEST(FalseDiscoveries, AtMostFivePercentWithSessionsButNoSessionOffset) {
  int discoveries = 0;
  for (int seed = 1; seed <= kSeeds; ++seed) {
    synth::Options opt;
    opt.seed = 23000 + static_cast<std::uint64_t>(seed);
    opt.parts = 30;
    opt.points_per_part = 12;
    opt.noise_um = seed % 2 == 0 ? 0.3 : 1.0;
    opt.tool_wear_rows = seed % 4 == 0;
    opt.sessions = 6;
    const cm::AnalysisResult r = cm::analyze(synth::generate(opt), synth::config(opt));
    ASSERT_FALSE(r.steps.empty());
    bool tried = false;
    for (const cm::TriedCandidate& t : r.steps[0]) tried = tried || t.name == "session_offset";
    EXPECT_TRUE(tried) << "seed " << seed;
    if (!r.effects.empty()) {
      ++discoveries;
      std::printf("seed %d: false discovery %s p=%g\n", seed, r.effects[0].spec.name.c_str(),
                  r.effects[0].p_value);
    }
  }
  std::printf("false discoveries with sessions but no session offset: %d of %d\n", discoveries,
              kSeeds);
  EXPECT_LE(discoveries, kSeeds * 5 / 100);
}
