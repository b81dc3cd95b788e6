// Creep profile shapes (S0 claims 17/18): the fraction f(u) ∈ [0, 1] of a correction that is in
// force at progress u ∈ [0, 1] of the creep (path, time or rate based — the caller computes u).
// Shared by every module that feeds a correction in gradually (S0 wear, S1 checkpoints, S3 drift).
// All functions are real-time safe.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <numbers>
#include <span>

namespace nccomp::core {

enum class ProfileShape : std::uint8_t {
  kLinear = 0,      // f = u: constant slope h/L
  kCosine = 1,      // f = (1 − cos πu)/2: zero slope at both ends
  kSmoothstep = 2,  // f = 3u² − 2u³: zero slope at both ends
  kTable = 3,       // operator table: f at equally spaced u, linear in between
  kStep = 4,        // prior art: the whole correction at once (f = 1 for u > 0)
};

/// An operator profile table: values f(u_i) at u_i = i/(n−1); must start at 0, end at 1 and be
/// non-decreasing (validated where it is configured).
inline constexpr std::size_t kMaxProfileTable = 33;
struct ProfileTable {
  std::array<double, kMaxProfileTable> f{};
  std::size_t n{0};
};

/// Fraction in force at progress u (clamped to [0, 1]).
inline double profile_fraction(ProfileShape shape, double u, const ProfileTable* table = nullptr) noexcept {
  if (!(u > 0.0)) {  // also NaN
    return 0.0;
  }
  if (u >= 1.0) {
    return 1.0;
  }
  switch (shape) {
    case ProfileShape::kLinear:
      return u;
    case ProfileShape::kCosine:
      return 0.5 * (1.0 - std::cos(std::numbers::pi * u));
    case ProfileShape::kSmoothstep:
      return u * u * (3.0 - 2.0 * u);
    case ProfileShape::kTable: {
      if (table == nullptr || table->n < 2) {
        return u;
      }
      const double x = u * static_cast<double>(table->n - 1);
      const auto i = std::min(static_cast<std::size_t>(x), table->n - 2);
      const double t = x - static_cast<double>(i);
      return table->f[i] + t * (table->f[i + 1] - table->f[i]);
    }
    case ProfileShape::kStep:
      return 1.0;
  }
  return u;
}

/// Slope df/du at progress u: the steepest slope sets the largest surface gradient h·max f'/L.
inline double profile_slope(ProfileShape shape, double u, const ProfileTable* table = nullptr) noexcept {
  if (u < 0.0 || u > 1.0) {
    return 0.0;
  }
  switch (shape) {
    case ProfileShape::kLinear:
      return 1.0;
    case ProfileShape::kCosine:
      return 0.5 * std::numbers::pi * std::sin(std::numbers::pi * u);
    case ProfileShape::kSmoothstep:
      return 6.0 * u * (1.0 - u);
    case ProfileShape::kTable: {
      if (table == nullptr || table->n < 2) {
        return 1.0;
      }
      const double x = std::min(u, 1.0 - 1e-12) * static_cast<double>(table->n - 1);
      const auto i = std::min(static_cast<std::size_t>(x), table->n - 2);
      return (table->f[i + 1] - table->f[i]) * static_cast<double>(table->n - 1);
    }
    case ProfileShape::kStep:
      return 0.0;
  }
  return 1.0;
}

}  // namespace nccomp::core
