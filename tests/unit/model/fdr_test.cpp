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

// The two real-data write-ups (docs/closing-the-loop.md) run with ar1_correction = false and offer
// extra columns to the search (a lag and a linear term of a speed column). The same guarantee must
// hold there: GIVEN logs with no undeclared effect, a spindle-speed column that nothing depends
// on, and the F-test taking the rows as independent (only the held-out check guards), WHEN
// analysed with 50 seeds THEN at most 5 % add an effect.
TEST(FalseDiscoveries, AtMostFivePercentWithoutTheAr1CorrectionAndWithExtraColumns) {
  const int discoveries =
      false_discoveries(5000, [](synth::Options& opt, cm::AnalysisConfig& c) {
        opt.speed_column = true;
        c = synth::config(opt);
        c.ar1_correction = false;
        c.search.linear_columns = c.search.lag_columns;
      });
  std::printf("false discoveries without the AR(1) correction, with extra columns: %d of %d\n",
              discoveries, kSeeds);
  EXPECT_LE(discoveries, kSeeds * 5 / 100);
}
