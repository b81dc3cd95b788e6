#include "core/grind/verify_grid.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

#include "core/grind/envelope.hpp"

namespace nccomp::core::grind {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// The path's and the profile's index spaces, checked once: path index c = profile index + shift.
struct Grid {
  std::ptrdiff_t shift;
  std::ptrdiff_t m;  // half window in samples
};

Grid check_inputs(const GridPathView& path, const UniformProfile& profile, const Wheel& wheel) {
  if (path.u_mm.empty()) {
    throw std::invalid_argument("grid verification: empty trajectory");
  }
  const double dz = profile.spacing_mm;
  const std::ptrdiff_t m = half_window_samples(wheel, dz);  // throws on a bad spacing
  if (!std::isfinite(path.z0_mm) || !std::isfinite(profile.z0_mm) ||
      !std::isfinite(path.spacing_mm) || !(path.spacing_mm > 0.0)) {
    throw std::invalid_argument("grid verification: origin or spacing is not finite");
  }
  const double shift = (profile.z0_mm - path.z0_mm) / dz;
  const double shift_round = std::round(shift);
  if (std::abs(path.spacing_mm - dz) > 1e-9 * dz || std::abs(shift - shift_round) > 1e-6 ||
      std::abs(shift_round) > 4e18) {
    std::ostringstream msg;
    msg << "grid verification: the trajectory's grid (z0 " << path.z0_mm << " mm, spacing "
        << path.spacing_mm << " mm) is not the profile's (z0 " << profile.z0_mm << " mm, spacing "
        << dz << " mm)";
    throw std::invalid_argument(msg.str());
  }
  for (std::size_t t = 0; t < path.u_mm.size(); ++t) {
    if (!std::isfinite(path.u_mm[t])) {
      std::ostringstream msg;
      msg << "grid verification: trajectory point " << t << " (z "
          << path.z0_mm + static_cast<double>(t) * path.spacing_mm << " mm) is not finite";
      throw std::invalid_argument(msg.str());
    }
  }
  return Grid{static_cast<std::ptrdiff_t>(shift_round), m};
}

// One copy on the stack: wheel position t owns the path indices from t + from_rel up to the
// next entry's start. |from_rel| ≤ M + 1 (a start lies within the copy's window or just past
// the previous copy's), so 8 bytes per entry instead of 16.
struct Entry {
  std::uint32_t t;
  std::int32_t from_rel;
};

// The first c in (lo, hi) at which `wins(c)` holds, else hi: `wins` is false at lo and true at
// hi (virtually, where they lie outside the copies' common window) and monotone in between.
// Where the search starts only sets its cost. First `near` (the last crossing's offset from its
// copy: on smooth paths the crossing moves by less than a sample from one copy to the next, so
// two tests settle it); else a gallop from `parabola` (where the copies would cross if the arc
// were its osculating parabola, O(1) samples off for a roll's slopes, also on noisy paths), then
// bisection.
template <class Wins>
std::ptrdiff_t first_true(std::ptrdiff_t lo, std::ptrdiff_t hi, std::ptrdiff_t near,
                          double parabola, const Wins& wins) {
  const std::ptrdiff_t g = std::clamp(near, lo + 1, hi - 1);
  if (wins(g)) {
    hi = g;
    if (g - 1 > lo) {
      (wins(g - 1) ? hi : lo) = g - 1;
    }
  } else {
    lo = g;
    if (g + 1 < hi) {
      (wins(g + 1) ? hi : lo) = g + 1;
    }
  }
  if (hi - lo <= 1) {
    return hi;
  }
  const auto start = static_cast<std::ptrdiff_t>(
      std::clamp(std::round(parabola), static_cast<double>(lo + 1), static_cast<double>(hi - 1)));
  std::ptrdiff_t step = 1;
  if (wins(start)) {
    hi = start;
    while (hi - step > lo) {
      if (!wins(hi - step)) {
        lo = hi - step;
        break;
      }
      hi -= step;
      step *= 2;
    }
  } else {
    lo = start;
    while (lo + step < hi) {
      if (wins(lo + step)) {
        hi = lo + step;
        break;
      }
      lo += step;
      step *= 2;
    }
  }
  while (hi - lo > 1) {
    const std::ptrdiff_t mid = lo + (hi - lo) / 2;
    (wins(mid) ? hi : lo) = mid;
  }
  return hi;
}

// The lower envelope over path indices [c_lo, c_hi] (the profile's samples), then the sweep.
// `out(v)` receives B at c_lo, c_lo + 1, …, c_hi in order.
// `r_cells` = R/Δ² (0 for the straight grinding line) steers where a search starts.
template <class Out>
void lower_envelope(std::span<const double> u, std::ptrdiff_t c_lo, std::ptrdiff_t c_hi,
                    std::ptrdiff_t m, const double* rise, double r_cells, Out&& out) {
  const auto t_count = static_cast<std::ptrdiff_t>(u.size());
  const std::ptrdiff_t t_first = std::max<std::ptrdiff_t>(0, c_lo - m);
  const std::ptrdiff_t t_last = std::min(t_count - 1, c_hi + m);
  std::vector<Entry> stack;
  if (t_first <= t_last) {
    stack.reserve(static_cast<std::size_t>(t_last - t_first + 1));
  }
  const double* uu = u.data();
  const auto dist = [](std::ptrdiff_t x, std::ptrdiff_t y) {
    return static_cast<std::size_t>(x > y ? x - y : y - x);
  };
  // The last crossing's offset from its copy, where the next search starts (first_true); for an
  // arc the fallback start is the osculating parabola's crossing, c = (a + b)/2 + R·(u_b −
  // u_a)/((b − a)·Δ²).
  std::ptrdiff_t guess = 0;
  for (std::ptrdiff_t b = t_first; b <= t_last; ++b) {
    const double ub = uu[b];
    const std::ptrdiff_t b_start = std::max(b - m, c_lo);
    std::ptrdiff_t x = b_start;
    while (!stack.empty()) {
      const Entry top = stack.back();
      const auto a = static_cast<std::ptrdiff_t>(top.t);
      const std::ptrdiff_t s_a = a + top.from_rel;
      const std::ptrdiff_t a_end = std::min(a + m, c_hi);
      if (b_start > a_end) {
        x = b_start;  // no common sample: b takes over where it begins
      } else {
        // First c in [b_start, a_end] with f_b(c) ≤ f_a(c), else a_end + 1 (a ends, b goes on).
        // f_a − f_b is non-decreasing, so the test is false … false true … true.
        const double ua = uu[a];
        const auto b_wins = [&](std::ptrdiff_t c) {
          return ub + rise[dist(c, b)] <= ua + rise[dist(c, a)];
        };
        if (!(r_cells > 0.0)) {
          // Straight grinding line: g ≡ 0, the difference is constant on the common window.
          x = b_wins(b_start) ? b_start : a_end + 1;
        } else {
          // Where the copies would cross if the arc were its osculating parabola s²/(2R).
          const double parabola =
              0.5 * static_cast<double>(a + b) + r_cells * (ub - ua) / static_cast<double>(b - a);
          x = first_true(b_start - 1, a_end + 1, b + guess, parabola, b_wins);
        }
      }
      if (x <= s_a) {
        stack.pop_back();  // b is at or below a on all of a's run: a never shows
        continue;
      }
      break;
    }
    if (stack.empty()) {
      x = b_start;  // no copy reaches the samples before it
    } else if (x > c_hi) {
      continue;  // b is above the top wherever both reach a profile sample: it never shows
    }
    guess = x - b;
    stack.push_back(Entry{static_cast<std::uint32_t>(b), static_cast<std::int32_t>(x - b)});
  }
  // The sweep: each sample belongs to the copy whose run holds it (+inf beyond its window:
  // then no wheel position reaches the sample at all).
  std::size_t k = 0;
  for (std::ptrdiff_t c = c_lo; c <= c_hi; ++c) {
    while (k + 1 < stack.size() &&
           static_cast<std::ptrdiff_t>(stack[k + 1].t) + stack[k + 1].from_rel <= c) {
      ++k;
    }
    double v = kInf;
    if (!stack.empty()) {
      const auto t = static_cast<std::ptrdiff_t>(stack[k].t);
      const std::size_t d = dist(c, t);
      if (d <= static_cast<std::size_t>(m)) {
        v = uu[t] + rise[d];
      }
    }
    out(v);
  }
}

}  // namespace

void ground_grid_chunks(const GridPathView& path, const UniformProfile& profile,
                        const Wheel& wheel, const ChunkVisitor& visit) {
  const Grid grid = check_inputs(path, profile, wheel);
  if (path.u_mm.size() > std::numeric_limits<std::uint32_t>::max()) {
    throw std::invalid_argument("grid verification: more than 2^32 - 1 trajectory points");
  }
  const std::size_t n = profile.size();
  if (n == 0) {
    return;
  }
  const double dz = profile.spacing_mm;
  // g at every sample offset: the same values as wheel.rise_mm((t − c)·Δ) in the brute force
  // (g is even, and (−k)·Δ = −(k·Δ) exactly).
  const auto m_size = static_cast<std::size_t>(grid.m);
  std::vector<double> rise(m_size + 1);
  for (std::size_t k = 0; k <= m_size; ++k) {
    rise[k] = wheel.rise_mm(static_cast<double>(k) * dz);
  }
  ChunkBuffer out(n, visit);
  const double r_cells = wheel.straight() ? 0.0 : wheel.radius_mm() / (dz * dz);
  lower_envelope(path.u_mm, grid.shift, grid.shift + static_cast<std::ptrdiff_t>(n) - 1, grid.m,
                 rise.data(), r_cells, [&out](double v) { out.push(v); });
  out.finish();
}

std::vector<double> ground_grid_every_sample(const GridPathView& path,
                                             const UniformProfile& profile, const Wheel& wheel) {
  return collect_chunks(profile.size(), [&](const ChunkVisitor& visit) {
    ground_grid_chunks(path, profile, wheel, visit);
  });
}

std::vector<double> ground_grid_brute(const GridPathView& path, const UniformProfile& profile,
                                      const Wheel& wheel) {
  const Grid grid = check_inputs(path, profile, wheel);
  const auto t_count = static_cast<std::ptrdiff_t>(path.u_mm.size());
  std::vector<double> b(profile.size(), kInf);
  for (std::size_t i = 0; i < b.size(); ++i) {
    const std::ptrdiff_t c = grid.shift + static_cast<std::ptrdiff_t>(i);
    const std::ptrdiff_t from = std::max<std::ptrdiff_t>(0, c - grid.m);
    const std::ptrdiff_t to = std::min(t_count - 1, c + grid.m);
    for (std::ptrdiff_t t = from; t <= to; ++t) {
      b[i] = std::min(b[i], path.u_mm[static_cast<std::size_t>(t)] +
                                wheel.rise_mm(static_cast<double>(t - c) * profile.spacing_mm));
    }
  }
  return b;
}

GroundError verify_grid_every_sample(const GridPathView& path, const UniformProfile& profile,
                                     const Wheel& wheel) {
  GroundErrorSum sum;
  ground_grid_chunks(path, profile, wheel, [&](std::size_t first, std::span<const double> b) {
    for (std::size_t k = 0; k < b.size(); ++k) {
      const std::size_t i = first + k;
      const double p = profile.u_mm[i];
      if (!std::isfinite(p)) {
        std::ostringstream msg;
        msg << "grid verification: profile sample " << i << " is not finite";
        throw std::invalid_argument(msg.str());
      }
      sum.add(profile.z_at(static_cast<std::ptrdiff_t>(i)), b[k], p);
    }
  });
  return sum.result();
}

}  // namespace nccomp::core::grind
