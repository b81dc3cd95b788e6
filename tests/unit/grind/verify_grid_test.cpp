#include "core/grind/verify_grid.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/grind/envelope.hpp"
#include "core/grind/verify.hpp"
#include "tests/unit/grind/sampled.hpp"

namespace nccomp::core::grind {
namespace {

using test::sampled;

GridPathView view(const UniformProfile& p) { return {p.z0_mm, p.spacing_mm, p.u_mm}; }
GridPathView view(const GridTrajectory& t) { return {t.z0_mm, t.spacing_mm, t.u_mm}; }

std::vector<double> zs(const UniformProfile& p) {
  std::vector<double> z(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    z[i] = p.z_at(static_cast<std::ptrdiff_t>(i));
  }
  return z;
}

// Heights of every kind the lower envelope meets: noise (many copies popped), smooth waves
// (a crossing a few samples from the last), steps, spikes and flat runs (exact ties).
std::vector<double> random_heights(std::size_t n, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<double> u(n);
  const double kind = unit(rng);
  double level = 0.0;
  const double phase = 6.3 * unit(rng);
  const double wave = 2.0 + 40.0 * unit(rng);
  for (std::size_t t = 0; t < n; ++t) {
    if (kind < 0.3) {
      u[t] = unit(rng) - 0.5;
    } else if (kind < 0.6) {
      u[t] = 0.4 * std::sin(static_cast<double>(t) / wave + phase);
    } else {
      const double r = unit(rng);
      if (r < 0.08) {
        level += 2.0 * (unit(rng) - 0.5);  // step
      } else if (r < 0.4) {
        level += 0.01 * (unit(rng) - 0.5);  // small noise
      }                                     // else flat run: ties
      u[t] = level + (unit(rng) < 0.03 ? unit(rng) : 0.0);
    }
  }
  return u;
}

// GIVEN random grid paths (every kind of height, h = 0 and h > 0, windows from 0 to far more
// samples than the profile has, paths starting before, at and after the profile and ending
// before or beyond it), WHEN B is computed at every profile sample by the lower envelope,
// THEN it equals the O(N·M) min over every wheel position bit for bit (+inf where none reaches).
TEST(VerifyGrid, GivenRandomPaths_ThenLowerEnvelopeEqualsBruteForceOnEverySample) {
  std::mt19937_64 rng(20261126);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int cases = 0;
  int with_unreached = 0;
  for (const double h : {0.0, 0.01, 0.3, 2.0, 20.0}) {
    for (const double window_samples : {0.4, 1.0, 3.0, 10.0, 37.0, 250.0, 1500.0}) {
      for (const std::size_t n : {1UL, 2UL, 9UL, 80UL, 300UL}) {
        for (int rep = 0; rep < 3; ++rep) {
          const double dz = 0.25 + unit(rng);
          const double width = dz * window_samples * (1.0 + 0.1 * unit(rng));
          if (!(h < 0.5 * width)) {
            continue;
          }
          const auto wheel = Wheel::from_arc_height(width, h);
          const auto m = static_cast<std::ptrdiff_t>(half_window_samples(wheel, dz));
          const UniformProfile p{-3.0, dz, random_heights(n, rng)};
          // The path: from up to M + 5 samples before the profile to up to M + 5 after it.
          const auto span = static_cast<std::ptrdiff_t>(n) + 2 * m + 10;
          auto pick = [&] {
            return static_cast<std::ptrdiff_t>(unit(rng) * static_cast<double>(span)) - m - 5;
          };
          std::ptrdiff_t from = pick();
          std::ptrdiff_t to = pick();
          if (from > to) {
            std::swap(from, to);
          }
          const auto path_u = random_heights(static_cast<std::size_t>(to - from + 1), rng);
          const GridPathView path{p.z_at(from), dz, path_u};
          const auto fast = ground_grid_every_sample(path, p, wheel);
          const auto slow = ground_grid_brute(path, p, wheel);
          ASSERT_EQ(fast.size(), n);
          bool unreached = false;
          for (std::size_t i = 0; i < n; ++i) {
            ASSERT_EQ(fast[i], slow[i]) << "h=" << h << " W/dz=" << window_samples << " n=" << n
                                        << " path " << from << ".." << to << " i=" << i;
            unreached = unreached || std::isinf(slow[i]);
          }
          with_unreached += unreached ? 1 : 0;
          // The paths of the command: the profile itself and its exact envelope (shift M).
          const auto exact = exact_trajectory(p, wheel);
          ASSERT_EQ(ground_grid_every_sample(view(p), p, wheel),
                    ground_grid_brute(view(p), p, wheel));
          ASSERT_EQ(ground_grid_every_sample(view(exact), p, wheel),
                    ground_grid_brute(view(exact), p, wheel));
          ++cases;
        }
      }
    }
  }
  EXPECT_GT(cases, 300);
  EXPECT_GT(with_unreached, 20);  // paths that miss some samples were among them
}

// GIVEN a window much wider than the profile (5 samples, W/2 = 40 samples) THEN still equal,
// and the exact envelope grinds the samples it can reach back to P.
TEST(VerifyGrid, GivenWindowWiderThanProfile_ThenEqualsBruteForce) {
  const auto wheel = Wheel::from_arc_height(80.0, 0.4);
  const auto p = sampled(0.0, 1.0, 5, [](double z) { return 0.01 * z * (4.0 - z); });
  const auto exact = exact_trajectory(p, wheel);
  EXPECT_EQ(exact.u_mm.size(), 5U + 2 * 40U);
  const auto b = ground_grid_every_sample(view(exact), p, wheel);
  EXPECT_EQ(b, ground_grid_brute(view(exact), p, wheel));
  for (std::size_t i = 0; i < p.size(); ++i) {
    EXPECT_GE(b[i], p.u_mm[i] - 1e-15) << i;  // the envelope never gouges
  }
  EXPECT_EQ(ground_grid_every_sample(view(p), p, wheel), ground_grid_brute(view(p), p, wheel));
}

// A straight profile of slope b: T following P on the grid gouges min over k of [b·kΔ + g(kΔ)]
// at every sample whose window lies on the path, i.e. R(sqrt(1 + b²) − 1) up to the grid's
// Δ²/(8R); the exact envelope grinds P back. For h = 0 the usual practice cuts |b|·MΔ.
TEST(VerifyGrid, GivenStraightProfile_ThenClosedFormGougeAndExactEnvelopeGrindsP) {
  const double b = 0.002;
  const double dz = 0.05;
  const auto p = sampled(0.0, dz, 6001, [&](double z) { return 0.1 + b * z; });
  {
    const auto wheel = Wheel::from_arc_height(150.0, 0.5);
    const auto usual = ground_grid_every_sample(view(p), p, wheel);
    const double gouge = wheel.radius_mm() * (std::sqrt(1 + b * b) - 1);  // ≈ 11.25 µm
    const double grid = dz * dz / (8.0 * wheel.radius_mm());
    for (std::size_t i = 1500; i <= 4500; i += 10) {
      EXPECT_NEAR(usual[i], p.u_mm[i] - gouge, grid + 1e-12) << i;
      EXPECT_GE(usual[i], p.u_mm[i] - gouge - 1e-12) << i;  // grid positions: a subset
    }
    const auto e = verify_grid_every_sample(view(exact_trajectory(p, wheel)), p, wheel);
    EXPECT_EQ(e.points, 6001U);
    EXPECT_LT(e.max_abs_mm, 1e-12);
  }
  {
    const auto wheel = Wheel::from_arc_height(150.0, 0.0);  // straight grinding line, g ≡ 0
    const auto m = static_cast<double>(half_window_samples(wheel, dz));
    const auto usual = ground_grid_every_sample(view(p), p, wheel);
    EXPECT_EQ(usual, ground_grid_brute(view(p), p, wheel));
    for (std::size_t i = 1500; i <= 4500; i += 10) {
      EXPECT_NEAR(usual[i], p.u_mm[i] - b * m * dz, 1e-12) << i;
    }
    EXPECT_NEAR(usual[0], p.u_mm[0], 1e-15);  // nothing of the path lies below the first sample
    const auto e = verify_grid_every_sample(view(exact_trajectory(p, wheel)), p, wheel);
    EXPECT_LT(e.max_abs_mm, 1e-12);
  }
}

// The issue's example: crown 0.6 mm over ±500 mm, W = 150, h = 0.5, sampled every 0.05 mm
// (20,001 samples, more than one chunk of the stream). T following P gouges up to
// e(z*) = a(500² − z*²) − g(500 − z*) at z* = 500/(1 + 2aR) = 486.85 mm (a sample here):
// 15.775 µm, the closed form of Verify.GivenIssueCrown_*; the exact envelope grinds P to
// sampling resolution. Both agree with the polyline brute force of verify.hpp at its points.
TEST(VerifyGrid, GivenIssueCrown_ThenUsualPracticeErrs15p77umAndExactEnvelopeNone) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const double dz = 0.05;
  const auto p = sampled(-500.0, dz, 20001, [](double z) { return 0.6 * (1 - z * z / 2.5e5); });
  const double a = 0.6 / 2.5e5;
  const double z_star = 500.0 / (1.0 + 2 * a * wheel.radius_mm());
  const double expect = a * (500.0 * 500.0 - z_star * z_star) - wheel.rise_mm(500.0 - z_star);
  EXPECT_NEAR(expect, 0.015775, 1e-6);

  const auto usual = verify_grid_every_sample(view(p), p, wheel);
  EXPECT_EQ(usual.points, 20001U);
  EXPECT_EQ(usual.unreached, 0U);
  EXPECT_NEAR(usual.max_gouge_mm, expect, 1e-8);
  EXPECT_NEAR(usual.max_abs_mm, expect, 1e-8);
  EXPECT_NEAR(std::abs(usual.z_at_max_mm), z_star, dz);
  EXPECT_LT(usual.max_left_mm, 1e-12);
  EXPECT_GT(usual.rms_mm, 0.003);

  const auto exact = exact_trajectory(p, wheel);
  const auto e = verify_grid_every_sample(view(exact), p, wheel);
  EXPECT_EQ(e.points, 20001U);
  EXPECT_LT(e.max_abs_mm, 1e-9);

  // The streamed figures are compare_ground's on the whole array.
  const auto b_usual = ground_grid_every_sample(view(p), p, wheel);
  const auto z = zs(p);
  const auto whole = compare_ground(z, b_usual, p.u_mm);
  EXPECT_EQ(whole.max_abs_mm, usual.max_abs_mm);
  EXPECT_EQ(whole.z_at_max_mm, usual.z_at_max_mm);
  EXPECT_EQ(whole.rms_mm, usual.rms_mm);

  // Against the polyline brute force (verify.hpp) at 201 points: the polyline holds the grid
  // points and the chords between them, so it grinds at most as high, and lower by at most
  // Δ²·max g''/8 (along a chord U is linear and U + g(z − Z) has the curvature of the arc,
  // g'' ≤ 1.0003/R here): 5.6e-8 mm.
  std::vector<double> z_eval;
  std::vector<std::size_t> at;
  for (std::size_t i = 0; i < p.size(); i += 100) {
    z_eval.push_back(z[i]);
    at.push_back(i);
  }
  const auto b_exact = ground_grid_every_sample(view(exact), p, wheel);
  const auto poly_usual = ground_by_grid_path(p.z0_mm, dz, p.u_mm, wheel, z_eval);
  const auto poly_exact = ground_by_grid_path(exact.z0_mm, dz, exact.u_mm, wheel, z_eval);
  const double sag = 1.001 * dz * dz / (8.0 * wheel.radius_mm());
  double deepest = 0.0;
  for (std::size_t k = 0; k < at.size(); ++k) {
    EXPECT_LE(poly_usual[k], b_usual[at[k]] + 1e-15) << z_eval[k];
    EXPECT_GE(poly_usual[k], b_usual[at[k]] - sag) << z_eval[k];
    EXPECT_LE(poly_exact[k], b_exact[at[k]] + 1e-15) << z_eval[k];
    EXPECT_GE(poly_exact[k], b_exact[at[k]] - sag) << z_eval[k];
    deepest = std::max(deepest, b_exact[at[k]] - poly_exact[k]);
  }
  EXPECT_GT(deepest, 0.5 * sag);  // two algorithms, and the difference is the chords
}

TEST(VerifyGrid, GivenBadInput_ThenThrowsWithClearMessage) {
  const auto wheel = Wheel::from_arc_height(10.0, 0.1);
  const auto p = sampled(0.0, 1.0, 20, [](double z) { return 0.01 * z; });
  const auto message = [&](const GridPathView& path) {
    try {
      ground_grid_every_sample(path, p, wheel);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no exception");
  };
  std::vector<double> u = p.u_mm;
  u[7] = std::nan("");
  EXPECT_EQ(message({0.0, 1.0, u}), "grid verification: trajectory point 7 (z 7 mm) is not finite");
  u[7] = std::numeric_limits<double>::infinity();
  EXPECT_THROW(ground_grid_brute({0.0, 1.0, u}, p, wheel), std::invalid_argument);
  EXPECT_EQ(message({0.0, 1.0, {}}), "grid verification: empty trajectory");
  EXPECT_EQ(message({0.5, 1.0, p.u_mm}),
            "grid verification: the trajectory's grid (z0 0.5 mm, spacing 1 mm) is not the "
            "profile's (z0 0 mm, spacing 1 mm)");
  EXPECT_EQ(message({0.0, 1.1, p.u_mm}).substr(0, 45),
            "grid verification: the trajectory's grid (z0 ");
  EXPECT_EQ(message({std::nan(""), 1.0, p.u_mm}),
            "grid verification: origin or spacing is not finite");
  auto bad_p = p;
  bad_p.u_mm[3] = std::nan("");
  try {
    verify_grid_every_sample(view(p), bad_p, wheel);
    ADD_FAILURE() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "grid verification: profile sample 3 is not finite");
  }
}

}  // namespace
}  // namespace nccomp::core::grind
