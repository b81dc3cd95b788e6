// GIVEN the shadow rule (daemon/sections/model/shadow.hpp) and measurement records scored by a
// live model and a candidate, WHEN enough parts are scored, THEN the one-sided sign test gives its
// closed-form p-values, a candidate equal to the live model is never promoted, a better one is,
// a promoted model is demoted when the one it replaced does better, and on noise with no new
// effect at most 5 % of candidates are promoted (figures in bench/results/handover.md, "Shadow").
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "core/model/model.hpp"
#include "daemon/measurement_log.hpp"
#include "daemon/sections/model/shadow.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/daemon_modules/temp_dir.hpp"

namespace nccomp::daemon::sections {
namespace {

namespace cm = core::model;

/// A model with one constant term of coef_um (every kind).
cm::Model constant_model(double coef_um) {
  cm::Term t;
  t.spec.name = "offset";
  t.spec.form = cm::Form::kConstant;
  t.groups = {{0.0, 0.0}};
  t.coef = {coef_um};
  return cm::Model({}, {t});
}

core::MeasurementRecord row(std::int32_t part, double measured_um, std::int64_t i) {
  core::MeasurementRecord r;
  r.time_ns = i * 1'000'000'000;
  r.part = part;
  r.kind = core::MeasurementKind::kContour;
  r.point = static_cast<std::int32_t>(i % 3);
  r.measured_um = measured_um;
  r.applied_um = 0.0;
  r.session = 1;
  return r;
}

TEST(ShadowRule, SignTestPValuesAreTheBinomialTails) {
  EXPECT_DOUBLE_EQ(sign_test_p(10, 10), 1.0 / 1024.0);
  EXPECT_NEAR(sign_test_p(9, 10), 11.0 / 1024.0, 1e-12);
  EXPECT_NEAR(sign_test_p(8, 10), 56.0 / 1024.0, 1e-12);
  EXPECT_NEAR(sign_test_p(3, 6), 42.0 / 64.0, 1e-12);
  EXPECT_DOUBLE_EQ(sign_test_p(0, 5), 1.0);
  EXPECT_DOUBLE_EQ(sign_test_p(0, 0), 1.0);
}

TEST(ShadowRule, NineOfTenPassesAtFivePercentAndEightOfTenDoesNot) {
  ShadowOptions o;
  o.min_parts = 10;
  o.alpha = 0.05;
  std::vector<double> live(10, 4.0);
  std::vector<double> cand(10, 1.0);
  cand[0] = 9.0;  // live better on one part
  PairedTest t = paired_test(live, cand, o);
  EXPECT_EQ(t.challenger_better, 9);
  EXPECT_EQ(t.incumbent_better, 1);
  EXPECT_NEAR(t.p_value, 11.0 / 1024.0, 1e-12);
  EXPECT_NEAR(t.incumbent_rms_um, 2.0, 1e-12);
  EXPECT_NEAR(t.challenger_rms_um, std::sqrt((9.0 + 9 * 1.0) / 10.0), 1e-12);
  EXPECT_TRUE(t.passed);
  cand[1] = 9.0;
  t = paired_test(live, cand, o);
  EXPECT_NEAR(t.p_value, 56.0 / 1024.0, 1e-12);
  EXPECT_FALSE(t.passed);
}

TEST(ShadowRule, ACandidateEqualToTheLiveModelOnlyTies) {
  ShadowOptions o;
  const std::vector<double> mse{1.0, 2.5, 0.3, 7.0, 1.0, 1.0, 4.0, 0.1, 0.2, 3.0, 5.0, 1e-3};
  const PairedTest t = paired_test(mse, mse, o);
  EXPECT_EQ(t.ties, 12);
  EXPECT_DOUBLE_EQ(t.p_value, 1.0);
  EXPECT_FALSE(t.passed);
}

TEST(ShadowRule, TheMarginIsRequiredBesideTheTest) {
  ShadowOptions o;
  o.margin_um = 0.5;
  const std::vector<double> live(10, 1.0);          // rms 1.0
  const std::vector<double> better(10, 0.64);       // rms 0.8: 0.2 µm better on every part
  const std::vector<double> much_better(10, 0.25);  // rms 0.5
  EXPECT_FALSE(paired_test(live, better, o).passed);
  EXPECT_TRUE(paired_test(live, much_better, o).passed);
}

TEST(ShadowRule, HistoryRoundTripsAndRefusesAMalformedLine) {
  ShadowDecision d;
  d.utc = "2026-11-27T19:00:00Z";
  d.action = "promoted";
  d.by = "shadow rule";
  d.live_file = "/srv/a model.toml";
  d.other_file = "/srv/b.toml";
  d.test.parts = 10;
  d.test.challenger_better = 10;
  d.test.p_value = 1.0 / 1024.0;
  d.test.incumbent_rms_um = 3.0;
  d.test.challenger_rms_um = 0.1;
  d.test.passed = true;
  const auto back = history_from_text(history_to_text({d, d}));
  ASSERT_EQ(back.size(), 2U);
  EXPECT_EQ(back[1].live_file, d.live_file);
  EXPECT_EQ(back[1].test.challenger_better, 10);
  EXPECT_DOUBLE_EQ(back[1].test.p_value, d.test.p_value);
  EXPECT_TRUE(back[1].test.passed);
  EXPECT_THROW((void)history_from_text("nccomp_model_shadow 1\na\tb\n"), std::invalid_argument);
  EXPECT_THROW((void)history_from_text("something else\n"), std::invalid_argument);
}

// A live model that predicts 0 on a process with a 3 µm offset, a candidate that predicts it:
// each part's squared errors are known in closed form, the candidate wins every part.
TEST(ShadowScoring, ABetterCandidateIsPromotedAfterMinPartsWithItsScores) {
  Shadow s;
  ShadowOptions o;
  o.min_parts = 6;
  s.configure(o, {});
  s.set_live("/live.toml", "1", constant_model(0.0));
  s.set_candidate("/cand.toml", "2", constant_model(3.0));
  std::int64_t i = 0;
  for (std::int32_t part = 1; part <= 6; ++part) {
    for (int k = 0; k < 3; ++k, ++i) s.observe(row(part, 3.0 + (k == 1 ? 0.3 : -0.3), i));
  }
  // The sixth part is scored once a row of the next one arrives.
  EXPECT_FALSE(s.take_decision().has_value());
  EXPECT_EQ(s.status().other.parts, 5U);
  s.observe(row(7, 3.0, i++));
  const auto d = s.take_decision();
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->action, "promoted");
  EXPECT_EQ(d->other_file, "/cand.toml");
  EXPECT_EQ(d->test.challenger_better, 6);
  EXPECT_NEAR(d->test.p_value, 1.0 / 64.0, 1e-12);
  const ShadowStatus st = s.status();
  EXPECT_EQ(st.live.parts, 6U);
  EXPECT_EQ(st.live.rows, 18U);
  // Rows 3 ± 0.3: live (3.3² + 2.7² + 2.7²) / 3; candidate 0.09.
  EXPECT_NEAR(st.live.mse_um2(), (3.3 * 3.3 + 2 * 2.7 * 2.7) / 3.0, 1e-9);
  EXPECT_NEAR(st.other.mse_um2(), 0.09, 1e-9);
  EXPECT_FALSE(s.take_decision().has_value());  // once
}

TEST(ShadowScoring, ACandidateEqualToTheLiveModelIsRejectedNotPromoted) {
  Shadow s;
  ShadowOptions o;
  o.min_parts = 5;
  s.configure(o, {});
  s.set_live("/live.toml", "1", constant_model(1.5));
  s.set_candidate("/same.toml", "1", constant_model(1.5));
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(2.0, 1.0);
  std::int64_t i = 0;
  for (std::int32_t part = 1; part <= 6; ++part) {
    for (int k = 0; k < 4; ++k, ++i) s.observe(row(part, noise(rng), i));
  }
  const auto d = s.take_decision();
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->action, "rejected");
  EXPECT_EQ(d->test.ties, 5);
  EXPECT_EQ(s.phase(), ShadowPhase::kNone);
}

TEST(ShadowScoring, OperatorModeAnnouncesInsteadOfPromoting) {
  Shadow s;
  ShadowOptions o;
  o.min_parts = 5;
  o.promote = ShadowPromote::kOperator;
  s.configure(o, {});
  s.set_live("/live.toml", "1", constant_model(0.0));
  s.set_candidate("/cand.toml", "2", constant_model(3.0));
  std::int64_t i = 0;
  // Rows without a part number: each is a part of its own.
  for (int k = 0; k < 5; ++k, ++i) s.observe(row(0, 3.0, i));
  const auto d = s.take_decision();
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->action, "announced");
  EXPECT_EQ(s.phase(), ShadowPhase::kAnnounced);
}

// After a promotion the model it replaced is watched: better again → demoted; not → confirmed.
TEST(ShadowScoring, APromotedModelIsDemotedWhenTheOneItReplacedDoesBetter) {
  for (const bool old_is_better : {true, false}) {
    Shadow s;
    ShadowOptions o;
    o.min_parts = 5;
    s.configure(o, {});
    s.set_live("/a.toml", "1", constant_model(0.0));
    s.set_candidate("/b.toml", "2", constant_model(3.0));
    std::int64_t i = 0;
    for (int k = 0; k < 5; ++k, ++i) s.observe(row(0, 3.0, i));
    ASSERT_EQ(s.take_decision()->action, "promoted");
    // What the daemon does: the candidate becomes live, then the old one is watched.
    s.set_live("/b.toml", "2", constant_model(3.0));
    EXPECT_EQ(s.phase(), ShadowPhase::kNone);
    s.watch_previous();
    ASSERT_EQ(s.phase(), ShadowPhase::kWatch);
    EXPECT_EQ(s.other_file(), "/a.toml");
    // The process changes back to 0 µm (the candidate's effect is gone), or stays at 3 µm.
    for (int k = 0; k < 5; ++k, ++i) s.observe(row(0, old_is_better ? 0.2 : 3.1, i));
    const auto d = s.take_decision();
    ASSERT_TRUE(d.has_value());
    EXPECT_EQ(d->action, old_is_better ? "demoted" : "confirmed");
    EXPECT_EQ(d->live_file, "/b.toml");
  }
}

// The loop's side of the shadow is the measurement log's ring: with a candidate in shadow, queuing
// a record allocates and frees nothing, and the scoring runs on the writer thread, not the loop's.
TEST(ShadowScoring, TheLoopOnlyQueuesRecordsTheWriterThreadScoresThem) {
  nccomp::testing::TempDir d;
  Shadow s;
  ShadowOptions o;
  o.min_parts = 5;
  s.configure(o, {});
  s.set_live("/live.toml", "1", constant_model(0.0));
  s.set_candidate("/cand.toml", "2", constant_model(3.0));
  MeasurementLogWriter w((d.path() / "log").string(), 1 << 20, 5);
  std::atomic<bool> on_producer{false};
  const std::thread::id producer = std::this_thread::get_id();
  w.set_observer([&](const core::MeasurementRecord& r) {
    if (std::this_thread::get_id() == producer) on_producer = true;
    s.observe(r);
  });
  w.start();
  constexpr int kRows = 12;
  std::vector<core::MeasurementRecord> rows;
  for (int i = 0; i < kRows; ++i) rows.push_back(row(0, 3.0, i));
  int pushed = 0;
  {
    nccomp::test::AllocationScope scope;
    for (const auto& r : rows) pushed += w.ring().try_push(r) ? 1 : 0;
    EXPECT_EQ(scope.count(), 0U);
    EXPECT_EQ(scope.frees(), 0U);
  }
  ASSERT_EQ(pushed, kRows);
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (s.status().rows_scored < kRows && std::chrono::steady_clock::now() < end) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  w.stop();
  EXPECT_EQ(s.status().rows_scored, static_cast<std::uint64_t>(kRows));
  EXPECT_FALSE(on_producer.load());
  const auto decision = s.take_decision();
  ASSERT_TRUE(decision.has_value());
  EXPECT_EQ(decision->action, "promoted");
}

/// Promotions among `seeds` candidates on a process with no new effect: rows = truth + noise
/// (σ 1 µm, 3 rows per part); the live model and the candidate predict truth + δ and truth − δ
/// (equally good: the null hypothesis exactly), or the candidate is the live model refitted on
/// 20 fresh rows (no better). Also the parts to a decision when the candidate knows an effect.
struct Rates {
  int promoted_equal{0};
  int promoted_refit{0};
  int promoted_effect{0};
};

Rates run_seeds(int seeds, const ShadowOptions& o, double effect_um) {
  Rates r;
  for (int seed = 1; seed <= seeds; ++seed) {
    std::mt19937 rng(static_cast<std::uint32_t>(seed));
    std::normal_distribution<double> noise(0.0, 1.0);
    std::uniform_real_distribution<double> off(0.0, 0.5);
    const double truth = 2.0;
    const double delta = off(rng);
    double refit = 0.0;
    for (int k = 0; k < 20; ++k) refit += truth + noise(rng);
    refit /= 20.0;
    for (int mode = 0; mode < 3; ++mode) {
      Shadow s;
      s.configure(o, {});
      const double process = mode == 2 ? truth + effect_um : truth;
      s.set_live("/live.toml", "1", constant_model(mode == 0 ? truth + delta : truth));
      s.set_candidate("/cand.toml", "2",
                      constant_model(mode == 0   ? truth - delta
                                     : mode == 1 ? refit
                                                 : truth + effect_um));
      std::int64_t i = 0;
      for (std::int32_t part = 1; part <= o.min_parts + 1; ++part) {
        for (int k = 0; k < 3; ++k, ++i) s.observe(row(part, process + noise(rng), i));
      }
      const auto d = s.take_decision();
      EXPECT_TRUE(d.has_value()) << "seed " << seed;
      if (d && d->action == "promoted") {
        (mode == 0 ? r.promoted_equal : mode == 1 ? r.promoted_refit : r.promoted_effect)++;
      }
    }
  }
  return r;
}

TEST(ShadowFalsePromotion, AtMostFivePercentOnNoiseWithNoNewEffect) {
  constexpr int kSeeds = 200;
  ShadowOptions o;  // the defaults: 10 parts, alpha 0.05
  const Rates r = run_seeds(kSeeds, o, 3.0);
  std::printf(
      "false promotions over %d seeds (min_parts %d, alpha %g): equally good %d (%.1f %%), "
      "refitted on noise %d (%.1f %%); a 3 um effect (noise 1 um) promoted %d (%.1f %%)\n",
      kSeeds, o.min_parts, o.alpha, r.promoted_equal, 100.0 * r.promoted_equal / kSeeds,
      r.promoted_refit, 100.0 * r.promoted_refit / kSeeds, r.promoted_effect,
      100.0 * r.promoted_effect / kSeeds);
  EXPECT_LE(r.promoted_equal, kSeeds / 20);
  EXPECT_LE(r.promoted_refit, kSeeds / 20);
  // The rule is not merely silent: a real effect is promoted.
  EXPECT_GE(r.promoted_effect, kSeeds * 9 / 10);
}

}  // namespace
}  // namespace nccomp::daemon::sections
