// Independent verification on EVERY sample (seeds.md S2, last paragraph) for trajectories on a
// grid: the profile ground when the wheel's midpoint T stands at the grid points
// Z_t = z0 + t·Δ at heights u[t] (the usual practice "T follows P", the exact envelope),
//   B_i = min over t, |c_i − t| ≤ M, of [ u[t] + g((c_i − t)·Δ) ],  c_i = i + shift,
// at every sample i of the profile P (shift: P's first sample on the path's grid, M = the half
// window of envelope.hpp). The three-case rule's path doubles back and is not on a grid: it
// stays with the polyline brute force of verify.hpp.
//
// Deliberately a different algorithm from envelope.cpp (online monotone deque with closed-form
// circle crossings): the lower envelope of the translated copies f_t(c) = u[t] + g((c − t)·Δ),
// each restricted to |c − t| ≤ M, built as a stack in the manner of Felzenszwalb–Huttenlocher's
// distance transform, then read in one sweep. For convex g and a < b, f_a − f_b is
// non-decreasing in c on the common domain (f_b undefined before it: a wins; f_a undefined
// after it: b wins), so each copy owns one contiguous run of samples, ordered by t. A new copy's
// crossing with the top of the stack is the first sample where it is ≤ the top, found on the
// sampled values themselves (two tests at the previous crossing's offset, else galloping from
// where the arc's osculating parabola would put it, then bisection; one test for the straight
// line, whose copies differ by a constant) — the crossing is never computed, only searched —
// and copies whose run it would begin at or before are popped. It evaluates the very
// expressions of the brute force (u[t] + g(k·Δ), g from a table of wheel.rise_mm(k·Δ)), so it
// equals ground_grid_brute bit for bit wherever the rounded differences stay monotone (they
// change by ≥ Δ²/R per sample, far above rounding, for any real wheel; for h = 0 they are
// constant; tests/unit/grind/verify_grid_test.cpp).
//
// Cost: O(T log M) for the stack in the worst case (O(T) on smooth and on noisy paths, where
// the first guesses are a few samples off), O(N + T) for the sweep; memory one 8-byte entry
// per wheel position plus the table of g (8·(M + 1) bytes). Not real-time.
#pragma once

#include <cstddef>
#include <span>
#include <vector>

#include "core/grind/chunks.hpp"
#include "core/grind/profile.hpp"
#include "core/grind/verify.hpp"
#include "core/grind/wheel.hpp"

namespace nccomp::core::grind {

/// A trajectory of T on a uniform grid, read where it lies (the profile itself for the usual
/// practice, GridTrajectory::u_mm for the envelope): Z_t = z0_mm + t·spacing_mm, U = u_mm[t].
struct GridPathView {
  double z0_mm{0.0};
  double spacing_mm{0.0};
  std::span<const double> u_mm;
};

/// B at every sample of `profile`, handed to `visit` in consecutive chunks (samples first ..
/// first + b.size() − 1; +inf where no wheel position is within W/2). The path's grid must be
/// the profile's (same spacing, origins an integer number of samples apart; the path may start
/// before or after the profile and extend beyond it). Throws std::invalid_argument on an empty
/// path, a non-finite height, or grids that differ.
void ground_grid_chunks(const GridPathView& path, const UniformProfile& profile,
                        const Wheel& wheel, const ChunkVisitor& visit);

/// The same B as one array of profile.size() values.
std::vector<double> ground_grid_every_sample(const GridPathView& path,
                                             const UniformProfile& profile, const Wheel& wheel);

/// The reference: the min over every wheel position within the window, O(N·M). Tests only.
std::vector<double> ground_grid_brute(const GridPathView& path, const UniformProfile& profile,
                                      const Wheel& wheel);

/// B − P over every sample of the profile, without an N-sized array (compare_ground's figures).
GroundError verify_grid_every_sample(const GridPathView& path, const UniformProfile& profile,
                                     const Wheel& wheel);

}  // namespace nccomp::core::grind
