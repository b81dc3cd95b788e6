// Issue 21, interactions: GIVEN generated logs (irregular part times, 0.3–1 µm noise) whose
// error grows with position × temperature rise (a ball screw's thermal growth) WHEN analysed
// THEN it is found as the one interaction temp_c*x_mm with the generated growth rate, not as
// two separate linear effects; it is written a*b in summary.json and model.toml, reads back, and
// evaluates the same in the daemon's model module.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

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

constexpr int kX = static_cast<int>(cm::Column::kX);
constexpr int kTemp = static_cast<int>(cm::Column::kTemp);

// Growth of the screw [µm per mm of position and K of temperature rise] (12 µm/(m·K), steel)
// and its reference temperature: at 19.5 °C the screw has its nominal length.
constexpr double kGrowthUmPerMmK = 0.012;
constexpr double kReferenceC = 19.5;

cm::Dataset screw_log(std::uint64_t seed, double noise_um) {
  synth::Options opt;
  opt.seed = seed;
  opt.parts = 60;
  opt.points_per_part = 12;
  opt.noise_um = noise_um;
  cm::Dataset d = synth::generate(opt);
  const auto& x = d.column(kX);
  const auto& temp = d.column(kTemp);
  for (std::size_t i = 0; i < d.rows(); ++i) {
    d.target_um[i] += kGrowthUmPerMmK * x[i] * (temp[i] - kReferenceC);
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

TEST(Interaction, PositionTimesTemperatureRiseIsOneInteractionNotTwoLinearEffects) {
  for (std::uint64_t seed = 11; seed <= 13; ++seed) {
    SCOPED_TRACE(seed);
    const double noise_um = seed == 12 ? 1.0 : 0.3;
    const cm::Dataset d = screw_log(seed, noise_um);
    const cm::AnalysisResult r = cm::analyze(d, synth::config());
    ASSERT_FALSE(r.effects.empty());
    EXPECT_EQ(r.effects[0].spec.name, "temp_c*x_mm");
    EXPECT_EQ(r.effects[0].spec.form, cm::Form::kInteraction);
    EXPECT_EQ(r.effects[0].spec.column, kTemp);
    EXPECT_EQ(r.effects[0].spec.column_b, kX);
    // Neither of the two linear effects is added besides it.
    for (const auto& e : r.effects) {
      EXPECT_NE(e.spec.name, "thermal_drift") << cm::form_name(e.spec.form);
      EXPECT_NE(e.spec.name, "position_x");
    }
    // With a = temp_c − ca, b = x − cb: g·x·(T − Tr) = g·ab + g·cb·a + g·(ca − Tr)·b + const.
    const cm::Term* t = find(r.fitted_model, "temp_c*x_mm");
    ASSERT_NE(t, nullptr);
    ASSERT_EQ(t->coef.size(), 3U);
    const double ca = t->spec.center;
    const double cb = t->spec.center_b;
    EXPECT_NEAR(t->coef[2], kGrowthUmPerMmK, 0.1 * kGrowthUmPerMmK);
    EXPECT_NEAR(t->coef[0], kGrowthUmPerMmK * cb, 0.1 * kGrowthUmPerMmK * cb);
    EXPECT_NEAR(t->coef[1], kGrowthUmPerMmK * (ca - kReferenceC),
                0.1 * kGrowthUmPerMmK * std::fabs(ca - kReferenceC) + 1e-3);
    const auto& ci = r.effects[0].coef_ci95;
    ASSERT_EQ(ci.size(), 3U);
    EXPECT_LT(ci[2][0], kGrowthUmPerMmK);
    EXPECT_GT(ci[2][1], kGrowthUmPerMmK);
    EXPECT_LT(r.final_stats.heldout.rms_um, 1.2 * noise_um);
  }
}

TEST(Interaction, WrittenAsAStarBInSummaryAndModelFileAndEvaluatedByTheModelModule) {
  const cm::Dataset d = screw_log(21, 0.5);
  const cm::AnalysisConfig c = synth::config();
  const cm::AnalysisResult r = cm::analyze(d, c);
  ASSERT_FALSE(r.effects.empty());
  ASSERT_EQ(r.effects[0].spec.name, "temp_c*x_mm");
  const std::string j = nccomp::tools::analyze::summary_json(d, r);
  EXPECT_NE(j.find(R"("name": "temp_c*x_mm", "label": "temp_c*x_mm", "per": [], "column": )"
                   R"("temp_c*x_mm", "form": "interaction", "params": {"center_a": )"),
            std::string::npos)
      << j;
  const std::string text = io::write_model_toml(r.final_model, c, {"t"});
  EXPECT_NE(text.find("name = \"temp_c*x_mm\"\nform = \"interaction\"\ncolumn = \"temp_c*x_mm\"\n"),
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
  // The daemon: the term on one register, evaluated each cycle at the axis position and the
  // temperature of the machine context, allocation-free.
  std::size_t index = 0;
  while (back.terms()[index].spec.name != "temp_c*x_mm") ++index;
  const cm::Term& t = back.terms()[index];
  cm::ModelApply a;
  a.term_index = index;
  a.register_index = 0;
  a.gain = -1.0;
  cm::ModelModule m(back, {a}, true);
  nccomp::core::StepOutput out;
  std::size_t allocations = 0;
  for (int k = 0; k < 40; ++k) {
    const double x_mm = 10.0 * k;
    const double temp_c = 19.0 + 0.05 * k;
    nccomp::core::AxisSample s{};
    s.time_ns = (k + 1) * 1'000'000LL;
    s.position_mm = {x_mm, 0.0, 0.0};
    const nccomp::core::Event ev[] = {s, nccomp::core::TemperatureSample{s.time_ns, 0, temp_c}};
    out.clear();
    {
      const nccomp::test::AllocationScope scope;
      m.step(s.time_ns, ev, out);
      allocations += scope.count() + scope.frees();
    }
    const double da = temp_c - t.spec.center;
    const double db = x_mm - t.spec.center_b;
    ASSERT_NEAR(m.trim_um(0), -(t.coef[0] * da + t.coef[1] * db + t.coef[2] * da * db), 1e-9) << k;
  }
  EXPECT_EQ(allocations, 0U);
}

TEST(Interaction, ModelFileRefusesAProductWithoutTheFormAndAnInteractionWithOneColumn) {
  auto error = [](const std::string& term) {
    try {
      io::read_model_text("[model]\n[[model.term]]\nname = \"g\"\n" + term, "m.toml", false);
    } catch (const nccomp::formats::DiagnosticsError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error("form = \"linear\"\ncolumn = \"temp_c*x_mm\"\n")
                .find("m.toml:5:10: model.term[0].column: 'temp_c*x_mm': a product of columns "
                      "needs form = \"interaction\""),
            std::string::npos);
  EXPECT_NE(error("form = \"interaction\"\ncolumn = \"x_mm\"\n")
                .find("m.toml:5:10: model.term[0].column: 'x_mm': an interaction's column is two "
                      "columns a*b"),
            std::string::npos);
  EXPECT_NE(error("form = \"linear\"\ncolumn = \"x_mm\"\ncenter_b = 1.0\n")
                .find("model.term[0].center_b: only for form = \"interaction\""),
            std::string::npos);
}
