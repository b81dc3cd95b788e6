#include "core/grind/envelope.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>

namespace nccomp::core::grind {
namespace {

constexpr double kMinusInf = -std::numeric_limits<double>::infinity();

// First integer i at which cap k (> j) is at least cap j, within k's window start lo = k − M and
// j's window end + 1 = j + M + 1. Caps are f − g, circles of radius R centred at (jΔ, f_j − R).
// `f(j)` is the value of sample j.
template <class Values>
std::ptrdiff_t crossing(const Values& f, std::ptrdiff_t j, std::ptrdiff_t k, std::ptrdiff_t m,
                        double dz_mm, const Wheel& wheel, const double* rise) {
  const std::ptrdiff_t lo = k - m;
  const std::ptrdiff_t end = j + m + 1;
  if (lo >= end) {
    return end;  // windows do not overlap: k takes over when j ends
  }
  const double fj = f(j);
  const double fk = f(k);
  if (wheel.straight()) {
    return fk >= fj ? lo : end;  // flat caps: the higher one wins all of the overlap
  }
  const double r = wheel.radius_mm();
  const double dz = static_cast<double>(k - j) * dz_mm;
  const double dp = fk - fj;
  const double d2 = dz * dz + dp * dp;
  const double t2 = r * r - 0.25 * d2;
  if (t2 >= 0.0) {
    const double d = std::sqrt(d2);
    const double t = std::sqrt(t2);
    // The upper of the two circle intersections is on both upper half circles iff its height
    // above both centres is ≥ 0; then it is the unique crossing of the caps.
    if (t * dz / d >= 0.5 * std::abs(dp)) {
      const double z_rel = 0.5 * dz - dp * t / d;  // from j's centre, mm
      const double x = static_cast<double>(j) + z_rel / dz_mm;
      const double c = std::ceil(x);
      if (!(c > static_cast<double>(lo))) {  // NaN too: never cast it
        return lo;
      }
      if (!(c < static_cast<double>(end))) {
        return end;
      }
      return static_cast<std::ptrdiff_t>(c);
    }
  }
  // No crossing on the common domain: one cap is above the other everywhere; compare at lo.
  // |lo − j| ≤ M (lo < end = j + M + 1) and k − lo = M: both in the table.
  const double vj = fj - rise[static_cast<std::size_t>(lo >= j ? lo - j : j - lo)];
  const double vk = fk - rise[static_cast<std::size_t>(k - lo)];
  return vk >= vj ? lo : end;
}

// The deque over n samples valued f(j); out(q, v) receives output q = 0..count−1 (index
// i = out_first + q) in order.
template <class Values, class Out>
void max_plus_arc_impl(std::ptrdiff_t n, const Values& f, double spacing_mm, const Wheel& wheel,
                       std::ptrdiff_t out_first, std::ptrdiff_t count, EnvelopeScratch& scratch,
                       Out&& out) {
  const std::ptrdiff_t m = half_window_samples(wheel, spacing_mm);
  // The deque never holds more than the caps alive at one query: 2M + 2 (the one just pushed).
  const auto need = std::bit_ceil(static_cast<std::size_t>(std::min(n, 2 * m + 2)) + 1);
  if (scratch.index.size() < need) {
    scratch.index.assign(need, 0);
    scratch.from.assign(need, 0);
  }
  const auto m_size = static_cast<std::size_t>(m);
  scratch.rise.resize(m_size + 1);
  for (std::size_t k = 0; k <= m_size; ++k) {
    scratch.rise[k] = wheel.rise_mm(static_cast<double>(k) * spacing_mm);
  }
  const double* rise = scratch.rise.data();
  const std::size_t mask = need - 1;
  std::ptrdiff_t* idx = scratch.index.data();
  std::ptrdiff_t* from = scratch.from.data();
  std::size_t head = 0;  // front = idx[head & mask]
  std::size_t tail = 0;  // one past back
  std::ptrdiff_t next = 0;
  for (std::ptrdiff_t q = 0; q < count; ++q) {
    const std::ptrdiff_t i = out_first + q;
    // Caps whose window has begun.
    for (; next < n && next - m <= i; ++next) {
      std::ptrdiff_t x = 0;
      while (tail > head) {
        const std::ptrdiff_t b = idx[(tail - 1) & mask];
        x = crossing(f, b, next, m, spacing_mm, wheel, rise);
        if (tail - head >= 2 && x <= from[(tail - 1) & mask]) {
          --tail;  // the back never wins: its successor overtakes it before it overtakes its own
          continue;
        }
        break;
      }
      idx[tail & mask] = next;
      from[tail & mask] = x;
      ++tail;
    }
    while (tail - head >= 2 && from[(head + 1) & mask] <= i) {
      ++head;
    }
    double v = kMinusInf;
    if (tail > head) {
      const std::ptrdiff_t j = idx[head & mask];
      if (j - m <= i && i <= j + m) {
        v = f(j) - rise[static_cast<std::size_t>(j > i ? j - i : i - j)];
      }
    }
    out(q, v);
  }
}

}  // namespace

std::ptrdiff_t half_window_samples(const Wheel& wheel, double spacing_mm) {
  if (!(spacing_mm > 0.0) || !std::isfinite(spacing_mm)) {
    throw std::invalid_argument("sample spacing must be > 0 mm");
  }
  const double m = std::floor(wheel.half_width_mm() / spacing_mm * (1.0 + 1e-9));
  if (m > 1e9) {
    throw std::invalid_argument("wheel width / sample spacing is too large");
  }
  return static_cast<std::ptrdiff_t>(m);
}

void max_plus_arc(std::span<const double> f, double spacing_mm, const Wheel& wheel,
                  std::ptrdiff_t out_first, std::span<double> out, EnvelopeScratch& scratch) {
  const double* values = f.data();
  double* dst = out.data();
  max_plus_arc_impl(
      static_cast<std::ptrdiff_t>(f.size()), [values](std::ptrdiff_t j) { return values[j]; },
      spacing_mm, wheel, out_first, static_cast<std::ptrdiff_t>(out.size()), scratch,
      [dst](std::ptrdiff_t q, double v) { dst[q] = v; });
}

void max_plus_arc_brute(std::span<const double> f, double spacing_mm, const Wheel& wheel,
                        std::ptrdiff_t out_first, std::span<double> out) {
  const auto n = static_cast<std::ptrdiff_t>(f.size());
  const std::ptrdiff_t m = half_window_samples(wheel, spacing_mm);
  for (std::size_t q = 0; q < out.size(); ++q) {
    const std::ptrdiff_t i = out_first + static_cast<std::ptrdiff_t>(q);
    double best = kMinusInf;
    for (std::ptrdiff_t j = std::max<std::ptrdiff_t>(0, i - m); j <= std::min(n - 1, i + m); ++j) {
      best = std::max(best, f[static_cast<std::size_t>(j)] -
                                wheel.rise_mm(static_cast<double>(j - i) * spacing_mm));
    }
    out[q] = best;
  }
}

GridTrajectory exact_trajectory(const UniformProfile& profile, const Wheel& wheel) {
  const std::ptrdiff_t m = half_window_samples(wheel, profile.spacing_mm);
  GridTrajectory t{profile.z_at(-m), profile.spacing_mm, {}};
  t.u_mm.resize(profile.size() + 2 * static_cast<std::size_t>(m));
  EnvelopeScratch scratch;
  max_plus_arc(profile.u_mm, profile.spacing_mm, wheel, -m, t.u_mm, scratch);
  return t;
}

void ground_profile_chunks(const GridTrajectory& trajectory, const UniformProfile& profile,
                           const Wheel& wheel, const ChunkVisitor& visit) {
  const double shift = (profile.z0_mm - trajectory.z0_mm) / profile.spacing_mm;
  const double shift_round = std::round(shift);
  if (std::abs(trajectory.spacing_mm - profile.spacing_mm) > 1e-9 * profile.spacing_mm ||
      std::abs(shift - shift_round) > 1e-6) {
    throw std::invalid_argument("ground profile: trajectory grid is not the profile's grid");
  }
  // B = −maxplus(−U_T): the deque reads −U_T in place (negation is exact), no negated copy.
  const double* u = trajectory.u_mm.data();
  ChunkBuffer out(profile.size(), visit);
  EnvelopeScratch scratch;
  max_plus_arc_impl(
      static_cast<std::ptrdiff_t>(trajectory.u_mm.size()), [u](std::ptrdiff_t j) { return -u[j]; },
      profile.spacing_mm, wheel, static_cast<std::ptrdiff_t>(shift_round),
      static_cast<std::ptrdiff_t>(profile.size()), scratch,
      // +inf where no trajectory point reaches z: nothing ground there
      [&out](std::ptrdiff_t, double v) { out.push(-v); });
  out.finish();
}

std::vector<double> ground_profile_fast(const GridTrajectory& trajectory,
                                        const UniformProfile& profile, const Wheel& wheel) {
  return collect_chunks(profile.size(), [&](const ChunkVisitor& visit) {
    ground_profile_chunks(trajectory, profile, wheel, visit);
  });
}

}  // namespace nccomp::core::grind
