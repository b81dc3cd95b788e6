#include "core/calib/drift_estimator.hpp"

#include <algorithm>
#include <cmath>

namespace nccomp::core::calib {

namespace {

using Filter = estimation::KalmanFilter<kEstimatorStates>;

Filter to_filter(const DriftEstimate& e) noexcept {
  Filter f;
  f.reset(
      Eigen::Map<const Filter::Vector>(e.x.data()),
      Eigen::Map<const Eigen::Matrix<double, kEstimatorStates, kEstimatorStates, Eigen::RowMajor>>(
          e.p.data()));
  return f;
}

Filter::Matrix process_noise(double dt_s, const EstimatorParams& p) noexcept {
  Filter::Matrix q = Filter::Matrix::Zero();
  const double walk = p.level_noise_um_per_h;
  q(0, 0) = walk * walk * std::max(0.0, dt_s) / 3600.0;
  return q;
}

}  // namespace

double prior_drift_um(const ShiftHistory& h, std::size_t slot, double since_s) noexcept {
  if (!(since_s > 0.0)) {
    return 0.0;
  }
  double t0 = 0.0;
  double v0 = 0.0;
  for (std::size_t j = 0; j < kPriorKnots; ++j) {
    if (!(h.weight[j] > 0.0)) {
      continue;
    }
    const double t1 = static_cast<double>(j + 1) * kPriorStepS;
    const double v1 = h.sum_um[slot][j] / h.weight[j];
    if (since_s <= t1) {
      return v0 + (v1 - v0) * (since_s - t0) / (t1 - t0);
    }
    t0 = t1;
    v0 = v1;
  }
  return v0;
}

bool has_prior(const ShiftHistory& h) noexcept {
  return std::any_of(h.weight.begin(), h.weight.end(), [](double w) { return w > 0.0; });
}

void add_shift_point(ShiftHistory& h, double since_s,
                     const std::array<double, kSlotCount>& drift_um) noexcept {
  if (!(since_s > h.last_since_s)) {
    return;  // not later than the last set: the curve stays a function of time
  }
  while (h.current_knots < static_cast<std::int32_t>(kPriorKnots)) {
    const auto j = static_cast<std::size_t>(h.current_knots);
    const double tj = static_cast<double>(j + 1) * kPriorStepS;
    if (tj > since_s) {
      break;
    }
    const double f = (tj - h.last_since_s) / (since_s - h.last_since_s);
    for (std::size_t s = 0; s < kSlotCount; ++s) {
      h.current_um[s][j] = h.last_drift_um[s] + f * (drift_um[s] - h.last_drift_um[s]);
    }
    ++h.current_knots;
  }
  h.last_since_s = since_s;
  h.last_drift_um = drift_um;
}

void fold_shift(ShiftHistory& h, double forgetting) noexcept {
  if (h.current_knots > 0) {
    // Increments over each whole hour (knots two apart, from the shift start at 0: the knots on
    // the hour are the hourly touch sets themselves), weighted like the mean.
    h.increment_weight *= forgetting;
    for (std::size_t s = 0; s < kSlotCount; ++s) {
      h.increment_sq_sum_um2[s] *= forgetting;
    }
    for (std::size_t m = 0; m + 2 <= static_cast<std::size_t>(h.current_knots); m += 2) {
      for (std::size_t s = 0; s < kSlotCount; ++s) {
        const double from = m == 0 ? 0.0 : h.current_um[s][m - 1];
        const double d = h.current_um[s][m + 1] - from;
        h.increment_sq_sum_um2[s] += d * d;
      }
      h.increment_weight += 1.0;
    }
    for (std::size_t j = 0; j < kPriorKnots; ++j) {
      h.weight[j] *= forgetting;
      for (std::size_t s = 0; s < kSlotCount; ++s) {
        h.sum_um[s][j] *= forgetting;
      }
      if (j < static_cast<std::size_t>(h.current_knots)) {
        h.weight[j] += 1.0;
        for (std::size_t s = 0; s < kSlotCount; ++s) {
          h.sum_um[s][j] += h.current_um[s][j];
        }
      }
    }
    ++h.shifts;
  }
  h.current_knots = 0;
  h.current_um = {};
  h.last_since_s = 0.0;
  h.last_drift_um = {};
}

double learned_level_noise_um_per_h(const ShiftHistory& h, std::size_t slot, double configured,
                                    double min_um_per_h, double max_um_per_h) noexcept {
  if (!(h.increment_weight > 0.0) || slot >= kSlotCount) {
    return configured;
  }
  const double rms = std::sqrt(std::max(0.0, h.increment_sq_sum_um2[slot] / h.increment_weight));
  return std::clamp(rms, min_um_per_h, max_um_per_h);
}

DriftEstimate start_estimate(double t_s, bool with_prior, double slope_um_per_c,
                             const EstimatorParams& p) noexcept {
  DriftEstimate e;
  e.valid = 1;
  e.time_s = t_s;
  e.x = {0.0, with_prior ? 1.0 : 0.0, std::isfinite(slope_um_per_c) ? slope_um_per_c : 0.0};
  e.p = {};
  const double g = with_prior ? p.prior_gain_sigma : 0.0;
  constexpr std::size_t kDiag = kEstimatorStates + 1;  // row-major stride of the diagonal
  e.p[0] = p.touch_noise_um * p.touch_noise_um;
  e.p[kDiag] = g * g;
  e.p[2 * kDiag] = p.slope_sigma_um_per_c * p.slope_sigma_um_per_c;
  return e;
}

EstimatedDrift predict_estimate(const DriftEstimate& e, double prior_um, double dtemp_c, double t_s,
                                const EstimatorParams& p) noexcept {
  if (e.valid != 1) {
    return {};
  }
  Filter f = to_filter(e);
  f.predict(Filter::Matrix::Identity(), process_noise(t_s - e.time_s, p));
  const Filter::Row h(1.0, prior_um, dtemp_c);
  EstimatedDrift d;
  d.mean_um = f.predicted_measurement(h);
  d.sigma_um = std::sqrt(std::max(0.0, f.innovation_variance(h, 0.0)));
  return d;
}

estimation::UpdateResult update_estimate(DriftEstimate& e, double prior_um, double dtemp_c,
                                         double t_s, double drift_um,
                                         const EstimatorParams& p) noexcept {
  if (e.valid != 1 || !(t_s >= e.time_s)) {
    return {};
  }
  Filter f = to_filter(e);
  f.predict(Filter::Matrix::Identity(), process_noise(t_s - e.time_s, p));
  const Filter::Row h(1.0, prior_um, dtemp_c);
  const auto res = f.update(h, drift_um, p.touch_noise_um * p.touch_noise_um, p.gate_sigmas);
  if (!res.accepted) {
    return res;
  }
  e.time_s = t_s;
  Eigen::Map<Filter::Vector>(e.x.data()) = f.state();
  Eigen::Map<Eigen::Matrix<double, kEstimatorStates, kEstimatorStates, Eigen::RowMajor>>(
      e.p.data()) = f.covariance();
  return res;
}

}  // namespace nccomp::core::calib
