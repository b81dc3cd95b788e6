// Issue 21, per-group candidates: GIVEN generated logs (irregular part times, 0.3–1 µm noise)
// where each axis drifts with the temperature at its own rate, some with opposite signs, WHEN
// analysed with [model.search] group_columns THEN the per-axis thermal_drift is found with the
// generated rates, not the shared one; it is named per=point in summary.json and model.toml,
// reads back, and the daemon's model module evaluates each axis' coefficient on the register
// of that axis, allocation-free.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
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

constexpr int kPoint = static_cast<int>(cm::Column::kPoint);
constexpr int kTool = static_cast<int>(cm::Column::kTool);
constexpr int kTemp = static_cast<int>(cm::Column::kTemp);

// µm per K of the X, Y and Z axis (point 0, 1, 2): their mean is 0, so one shared coefficient
// explains nothing.
constexpr std::array<double, 3> kRateUmPerK = {1.8, -1.5, -0.3};

// Calibration rows of three axes (point = axis) at the generator's irregular times, with the
// generator's day cycle of temp_c; each axis drifts by its own rate × (temp_c − 20 °C).
cm::Dataset axes_log(std::uint64_t seed, double noise_um) {
  synth::Options opt;
  opt.seed = seed;
  opt.parts = 120;
  opt.points_per_part = 3;
  opt.noise_um = noise_um;
  cm::Dataset d = synth::generate(opt);
  auto& kind = d.columns[static_cast<std::size_t>(cm::Column::kKind)];
  const auto& point = d.column(kPoint);
  const auto& temp = d.column(kTemp);
  for (std::size_t i = 0; i < d.rows(); ++i) {
    kind[i] = 2.0;  // calib
    d.target_um[i] += kRateUmPerK[static_cast<std::size_t>(point[i])] * (temp[i] - 20.0);
  }
  return d;
}

cm::AnalysisConfig groups_config() {
  cm::AnalysisConfig c = synth::config();
  c.search.group_columns = {kPoint, kTool};
  return c;
}

bool is_temp_drift(const cm::TermSpec& s) {
  return s.name == "thermal_drift" && s.column == kTemp && s.form == cm::Form::kLinear;
}

}  // namespace

TEST(PerGroupCandidates, EachAxisOwnThermalRateIsFoundPerAxisNotShared) {
  for (std::uint64_t seed = 1; seed <= 3; ++seed) {
    SCOPED_TRACE(seed);
    const double noise_um = seed == 2 ? 1.0 : 0.3;
    const cm::Dataset d = axes_log(seed, noise_um);
    const cm::AnalysisResult r = cm::analyze(d, groups_config());
    ASSERT_FALSE(r.effects.empty());
    const cm::AddedEffect& e = r.effects[0];
    EXPECT_TRUE(is_temp_drift(e.spec)) << e.spec.name << " column " << e.spec.column;
    EXPECT_EQ(e.spec.per[0], kPoint);
    EXPECT_EQ(e.spec.per[1], -1);
    // The shared thermal_drift in temp_c is never added, and ranks below the per-axis one.
    for (const auto& a : r.effects) EXPECT_FALSE(is_temp_drift(a.spec) && a.spec.per[0] < 0);
    ASSERT_FALSE(r.steps.empty());
    int per_rank = -1;
    int shared_rank = -1;
    for (std::size_t k = 0; k < r.steps[0].size(); ++k) {
      const cm::TriedCandidate& t = r.steps[0][k];
      if (t.name != "thermal_drift" || t.column != "temp_c" || t.form != cm::Form::kLinear) {
        continue;
      }
      if (t.per[0] == kPoint) per_rank = static_cast<int>(k);
      if (t.per[0] < 0) shared_rank = static_cast<int>(k);
    }
    ASSERT_GE(per_rank, 0);
    ASSERT_GE(shared_rank, 0);
    EXPECT_LT(per_rank, shared_rank);
    for (const auto& a : r.effects) {
      std::printf("seed %d: added %s\n", static_cast<int>(seed),
                  cm::effect_label(a.spec.name, a.spec.per, d.extra_columns).c_str());
    }
    // One coefficient per axis: the generated rates. Their standard error is about
    // noise / (sd of temp_c 1.06 K × √(96 fitted rows per axis)) = 0.1 × noise.
    const cm::Term* term = nullptr;
    for (const auto& t : r.fitted_model.terms()) {
      if (is_temp_drift(t.spec)) term = &t;
    }
    ASSERT_NE(term, nullptr);
    ASSERT_EQ(term->groups.size(), 3U);
    ASSERT_EQ(e.coef_ci95.size(), 3U);
    for (std::size_t g = 0; g < 3; ++g) {
      const auto axis = static_cast<std::size_t>(term->groups[g][0]);
      EXPECT_NEAR(term->coef[g], kRateUmPerK[axis], 0.4 * noise_um) << "axis " << axis;
      EXPECT_LT(e.coef_ci95[g][0], term->coef[g]);
      EXPECT_GT(e.coef_ci95[g][1], term->coef[g]);
    }
    // Nothing but noise is left.
    EXPECT_LT(r.final_stats.heldout.rms_um, 1.2 * noise_um);
  }
}

TEST(PerGroupCandidates, WithoutGroupColumnsOnlySharedVersionsAreCandidates) {
  const cm::Dataset d = axes_log(7, 0.5);
  std::vector<std::uint8_t> use(d.rows(), 1);
  const cm::AnalysisConfig plain = synth::config();
  const std::vector<cm::Candidate> shared = cm::make_candidates(d, use, plain.search);
  const std::vector<cm::Candidate> all = cm::make_candidates(d, use, groups_config().search);
  for (const auto& c : shared) EXPECT_LT(c.spec.per[0], 0) << c.spec.name;
  // Every shared candidate again per point (3 axes) and per tool (3 tools).
  ASSERT_EQ(all.size(), 3 * shared.size());
  for (std::size_t i = 0; i < shared.size(); ++i) {
    for (std::size_t k = 1; k <= 2; ++k) {
      const cm::Candidate& c = all[k * shared.size() + i];
      EXPECT_EQ(c.spec.name, shared[i].spec.name);
      EXPECT_EQ(c.spec.form, shared[i].spec.form);
      EXPECT_EQ(c.spec.per[0], k == 1 ? kPoint : kTool);
      EXPECT_TRUE(c.grouped);
      EXPECT_DOUBLE_EQ(c.multiplicity, shared[i].multiplicity);
    }
  }
}

TEST(PerGroupCandidates, AGroupColumnWithOneValueIsReported) {
  cm::Dataset d = axes_log(8, 0.5);
  auto& tool = d.columns[static_cast<std::size_t>(kTool)];
  for (double& t : tool) t = 4.0;
  const cm::AnalysisResult r = cm::analyze(d, groups_config());
  bool warned = false;
  for (const auto& w : r.warnings) {
    warned = warned || (w.code == "group_column_unused" &&
                        w.message.find("'tool' has 1 values") != std::string::npos);
  }
  EXPECT_TRUE(warned);
  ASSERT_FALSE(r.effects.empty());
  EXPECT_EQ(r.effects[0].spec.per[0], kPoint);
}

TEST(PerGroupCandidates, NamedInSummaryAndModelFileWhichReadsBackAndEvaluatesTheSame) {
  const cm::Dataset d = axes_log(4, 0.5);
  const cm::AnalysisConfig c = groups_config();
  const cm::AnalysisResult r = cm::analyze(d, c);
  ASSERT_FALSE(r.effects.empty());
  ASSERT_TRUE(is_temp_drift(r.effects[0].spec));
  const std::string j = nccomp::tools::analyze::summary_json(d, r);
  EXPECT_NE(
      j.find(R"("name": "thermal_drift", "label": "thermal_drift per=point", "per": ["point"])"),
      std::string::npos)
      << j;
  EXPECT_NE(j.find(R"("groups": [[0, 0], [1, 0], [2, 0]])"), std::string::npos) << j;

  const std::string text = io::write_model_toml(r.final_model, c, {"t"});
  EXPECT_NE(text.find("group_columns = [\"point\", \"tool\"]"), std::string::npos) << text;
  const io::ModelFile f = io::read_model_text(text, "model.toml", true);
  EXPECT_EQ(f.config.search.group_columns, c.search.group_columns);
  const cm::Model back(f.extra_columns, f.fitted_terms);
  bool found = false;
  for (const auto& t : back.terms()) {
    if (!is_temp_drift(t.spec)) continue;
    found = true;
    EXPECT_EQ(t.spec.per[0], kPoint);
    EXPECT_EQ(t.groups.size(), 3U);
  }
  EXPECT_TRUE(found);
  cm::EvalState s1 = r.final_model.make_state();
  cm::EvalState s2 = back.make_state();
  for (std::size_t i = 0; i < d.rows(); ++i) {
    const cm::Row row = d.row(i);
    ASSERT_NEAR(r.final_model.evaluate(row, s1), back.evaluate(row, s2), 1e-9) << i;
  }
}

TEST(PerGroupCandidates, GroupColumnsAndPerAreRefusedTogether) {
  const std::string text =
      "[model]\n[[model.term]]\nname = \"offset\"\nform = \"constant\"\n"
      "[model.search]\nper = [\"tool\"]\ngroup_columns = [\"point\"]\n";
  try {
    io::read_model_text(text, "c.toml", false);
    ADD_FAILURE() << "accepted";
  } catch (const nccomp::formats::DiagnosticsError& e) {
    EXPECT_NE(std::string(e.what()).find("c.toml:7:17: model.search.group_columns: not together"),
              std::string::npos)
        << e.what();
  }
}

// The daemon side: a per-axis term on three registers, each entry fixing its axis (point). The
// trim of each register is gain × that axis' coefficient × temp_c, evaluated allocation-free.
TEST(PerGroupCandidates, TheModelModuleTakesEachRegistersAxisCoefficientAllocationFree) {
  cm::Term t;
  t.spec.name = "thermal_drift";
  t.spec.form = cm::Form::kLinear;
  t.spec.column = kTemp;
  t.spec.per = {kPoint, -1};
  t.spec.kind_mask = 0x4;  // calib
  t.groups = {{0.0, 0.0}, {1.0, 0.0}, {2.0, 0.0}};
  t.coef = {kRateUmPerK[0], kRateUmPerK[1], kRateUmPerK[2]};
  std::vector<cm::ModelApply> applies;
  for (std::uint16_t axis = 0; axis < 3; ++axis) {
    cm::ModelApply a;
    a.term_index = 0;
    a.register_index = axis;
    a.gain = -1.0;
    a.kind = 2.0;
    a.point = axis;
    applies.push_back(a);
  }
  cm::ModelModule m(cm::Model({}, {t}), applies, true);
  nccomp::core::StepOutput out;
  std::size_t allocations = 0;
  for (int k = 0; k < 50; ++k) {
    const double temp_c = 18.0 + 0.1 * k;
    const nccomp::core::Event ev[] = {
        nccomp::core::TemperatureSample{(k + 1) * 1'000'000LL, 0, temp_c}};
    out.clear();
    {
      const nccomp::test::AllocationScope scope;
      m.step((k + 1) * 1'000'000LL, ev, out);
      allocations += scope.count() + scope.frees();
    }
    for (std::size_t axis = 0; axis < 3; ++axis) {
      ASSERT_NEAR(m.trim_um(axis), -kRateUmPerK[axis] * temp_c, 1e-12) << k << " axis " << axis;
    }
  }
  EXPECT_EQ(allocations, 0U);
}

// The grid searches run on search_rows rows of a large log. GIVEN a log of 20 checkpoints per
// part, each drifting with temp_c at its own rate (mean 0), larger than search_rows WHEN
// analysed THEN the search rows hold every checkpoint: the per-checkpoint thermal_drift removes
// most of the residual there and the shared one almost nothing. (Every 20th fitted row, the
// subsample before, was checkpoint 0 only: both versions scored the same.)
TEST(PerGroupCandidates, TheSearchRowsOfALargeLogHoldEveryGroup) {
  synth::Options opt;
  opt.seed = 5;
  opt.parts = 125;
  opt.points_per_part = 20;
  opt.noise_um = 0.5;
  opt.effects = {"thermal_temp_per_point"};
  cm::AnalysisConfig c = synth::config(opt);
  c.search.group_columns = {kPoint};
  c.search_rows = 100;  // 2000 fitted rows: one in 20
  const cm::AnalysisResult r = cm::analyze(synth::generate(opt), c);
  ASSERT_FALSE(r.steps.empty());
  double shared = -1.0;
  double per_point = -1.0;
  for (const cm::TriedCandidate& t : r.steps[0]) {
    if (t.name != "thermal_drift" || t.column != "temp_c") continue;
    (t.per[0] == kPoint ? per_point : shared) = t.rss_reduction_fraction;
  }
  EXPECT_GT(per_point, 0.5);
  EXPECT_LT(shared, 0.1);
  ASSERT_FALSE(r.effects.empty());
  EXPECT_TRUE(is_temp_drift(r.effects[0].spec));
  EXPECT_EQ(r.effects[0].spec.per[0], kPoint);
}
