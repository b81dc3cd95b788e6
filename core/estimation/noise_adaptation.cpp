#include "core/estimation/noise_adaptation.hpp"

#include <algorithm>
#include <cmath>

namespace nccomp::core::estimation {

double adapt_process_noise(double q, double nis, double prior_fraction,
                           const NoiseAdaptation& a) noexcept {
  const double base = std::clamp(std::isfinite(q) && q > 0.0 ? q : a.q_min, a.q_min, a.q_max);
  if (!std::isfinite(nis) || !std::isfinite(prior_fraction) || !(a.window >= 1.0)) return base;
  const double gain =
      prior_fraction > 0.0 ? std::min(1.0 / prior_fraction, a.max_gain) : a.max_gain;
  const double step = std::clamp((nis - 1.0) * gain / a.window, -1.0, 1.0);
  return std::clamp(base * std::exp(step), a.q_min, a.q_max);
}

}  // namespace nccomp::core::estimation
