// Issue 21, angle profile × wear: GIVEN generated logs (irregular part times, tool changes that
// reset the cut path, 0.3–1 µm noise) whose error is edge wear concentrated at high engagement
// angles, growing with the cut path, WHEN analysed THEN it is found as contact_angle*tool_wear
// with the generated profile and the held-out error falls to the noise; logs without it do not
// find it; it is written in summary.json and model.toml, reads back, and the daemon's model
// module evaluates it as the analysis predicts, allocation-free.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>

#include "core/model/analysis.hpp"
#include "core/model/model_module.hpp"
#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/model/synth.hpp"
#include "tools/analyze/report.hpp"

namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;
namespace synth = nccomp::test::synth;

namespace {

constexpr int kAngle = static_cast<int>(cm::Column::kAngle);
constexpr int kPath = static_cast<int>(cm::Column::kPath);
constexpr const char* kName = "contact_angle*tool_wear";

// The generated effect: kRate × path × ((angle − 10°) / 50°)², 0 at 10° and kRate × path at 60°.
constexpr double kRateUmPerMm = 1.5e-3;
double profile(double angle_deg) {
  const double p = (angle_deg - 10.0) / 50.0;
  return p * p;
}

cm::Dataset log_with(std::uint64_t seed, double noise_um, bool effect) {
  synth::Options opt;
  opt.seed = seed;
  opt.parts = 60;
  opt.points_per_part = 12;
  opt.noise_um = noise_um;
  cm::Dataset d = synth::generate(opt);
  if (effect) {
    const auto& angle = d.column(kAngle);
    const auto& path = d.column(kPath);
    for (std::size_t i = 0; i < d.rows(); ++i) {
      d.target_um[i] += kRateUmPerMm * path[i] * profile(angle[i]);
    }
  }
  return d;
}

const cm::Term* find(const cm::Model& m, const std::string& name) {
  for (const auto& t : m.terms()) {
    if (t.spec.name == name) return &t;
  }
  return nullptr;
}

}  // namespace

TEST(ProfileWear, EdgeWearAtHighAnglesGrowingWithThePathIsFoundAndPredicted) {
  for (std::uint64_t seed = 31; seed <= 33; ++seed) {
    SCOPED_TRACE(seed);
    const double noise_um = seed == 32 ? 1.0 : 0.3;
    const cm::Dataset d = log_with(seed, noise_um, true);
    const cm::AnalysisResult r = cm::analyze(d, synth::config());
    ASSERT_FALSE(r.effects.empty());
    EXPECT_EQ(r.effects[0].spec.name, kName);
    EXPECT_EQ(r.effects[0].spec.form, cm::Form::kProfileWear);
    EXPECT_EQ(r.effects[0].spec.column, kAngle);
    EXPECT_EQ(r.effects[0].spec.column_b, kPath);
    // With angle = c + s·u: ((c + s·u − 10) / 50)² = ((c − 10)/50)² + 2(c − 10)s/2500 · u
    // + s²/2500 · u², each times kRate × path.
    const cm::Term* t = find(r.fitted_model, kName);
    ASSERT_NE(t, nullptr);
    ASSERT_EQ(t->coef.size(), 3U);
    const double c = t->spec.center;
    const double s = t->spec.scale;
    const double expected[] = {kRateUmPerMm * profile(c),
                               kRateUmPerMm * 2.0 * (c - 10.0) * s / 2500.0,
                               kRateUmPerMm * s * s / 2500.0};
    for (std::size_t k = 0; k < 3; ++k) {
      EXPECT_NEAR(t->coef[k], expected[k], 0.1 * kRateUmPerMm * std::max(1.0, s * s / 2500.0)) << k;
    }
    // Held out (the latest rows): from the declared model's error to the noise.
    EXPECT_LT(r.final_stats.heldout.rms_um, 0.8 * r.declared.heldout.rms_um);
    EXPECT_LT(r.final_stats.heldout.rms_um, 1.2 * noise_um);
    std::printf("seed %d noise %.1f um: held-out RMS %.3f -> %.3f um\n", static_cast<int>(seed),
                noise_um, r.declared.heldout.rms_um, r.final_stats.heldout.rms_um);
  }
}

TEST(ProfileWear, LogsWithoutItDoNotFindIt) {
  // 20 seeds of logs that carry angle and path but no undeclared effect: the candidate counts
  // in the search's multiple-test correction like the others.
  int found = 0;
  int any = 0;
  for (std::uint64_t seed = 100; seed < 120; ++seed) {
    const cm::AnalysisResult r = cm::analyze(log_with(seed, 0.5, false), synth::config());
    for (const auto& e : r.effects) found += e.spec.name == kName ? 1 : 0;
    any += r.effects.empty() ? 0 : 1;
  }
  EXPECT_LE(found, 1);  // 5 % of 20
  EXPECT_LE(any, 1);
  std::printf("20 logs without an effect: %d added contact_angle*tool_wear, %d added any\n",
              found, any);
  // A wear that does not depend on the angle is tool_wear, not the profile.
  for (std::uint64_t seed = 41; seed <= 42; ++seed) {
    synth::Options opt;
    opt.seed = seed;
    opt.parts = 60;
    opt.points_per_part = 12;
    opt.effects = {"tool_wear"};
    const cm::AnalysisResult r = cm::analyze(synth::generate(opt), synth::config());
    ASSERT_FALSE(r.effects.empty());
    EXPECT_EQ(r.effects[0].spec.name, "tool_wear") << seed;
  }
}

TEST(ProfileWear, WrittenInSummaryAndModelFileAndEvaluatedByTheModelModuleAsPredicted) {
  const cm::Dataset d = log_with(35, 0.5, true);
  const cm::AnalysisConfig c = synth::config();
  const cm::AnalysisResult r = cm::analyze(d, c);
  ASSERT_FALSE(r.effects.empty());
  ASSERT_EQ(r.effects[0].spec.name, kName);
  const std::string j = nccomp::tools::analyze::summary_json(d, r);
  EXPECT_NE(j.find(R"("name": "contact_angle*tool_wear", "label": "contact_angle*tool_wear", )"
                   R"("per": [], "column": "angle_deg*path_mm", "form": "profile_wear", )"
                   R"("params": {"center_a": )"),
            std::string::npos)
      << j;
  const std::string text = io::write_model_toml(r.final_model, c, {"t"});
  EXPECT_NE(text.find("name = \"contact_angle*tool_wear\"\nform = \"profile_wear\"\n"
                      "column = \"angle_deg*path_mm\"\n"),
            std::string::npos)
      << text;
  const io::ModelFile f = io::read_model_text(text, "model.toml", true);
  const cm::Model back(f.extra_columns, f.fitted_terms);
  cm::EvalState s1 = r.final_model.make_state();
  cm::EvalState s2 = back.make_state();
  for (std::size_t i = 0; i < d.rows(); ++i) {
    const cm::Row row = d.row(i);
    ASSERT_NEAR(r.final_model.evaluate(row, s1), back.evaluate(row, s2), 1e-9) << i;
  }
  // The daemon: the term on the register of a checkpoint at 50° of engagement, evaluated each
  // cycle at the cut path of the tool in the spindle (cutting samples 10 mm apart).
  std::size_t index = 0;
  while (back.terms()[index].spec.name != kName) ++index;
  const cm::Term& t = back.terms()[index];
  cm::ModelApply a;
  a.term_index = index;
  a.register_index = 0;
  a.gain = -1.0;
  a.kind = 1.0;  // contour
  a.angle_deg = 50.0;
  cm::ModelModule m(back, {a}, true);
  nccomp::core::StepOutput out;
  std::size_t allocations = 0;
  for (int k = 0; k < 40; ++k) {
    nccomp::core::AxisSample s{};
    s.time_ns = (k + 1) * 1'000'000LL;
    s.position_mm = {10.0 * k, 0.0, 0.0};
    s.tool = 3;
    s.cutting = true;
    const nccomp::core::Event ev[] = {s};
    out.clear();
    {
      const nccomp::test::AllocationScope scope;
      m.step(s.time_ns, ev, out);
      allocations += scope.count() + scope.frees();
    }
    const double path_mm = 10.0 * k;
    const double u = (50.0 - t.spec.center) / t.spec.scale;
    const double term_um = (t.coef[0] + t.coef[1] * u + t.coef[2] * u * u) * path_mm;
    ASSERT_NEAR(m.trim_um(0), -term_um, 1e-9) << k;
    // The analysis's prediction of the term at that row.
    cm::Row row = cm::unknown_row();
    row[static_cast<std::size_t>(cm::Column::kKind)] = 1.0;
    row[static_cast<std::size_t>(kAngle)] = 50.0;
    row[static_cast<std::size_t>(kPath)] = path_mm;
    ASSERT_NEAR(m.trim_um(0), -r.final_model.evaluate_term(index, row, s1), 1e-9) << k;
  }
  EXPECT_EQ(allocations, 0U);
}

TEST(ProfileWear, ModelFileRefusesAProfileWithOneColumnOrWithoutItsScale) {
  auto error = [](const std::string& term) {
    try {
      io::read_model_text("[model]\n[[model.term]]\nname = \"p\"\n" + term, "m.toml", false);
    } catch (const nccomp::formats::DiagnosticsError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error("form = \"profile_wear\"\ncolumn = \"angle_deg\"\nscale = 10.0\n")
                .find("m.toml:5:10: model.term[0].column: 'angle_deg': a profile_wear term's "
                      "column is two columns a*b (e.g. \"angle_deg*path_mm\")"),
            std::string::npos);
  EXPECT_NE(error("form = \"profile_wear\"\ncolumn = \"angle_deg*path_mm\"\n")
                .find("model.term[0].scale: missing (form profile_wear needs its scale"),
            std::string::npos);
  EXPECT_EQ(error("form = \"profile_wear\"\ncolumn = \"angle_deg*path_mm\"\nscale = 10.0\n"
                  "center = 30.0\n"),
            "");
}
