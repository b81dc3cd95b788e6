// Process noise adapted from the filter's own consistency (issue 22): after each update the
// normalised innovation square ν²/S says whether the filter's predicted uncertainty was too small
// (NIS > 1 on average: more process noise) or too large (NIS < 1: less). The density q is moved
// on a log scale by a small step per measurement, an exponential window over the innovations, and
// stays within [q_min, q_max]. Its only state is q itself, so whatever keeps q keeps the whole
// adaptation across restarts.
#pragma once

namespace nccomp::core::estimation {

struct NoiseAdaptation {
  /// Measurements of the exponential window: the step per measurement is 1/window of the
  /// NIS's departure from 1 (times the gain below).
  double window{20.0};
  /// Bounds of the adapted density (q_min > 0: the adaptation works on log q).
  double q_min{1e-12};
  double q_max{1e-3};
  /// Cap of the sensitivity gain S/P⁻ (below).
  double max_gain{4.0};
};

/// The density after one measurement. nis = ν²/S, prior_fraction = P⁻/S, the part of the
/// innovation's variance that comes from the state (not the measurement noise): where P⁻ ≪ r the
/// NIS hardly moves with q, so its departure from 1 is weighted by S/P⁻ (at most max_gain). The
/// log step is clamped to ±1 (one wild measurement changes q by at most a factor e). A
/// non-finite input leaves q as it is (clamped to the bounds). Real-time safe: no allocation, no
/// locks, no I/O.
double adapt_process_noise(double q, double nis, double prior_fraction,
                           const NoiseAdaptation& a) noexcept;

}  // namespace nccomp::core::estimation
