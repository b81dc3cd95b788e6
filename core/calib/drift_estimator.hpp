// The drift estimator of prediction = "estimator" (issue 22, S3): per slot a Kalman state
// x = [level, gain, slope] with drift(t) = level + gain · prior(τ) + slope · ΔT, where τ is the
// time since the nominals, prior(τ) the mean drift of earlier shifts at τ (ShiftHistory) and ΔT
// the mapped temperature minus its value at the nominals. The level is a random walk; gain and
// slope are constant within a shift. Seeded by the earlier shifts, the first hour's prediction
// exists before the first touch. Built on core/estimation/kalman.hpp; everything here is
// allocation-free and takes time as an argument.
#pragma once

#include <array>
#include <cstddef>

#include "core/calib/state.hpp"
#include "core/estimation/kalman.hpp"

namespace nccomp::core::calib {

struct EstimatorParams {
  double touch_noise_um{0.7};
  double level_noise_um_per_h{6.0};
  double prior_gain_sigma{0.5};
  double slope_sigma_um_per_c{0.0};
  double gate_sigmas{5.0};
};

/// Mean drift of the earlier shifts at since_s after the nominals [µm]: 0 at 0, linear between
/// the knots that have data, held after the last one; 0 without earlier shifts. Real-time safe.
double prior_drift_um(const ShiftHistory& h, std::size_t slot, double since_s) noexcept;
/// True when some knot has data. Real-time safe.
bool has_prior(const ShiftHistory& h) noexcept;
/// Adds an accepted touch set of the shift in progress, since_s after its nominals. Real-time
/// safe.
void add_shift_point(ShiftHistory& h, double since_s,
                     const std::array<double, kSlotCount>& drift_um) noexcept;
/// New nominals: the shift in progress (if it passed a knot) joins the earlier shifts (its mean
/// drift and its hourly increments), weights of the older ones times `forgetting`; a new shift
/// starts. Real-time safe.
void fold_shift(ShiftHistory& h, double forgetting) noexcept;

/// The level noise learned from the earlier shifts: the RMS of their hourly drift increments
/// (ShiftHistory::increment_*) clamped to [min, max] [µm/h]; `configured` while no earlier shift
/// has an hour of drift. Real-time safe.
double learned_level_noise_um_per_h(const ShiftHistory& h, std::size_t slot, double configured,
                                    double min_um_per_h, double max_um_per_h) noexcept;

/// The estimate at the nominals (time t_s): level 0 ± touch noise, gain 1 ± prior_gain_sigma
/// when earlier shifts exist (else 0 ± 0), slope slope_um_per_c (a model's, what the shift before
/// learned, or 0 for none; NaN = 0) ± slope_sigma_um_per_c. Real-time safe.
DriftEstimate start_estimate(double t_s, bool with_prior, double slope_um_per_c,
                             const EstimatorParams& p) noexcept;

struct EstimatedDrift {
  double mean_um{kNaN};
  /// Standard deviation of the estimate (not of a touch) [µm].
  double sigma_um{kNaN};
};
/// Prediction at t_s ≥ e.time_s from the regressors prior_um = prior(τ) and dtemp_c = ΔT.
/// Real-time safe.
EstimatedDrift predict_estimate(const DriftEstimate& e, double prior_um, double dtemp_c, double t_s,
                                const EstimatorParams& p) noexcept;
/// Touch set at t_s with measured drift_um: predict to t_s, then update, gated at
/// p.gate_sigmas. Gated or invalid: e is unchanged and accepted is false. Real-time safe.
estimation::UpdateResult update_estimate(DriftEstimate& e, double prior_um, double dtemp_c,
                                         double t_s, double drift_um,
                                         const EstimatorParams& p) noexcept;

}  // namespace nccomp::core::calib
