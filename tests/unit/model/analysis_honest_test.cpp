// Issue 21: GIVEN inputs that used to give a silent wrong number (absurd values, a saturated
// model, a linear effect misnamed or dropped by exclude) WHEN analysed THEN the analysis refuses
// or warns by name, and the effects are named by what they are.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "core/model/analysis.hpp"
#include "tests/unit/model/synth.hpp"

namespace cm = nccomp::core::model;
namespace synth = nccomp::test::synth;

namespace {

constexpr int kTime = static_cast<int>(cm::Column::kTime);
constexpr int kKind = static_cast<int>(cm::Column::kKind);
constexpr int kPoint = static_cast<int>(cm::Column::kPoint);
constexpr int kTemp = static_cast<int>(cm::Column::kTemp);

/// `n` contour rows at point 1, one per minute, target 0; extra columns as named.
cm::Dataset small_log(std::size_t n, const std::vector<std::string>& extras = {}) {
  cm::Dataset d;
  d.extra_columns = extras;
  d.columns.resize(cm::kStandardColumns + extras.size());
  for (std::size_t i = 0; i < n; ++i) {
    d.columns[kTime].push_back(60.0 * static_cast<double>(i));
    d.columns[kKind].push_back(1.0);
    d.columns[kPoint].push_back(1.0);
    d.target_um.push_back(0.0);
  }
  return d;
}

std::vector<std::string> names_of(const std::vector<cm::Candidate>& cands, cm::Form form) {
  std::vector<std::string> out;
  for (const auto& c : cands) {
    if (c.spec.form == form) out.push_back(c.spec.name);
  }
  return out;
}

}  // namespace

TEST(CandidateNames, ALinearColumnIsThermalDriftOnlyWhenItIsATemperature) {
  cm::Dataset d = small_log(40, {"depth_mm", "t1_c", "t2"});
  const int depth = static_cast<int>(cm::kStandardColumns);
  for (std::size_t i = 0; i < 40; ++i) {
    const double v = static_cast<double>(i % 7);
    d.columns[kTemp].push_back(20.0 + v);
    d.columns[static_cast<std::size_t>(depth)].push_back(0.5 + 0.1 * v);
    d.columns[static_cast<std::size_t>(depth + 1)].push_back(21.0 + v);
    d.columns[static_cast<std::size_t>(depth + 2)].push_back(22.0 - v);
  }
  const std::vector<std::uint8_t> use(40, 1);
  cm::SearchOptions o;
  o.linear_columns = {depth, depth + 1, depth + 2};
  auto linear = names_of(cm::make_candidates(d, use, o), cm::Form::kLinear);
  std::sort(linear.begin(), linear.end());
  // temp_c and t1_c by their unit, t2 is a plain column until declared.
  EXPECT_EQ(linear, (std::vector<std::string>{"linear_depth_mm", "linear_t2", "thermal_drift",
                                              "thermal_drift"}));

  o.column_is_temperature = {{depth + 2, true}};
  linear = names_of(cm::make_candidates(d, use, o), cm::Form::kLinear);
  EXPECT_EQ(std::count(linear.begin(), linear.end(), "thermal_drift"), 3);

  // Excluding thermal_drift leaves the depth of cut a candidate.
  o.exclude = {"thermal_drift"};
  linear = names_of(cm::make_candidates(d, use, o), cm::Form::kLinear);
  EXPECT_EQ(linear, (std::vector<std::string>{"linear_depth_mm"}));
  o.exclude = {"linear_depth_mm"};
  linear = names_of(cm::make_candidates(d, use, o), cm::Form::kLinear);
  EXPECT_EQ(std::count(linear.begin(), linear.end(), "linear_depth_mm"), 0);
}
