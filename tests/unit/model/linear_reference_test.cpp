// Issue 23, a prior's linear temperature term in the daemon: GIVEN a machine whose error is its
// checkpoints' constants plus a thermal drift from its warm-start temperature (about 22 °C, so a
// model counted from 0 °C has an intercept of some 26 µm) WHEN analysed THEN thermal_drift is
// counted from the warm-start temperature of the fitted sessions (its reference, written to and
// read from model.toml), and the daemon's trim at a new machine's first part, which applies the
// term without the model's constants, is the drift the analysis predicts since the warm start;
// a model file without a reference keeps the meaning of 0.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "core/model/analysis.hpp"
#include "core/model/model_module.hpp"
#include "formats/model/model_io.hpp"
#include "tests/unit/model/synth.hpp"
#include "tools/analyze/report.hpp"

namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;
namespace synth = nccomp::test::synth;

namespace {

constexpr double kSlopeUmPerK = -1.2;
constexpr double kRiseC = 8.0;
constexpr double kTimeConstantS = 40.0;
constexpr double kPartS = 11.0;

// The shop's temperature differs from day to day, so the drift is one of temp_c, not of time_s.
constexpr double kAmbientC[3] = {21.0, 22.0, 23.5};

double temperature_c(std::uint32_t session, double t_s) {
  return kAmbientC[session] + kRiseC * -std::expm1(-t_s / kTimeConstantS);
}

struct Log {
  cm::Dataset data;
  std::vector<double> first_temp_c;  // each session's first row
};

// Three warm starts of 12 parts, 4 checkpoints each probed after the part (1 s apart), noise
// 0.2 µm; each checkpoint has its own constant (1 … 4 µm).
Log drift_log() {
  Log log;
  cm::Dataset& d = log.data;
  std::mt19937_64 rng(23);
  std::normal_distribution<double> noise(0.0, 0.2);
  for (std::uint32_t session = 0; session < 3; ++session) {
    for (int part = 1; part <= 12; ++part) {
      for (int point = 0; point < 4; ++point) {
        const double t_s = kPartS * part + point;
        const double temp = temperature_c(session, t_s);
        if (part == 1 && point == 0) log.first_temp_c.push_back(temp);
        const double values[cm::kStandardColumns] = {t_s,
                                                     static_cast<double>(part),
                                                     1.0,
                                                     1.0,
                                                     static_cast<double>(point),
                                                     10.0,
                                                     0.0,
                                                     -5.0,
                                                     0.0,
                                                     200.0 * part,
                                                     temp};
        for (std::size_t c = 0; c < cm::kStandardColumns; ++c) d.columns[c].push_back(values[c]);
        d.target_um.push_back(1.0 + point + kSlopeUmPerK * (temp - 22.0) + noise(rng));
        d.row_session.push_back(session);
      }
    }
  }
  return log;
}

std::size_t index_of(const cm::Model& m, const std::string& name) {
  for (std::size_t i = 0; i < m.terms().size(); ++i) {
    if (m.terms()[i].spec.name == name) return i;
  }
  return m.terms().size();
}

// The model's prediction at a contour row of `point` at `temp_c` (time and path as at part 1).
double predict(const cm::Model& m, double point, double temp_c) {
  cm::Row r = cm::unknown_row();
  r[static_cast<std::size_t>(cm::Column::kTime)] = kPartS;
  r[static_cast<std::size_t>(cm::Column::kPart)] = 1.0;
  r[static_cast<std::size_t>(cm::Column::kTool)] = 1.0;
  r[static_cast<std::size_t>(cm::Column::kKind)] = 1.0;
  r[static_cast<std::size_t>(cm::Column::kPoint)] = point;
  r[static_cast<std::size_t>(cm::Column::kTemp)] = temp_c;
  r[cm::kSessionColumn] = 0.0;
  cm::EvalState s = m.make_state();
  return m.evaluate(r, s);
}

// The trim the daemon's model module publishes with `m`'s thermal_drift on one register (gain
// −1, each cycle) once the machine context reads `temp_c`.
double daemon_trim_um(const cm::Model& m, double temp_c) {
  cm::ModelApply a;
  a.term_index = index_of(m, "thermal_drift");
  a.register_index = 0;
  a.gain = -1.0;
  cm::ModelModule module(m, {a}, true);
  nccomp::core::AxisSample s{};
  s.time_ns = 1'000'000;
  s.position_mm = {10.0, 0.0, -5.0};
  const nccomp::core::Event ev[] = {s, nccomp::core::TemperatureSample{s.time_ns, 0, temp_c}};
  nccomp::core::StepOutput out;
  module.step(s.time_ns, ev, out);
  return module.trim_um(0);
}

}  // namespace

TEST(LinearReference, TheDaemonsTrimAtTheFirstPartIsTheDriftSinceTheWarmStart) {
  const Log log = drift_log();
  const cm::AnalysisResult r = cm::analyze(log.data, synth::config());
  ASSERT_FALSE(r.effects.empty());
  EXPECT_EQ(r.effects[0].spec.name, "thermal_drift");
  EXPECT_EQ(r.effects[0].spec.form, cm::Form::kLinear);
  const cm::Model& model = r.final_model;
  const std::size_t k = index_of(model, "thermal_drift");
  ASSERT_LT(k, model.terms().size());
  const cm::Term& term = model.terms()[k];
  double reference_c = 0.0;
  for (double t : log.first_temp_c) reference_c += t;
  reference_c /= static_cast<double>(log.first_temp_c.size());
  EXPECT_NEAR(term.spec.center, reference_c, 1e-9);
  EXPECT_NEAR(term.coef[0], kSlopeUmPerK, 0.05);

  // A new machine's first part, cut 1 K above its warm start: before it, the model's constants
  // (about 26 µm from 0 °C) were in the trim.
  const double first_part_c = reference_c + 1.0;
  const double trim = daemon_trim_um(model, first_part_c);
  for (double point = 0.0; point < 4.0; point += 1.0) {
    const double drift = predict(model, point, first_part_c) - predict(model, point, reference_c);
    EXPECT_NEAR(trim, -drift, 1e-9) << point;
  }
  EXPECT_NEAR(trim, -kSlopeUmPerK * 1.0, 0.1);

  // model.toml carries the reference and reads back to the same trim.
  const cm::AnalysisConfig config = synth::config();
  const std::string text = io::write_model_toml(model, config, {"t"});
  EXPECT_NE(text.find("form = \"linear\"\ncolumn = \"temp_c\"\ncenter = "), std::string::npos)
      << text;
  const io::ModelFile f = io::read_model_text(text, "model.toml", true);
  const cm::Model back(f.extra_columns, f.fitted_terms);
  EXPECT_NEAR(daemon_trim_um(back, first_part_c), trim, 1e-9);

  // summary.json gives the effect's reference beside its coefficient.
  const std::string j = nccomp::tools::analyze::summary_json(log.data, r);
  const std::string key = "\"form\": \"linear\", \"params\": {\"center_c\": ";
  const std::size_t at = j.find(key);
  ASSERT_NE(at, std::string::npos) << j;
  EXPECT_NEAR(std::stod(j.substr(at + key.size())), reference_c, 1e-6) << j;
}

// A model file of an earlier version (no reference): the term counts from 0, as it did.
TEST(LinearReference, AFileWithoutAReferenceCountsFromZero) {
  const std::string text =
      "[model]\n[[model.term]]\nname = \"thermal_drift\"\nform = \"linear\"\ncolumn = "
      "\"temp_c\"\ngroups = [[0.0, 0.0]]\ncoef_um = [-1.5]\n";
  const io::ModelFile f = io::read_model_text(text, "old.toml", true);
  const cm::Model m(f.extra_columns, f.fitted_terms);
  EXPECT_DOUBLE_EQ(m.terms()[0].spec.center, 0.0);
  EXPECT_NEAR(daemon_trim_um(m, 25.0), 1.5 * 25.0, 1e-9);
  // Written back without one.
  EXPECT_EQ(io::write_model_toml(m, cm::AnalysisConfig{}, {"t"}).find("center"), std::string::npos);
}
