// The exact, gouge-free trajectory of S2 (seeds.md, "exact form"):
//   U_T(Z) = max over |s| ≤ W/2 of [ P(Z + s) − g(s) ],
// a max-plus convolution of P with the concave −g, and the profile a trajectory grinds,
//   B(z) = min over |z − Z| ≤ W/2 of [ U_T(Z) + g(z − Z) ],
// the dual min-plus convolution (B = −maxplus(−U_T)).
//
// Algorithm (O(N) time, O(W/Δ) extra memory). Every sample j contributes the cap
// φ_j(i) = f_j − g((i − j)·Δ) on the index window |i − j| ≤ M. Two caps j < k are translates of
// one strictly concave arc, so φ_j − φ_k is strictly decreasing where both exist; with the
// windows (φ = −∞ outside, windows ordered like the centres) the difference is still monotone,
// so any two caps cross once and the later one wins to the right. The upper envelope therefore
// visits caps in index order, each on one interval, and a monotone deque finds it: a new cap
// pops dominated caps from the back (its crossing with the back comes before the back's own
// start), the query pops caps from the front once their successor has taken over. Crossings are
// computed in closed form: two circles of equal radius R meet on the perpendicular bisector of
// their centres. Each cap is pushed and popped once and costs at most two crossings.
// Correctness against brute force: tests/unit/grind/envelope_test.cpp.
#pragma once

#include <cstddef>
#include <functional>
#include <span>
#include <vector>

#include "core/grind/chunks.hpp"
#include "core/grind/profile.hpp"
#include "core/grind/wheel.hpp"

namespace nccomp::core::grind {

/// Half window in samples: M = floor(W/2 / Δ) (with a relative guard of 1e-9 against W/2 being
/// a multiple of Δ that rounds down).
std::ptrdiff_t half_window_samples(const Wheel& wheel, double spacing_mm);

/// out[k] = max over j ∈ [0, f.size()), |j − i| ≤ M of f[j] − g((j − i)·Δ), i = out_first + k;
/// −inf where the window holds no sample. O(f.size() + out.size()). `scratch` is reused between
/// calls (sized here: about 3 × 8 bytes per window sample). Not real-time (may allocate scratch).
struct EnvelopeScratch {
  std::vector<std::ptrdiff_t> index;
  std::vector<std::ptrdiff_t> from;
  std::vector<double> rise;  ///< g(k·Δ), k = 0..M: one table look-up per output, not a sqrt
};
void max_plus_arc(std::span<const double> f, double spacing_mm, const Wheel& wheel,
                  std::ptrdiff_t out_first, std::span<double> out, EnvelopeScratch& scratch);

/// The same by brute force, O(N·M): the reference in tests and in the bench's spot checks.
void max_plus_arc_brute(std::span<const double> f, double spacing_mm, const Wheel& wheel,
                        std::ptrdiff_t out_first, std::span<double> out);

/// A trajectory of T on a uniform grid Z_t = z0_mm + t·spacing_mm.
struct GridTrajectory {
  double z0_mm{0.0};
  double spacing_mm{0.0};
  std::vector<double> u_mm;
  [[nodiscard]] double z_at(std::ptrdiff_t t) const noexcept {
    return z0_mm + static_cast<double>(t) * spacing_mm;
  }
};

/// The exact envelope on the profile's grid extended by M samples (≈ W/2) beyond each end, so
/// the wheel overhangs the roll's ends (no material is there, nothing to gouge).
GridTrajectory exact_trajectory(const UniformProfile& profile, const Wheel& wheel);

/// B on the profile's samples for a trajectory on a grid of the same spacing whose origin is an
/// integer number of samples from the profile's (as exact_trajectory returns). O(N). +inf where
/// no trajectory point is within W/2. Throws std::invalid_argument if the grids differ.
std::vector<double> ground_profile_fast(const GridTrajectory& trajectory,
                                        const UniformProfile& profile, const Wheel& wheel);

/// The same B, handed to `visit` in consecutive chunks (samples first .. first + b.size() − 1)
/// instead of one N-sized array: what the command's unreachable-region report streams through.
void ground_profile_chunks(const GridTrajectory& trajectory, const UniformProfile& profile,
                           const Wheel& wheel, const ChunkVisitor& visit);

}  // namespace nccomp::core::grind
