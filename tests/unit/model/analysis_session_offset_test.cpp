// Issue 21, session_offset: GIVEN a machine re-homed each morning (a different offset per
// session) WHEN analysed THEN the search finds one offset per session, fitted as a random effect,
// not a level change or a time trend; the model file carries the term for the daemon, which
// learns each new session's offset from its first measurements (Model::observe()).
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/model/analysis.hpp"
#include "core/model/model.hpp"
#include "formats/model/model_io.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/model/synth.hpp"
#include "tools/analyze/report.hpp"

namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;
namespace synth = nccomp::test::synth;

namespace {

const cm::Term* session_term(const cm::Model& m) {
  for (const auto& t : m.terms()) {
    if (t.spec.form == cm::Form::kSession) return &t;
  }
  return nullptr;
}

}  // namespace

// 60 parts at irregular times, 12 checkpoints, six sessions of ten parts with offsets drawn with
// σ = 4 µm, probe noise 0.5 or 1 µm.
TEST(SessionOffset, AMachineReHomedEachMorningIsFoundAsSessionOffsetNotAsATimeEffect) {
  for (std::uint64_t seed = 41; seed <= 43; ++seed) {
    SCOPED_TRACE(seed);
    synth::Options opt;
    opt.seed = seed;
    opt.parts = 60;
    opt.points_per_part = 12;
    opt.noise_um = seed % 2 == 0 ? 0.5 : 1.0;
    opt.sessions = 6;
    opt.session_sigma_um = 4.0;
    const cm::Dataset d = synth::generate(opt);
    const cm::AnalysisResult r = cm::analyze(d, synth::config(opt));
    for (const cm::AddedEffect& e : r.effects) {
      std::printf("seed %llu: added %s (%s, %s): held-out RMS %.3f -> %.3f µm, p = %.3g\n",
                  static_cast<unsigned long long>(seed), e.spec.name.c_str(),
                  cm::term_column_name(e.spec, d.extra_columns).c_str(),
                  std::string(cm::form_name(e.spec.form)).c_str(), e.before.heldout.rms_um,
                  e.after.heldout.rms_um, e.p_value);
    }
    ASSERT_FALSE(r.effects.empty());
    EXPECT_EQ(r.effects[0].spec.name, "session_offset");
    EXPECT_EQ(r.effects[0].spec.form, cm::Form::kSession);
    for (const cm::AddedEffect& e : r.effects) {
      // Neither a level change nor a warm-up nor a time interaction took the sessions' place.
      EXPECT_NE(e.spec.column, static_cast<int>(cm::Column::kTime)) << e.spec.name;
      EXPECT_NE(e.spec.column_b, static_cast<int>(cm::Column::kTime)) << e.spec.name;
    }
    // The new sessions of the held-out rows are learned from their own rows, as the daemon
    // would: the held-out error drops too.
    EXPECT_LT(r.effects[0].after.heldout.rms_um, 0.5 * r.effects[0].before.heldout.rms_um);

    // The fitted offsets against the true ones: the declared per-checkpoint constants take
    // their (row-weighted) mean, so compare differences to session 0.
    const std::vector<double> truth = synth::session_offsets_um(opt);
    const cm::Term* t = session_term(r.fitted_model);
    ASSERT_NE(t, nullptr);
    ASSERT_GE(t->groups.size(), 4U);
    ASSERT_DOUBLE_EQ(t->groups[0][0], 0.0);
    for (std::size_t g = 1; g < t->groups.size(); ++g) {
      const auto s = static_cast<std::size_t>(t->groups[g][0]);
      EXPECT_NEAR(t->coef[g] - t->coef[0], truth[s] - truth[0], 0.5) << "session " << s;
    }
    // The method-of-moments variances against the same formula on the true offsets of the
    // fitted rows: τ² = Σ n_s (o_s − ō)² / (N − Σ n_s² / N), ō the row-weighted mean.
    std::vector<double> n_s(opt.sessions, 0.0);
    for (std::size_t i = 0; i < d.rows(); ++i) {
      if (r.heldout[i] == 0U) n_s[d.row_session[i]] += 1.0;
    }
    double n = 0.0;
    double mean = 0.0;
    double sum_n2 = 0.0;
    for (std::size_t s = 0; s < opt.sessions; ++s) {
      n += n_s[s];
      mean += n_s[s] * truth[s];
      sum_n2 += n_s[s] * n_s[s];
    }
    mean /= n;
    double between = 0.0;
    for (std::size_t s = 0; s < opt.sessions; ++s) {
      between += n_s[s] * (truth[s] - mean) * (truth[s] - mean);
    }
    const double tau = std::sqrt(between / (n - sum_n2 / n));
    EXPECT_NEAR(r.effects[0].spec.scale, tau, 0.1 * tau + 0.2);
    EXPECT_NEAR(r.effects[0].spec.center, opt.noise_um, 0.15 * opt.noise_um);
  }
}

TEST(SessionOffset, SummaryAndModelFileNameItAndTheDaemonLearnsANewSession) {
  synth::Options opt;
  opt.seed = 44;
  opt.parts = 60;
  opt.points_per_part = 12;
  opt.noise_um = 0.5;
  opt.sessions = 6;
  opt.session_sigma_um = 4.0;
  const cm::Dataset d = synth::generate(opt);
  const cm::AnalysisConfig c = synth::config(opt);
  const cm::AnalysisResult r = cm::analyze(d, c);
  ASSERT_FALSE(r.effects.empty());
  ASSERT_EQ(r.effects[0].spec.name, "session_offset");
  const std::string j = nccomp::tools::analyze::summary_json(d, r);
  EXPECT_NE(j.find(R"("name": "session_offset", "label": "session_offset")"), std::string::npos)
      << j;
  EXPECT_NE(j.find(R"("between_session_sigma_um": )"), std::string::npos) << j;
  EXPECT_NE(j.find(R"("session_offsets": [{"session": 1, "offset_um": )"), std::string::npos) << j;

  const std::string text = io::write_model_toml(r.final_model, c, {"t"});
  EXPECT_NE(text.find("form = \"session\""), std::string::npos) << text;
  const io::ModelFile f = io::read_model_text(text, "model.toml", true);
  const cm::Model back(f.extra_columns, f.fitted_terms);
  const cm::Term* t = session_term(back);
  ASSERT_NE(t, nullptr);
  EXPECT_TRUE(t->groups.empty());  // every session in the daemon is a new one
  EXPECT_NEAR(t->spec.scale, r.effects[0].spec.scale, 1e-9 * r.effects[0].spec.scale);
  EXPECT_NEAR(t->spec.center, r.effects[0].spec.center, 1e-9 * r.effects[0].spec.center);

  // A new session, re-homed 6 µm off: the loaded model learns it row by row.
  cm::EvalState state = back.make_state();
  cm::Row row = d.row(0);
  row[cm::kSessionColumn] = 100.0;
  const double others = back.evaluate(row, state);  // the session term adds 0 yet
  back.observe(row, others + 6.0, state);
  const double tau2 = t->spec.scale * t->spec.scale;
  const double sigma2 = t->spec.center * t->spec.center;
  EXPECT_NEAR(back.evaluate(row, state) - others, 6.0 * tau2 / (tau2 + sigma2), 1e-9);
}

// The closed form of the posterior mean: prior N(0, τ²), n residuals r_i with noise σ:
// E[offset | r] = τ² Σ r_i / (n τ² + σ²). τ = 4 µm, σ = 1 µm, a declared constant of 2 µm.
TEST(SessionOffset, ThePosteriorAfterOneTwoAndFiveMeasurementsIsTheClosedFormWithoutAllocating) {
  cm::Term offset;
  offset.spec.name = "offset";
  offset.spec.form = cm::Form::kConstant;
  offset.groups = {{0.0, 0.0}};
  offset.coef = {2.0};
  cm::Term session;
  session.spec.name = "session_offset";
  session.spec.form = cm::Form::kSession;
  session.spec.column = static_cast<int>(cm::kSessionColumn);
  session.spec.per = {static_cast<int>(cm::kSessionColumn), -1};
  session.spec.kind_mask = 0x2;  // contour
  session.spec.scale = 4.0;
  session.spec.center = 1.0;
  const cm::Model m({}, {offset, session});
  ASSERT_EQ(m.session_term(), 1);
  cm::EvalState state = m.make_state();
  cm::Row row = cm::unknown_row();
  row[static_cast<std::size_t>(cm::Column::kTime)] = 0.0;
  row[static_cast<std::size_t>(cm::Column::kKind)] = 1.0;
  row[cm::kSessionColumn] = 3.0;
  const std::vector<double> measured = {5.1, 4.6, 5.4, 4.9, 5.3};  // offset 3 µm + noise
  std::array<double, 6> predicted{};
  {
    nccomp::test::AllocationScope scope;
    for (std::size_t k = 0; k < measured.size(); ++k) {
      row[static_cast<std::size_t>(cm::Column::kTime)] += 10.0;
      predicted[k] = m.evaluate(row, state);
      m.observe(row, measured[k], state);
    }
    predicted[5] = m.evaluate(row, state);
    EXPECT_EQ(scope.count(), 0U);
    EXPECT_EQ(scope.frees(), 0U);
  }
  EXPECT_DOUBLE_EQ(predicted[0], 2.0);  // the prior mean: 0
  // After 1: 16 × 3.1 / 17; after 2: 16 × 5.7 / 33; after 5: 16 × 15.3 / 81.
  EXPECT_NEAR(predicted[1], 2.0 + 16.0 * 3.1 / 17.0, 1e-12);
  EXPECT_NEAR(predicted[2], 2.0 + 16.0 * 5.7 / 33.0, 1e-12);
  EXPECT_NEAR(predicted[5], 2.0 + 16.0 * 15.3 / 81.0, 1e-12);
  // A tool_wear row is not the term's kind: neither predicted nor learned from.
  cm::Row wear = row;
  wear[static_cast<std::size_t>(cm::Column::kKind)] = 0.0;
  m.observe(wear, 100.0, state);
  EXPECT_NEAR(m.evaluate(row, state), predicted[5], 1e-12);
  // A warm start is a new session: back to the prior.
  row[cm::kSessionColumn] = 4.0;
  EXPECT_DOUBLE_EQ(m.evaluate(row, state), 2.0);
  m.observe(row, 1.0, state);
  EXPECT_NEAR(m.evaluate(row, state), 2.0 + 16.0 * -1.0 / 17.0, 1e-12);
}

// A session term in model.toml: its two sigmas and nothing of the other forms' keys; one per model.
TEST(SessionOffset, ModelFileErrorsNameFileLineAndKey) {
  auto err = [](const std::string& terms) {
    try {
      io::read_model_text(terms, "m.toml", false);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string ok =
      "[[model.term]]\nname = \"session_offset\"\nform = \"session\"\n"
      "between_session_sigma_um = 3.9\nnoise_sigma_um = 0.5\n";
  EXPECT_EQ(err(ok), "");
  EXPECT_EQ(err(ok + "column = \"time_s\"\n"),
            "m.toml:6:10: model.term[0].column: not for form = \"session\" (it is per session by "
            "definition; its variances are between_session_sigma_um and noise_sigma_um)");
  EXPECT_EQ(err("[[model.term]]\nname = \"s\"\nform = \"session\"\nnoise_sigma_um = 0.5\n"),
            "m.toml:1:1: model.term[0].between_session_sigma_um: missing (form session)");
  EXPECT_EQ(err("[[model.term]]\nname = \"s\"\nform = \"session\"\n"
                "between_session_sigma_um = 1\nnoise_sigma_um = 0\n"),
            "m.toml:5:18: model.term[0].noise_sigma_um: must be > 0 [µm]");
  EXPECT_EQ(err(ok + "[[model.term]]\nname = \"t\"\nform = \"session\"\n"
                     "between_session_sigma_um = 1\nnoise_sigma_um = 1\n"),
            "m.toml:8:8: model.term[1].form: a model has at most one session term");
  EXPECT_EQ(err("[[model.term]]\nname = \"a\"\nform = \"constant\"\nnoise_sigma_um = 1\n"),
            "m.toml:4:18: model.term[0].noise_sigma_um: only for form = \"session\"");
}
