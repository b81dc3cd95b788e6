// Fleet analysis (`nccomp analyze` over several machines of one type, issue 23): the effects a
// machine type shares, and each machine's deviation from the type as a random effect, shrunk
// toward the type by the best linear unbiased predictor (BLUP). Pure: data in, numbers out.
//
//   1. Each machine's log is searched on its own (analyze()) at alpha / machines, so that the
//      fleet as a whole keeps the family-wise level alpha.
//   2. Every effect found on any machine, those found by more machines first, is fitted on
//      every machine with the terms that machine has so far (declared, then the effects kept);
//      a Wald F-test of its coefficients on each machine (Bonferroni over machines × effects)
//      says where it is. Significant on one machine only, and the other machines' mean not
//      different from 0: that machine's own effect. Significant on two or more, or the type
//      mean significant: common to the type. Otherwise (or collinear with the terms kept, e.g.
//      an interaction whose main effect is kept): not supported by the fleet, dropped.
//   3. Each machine is fitted with the declared, the common and its own terms. Per coefficient
//      of a common term, the machines' estimates β_i with variances v_i give the
//      between-machine variance τ² (DerSimonian–Laird, method of moments), the type mean μ
//      (weights 1 / (v_i + τ²)) and the BLUP μ + τ² / (τ² + v_i) · (β_i − μ).
//   4. With the common effects held at its BLUP, each machine's declared terms (its set-up) and
//      its own effects are refitted, not shrunk: they co-vary with the shrunk coefficients (a
//      constant and a slope in temp_c far from 0 °C), and shrinking them one by one would spoil
//      the machine's fit. The type's prior: the common effects at μ, the declared terms at the
//      mean of the machines' values refitted with the common effects at μ.
//
// Balanced data (all v_i = v): τ² = max(0, s² − v) with s² the sample variance of the β_i, μ =
// their mean, and every estimate moves toward μ by the same factor v / (τ² + v).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "core/model/analysis.hpp"
#include "core/model/model.hpp"

namespace nccomp::core::model {

/// Random-effects estimate of one coefficient over machines.
struct RandomEffect {
  double mean{0.0};           // μ, the type's value
  double mean_variance{0.0};  // variance of μ: 1 / Σ 1 / (v_i + τ²)
  double tau2{0.0};           // τ², the between-machine variance
  /// Per machine: the BLUP, and τ² / (τ² + v_i), the weight of the machine's own estimate.
  std::vector<double> blup;
  std::vector<double> own_weight;
};

/// DerSimonian–Laird estimate from `estimate[i]` with `variance[i]` (finite, > 0) of machine
/// i. One machine: τ² = 0, μ = its estimate, its BLUP its estimate. Throws AnalysisError on an
/// empty input or a variance that is not finite and positive.
RandomEffect random_effect(const std::vector<double>& estimate,
                           const std::vector<double>& variance);

/// One machine's rows.
struct FleetMachine {
  std::string id;
  Dataset data;
};

enum class FleetRole : std::uint8_t {
  kDeclared = 0,     // declared: on every machine, refitted given the common effects
  kCommon = 1,       // found, shared by the type: fitted on every machine, shrunk
  kMachine = 2,      // found, one machine's own: only in that machine's model, not shrunk
  kUnsupported = 3,  // found by a machine's search, not confirmed by the fleet fit: dropped
};
std::string_view fleet_role_name(FleetRole role) noexcept;

/// One coefficient of a declared or common term across the machines.
struct FleetCoefficient {
  std::array<double, 2> group{0.0, 0.0};  // the group key (Term::groups)
  std::size_t basis{0};
  /// Per machine (FleetResult::machines order); NaN where the machine has no such coefficient
  /// (a group it never saw, a collinear coefficient).
  std::vector<double> estimate;
  std::vector<double> variance;
  /// Over the machines that have it; blup / own_weight per machine (NaN where absent, and for
  /// a declared term, which is not shrunk).
  RandomEffect effect;
};

struct FleetTerm {
  TermSpec spec;
  FleetRole role{FleetRole::kDeclared};
  /// kMachine: index of the machine it belongs to.
  std::size_t owner{0};
  /// Machines whose own search added it.
  std::vector<std::size_t> found_on;
  /// Found terms, per machine: the Bonferroni-adjusted p-value of the Wald test of its
  /// coefficients in the joint fit (1 where not estimable), and whether it is below alpha.
  std::vector<double> p_value;
  std::vector<std::uint8_t> significant;
  /// Found terms: adjusted p-value of the type mean (of the machines other than the one it was
  /// significant on, for a term significant on exactly one machine).
  double type_p_value{1.0};
  /// kDeclared, kCommon: every coefficient across the machines.
  std::vector<FleetCoefficient> coefficients;
};

/// Residual RMS [µm] of one machine's rows under a model.
struct FleetFit {
  ErrorStats own;    // its own model (the BLUP coefficients)
  ErrorStats type;   // the type's prior model
  ErrorStats alone;  // its own search's final model (fitted on its rows alone)
};

struct FleetResult {
  std::vector<std::string> machines;
  /// Each machine's own search (analyze() at alpha / machines).
  std::vector<AnalysisResult> searches;
  std::vector<FleetTerm> terms;
  /// Per machine: declared + common (BLUP) + its own terms. The type: declared + common at μ.
  std::vector<Model> machine_models;
  Model type_model;
  std::vector<FleetFit> fits;
  double alpha{0.01};
  std::vector<Warning> warnings;
};

/// The whole fleet analysis. At least two machines, distinct ids, the same extra columns.
/// Throws AnalysisError otherwise or when a machine's search fails (its id in the message).
FleetResult analyze_fleet(const std::vector<FleetMachine>& machines, const AnalysisConfig& config);

}  // namespace nccomp::core::model
