#include "core/grind/envelope.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "core/grind/profile.hpp"
#include "core/grind/wheel.hpp"
#include "tests/unit/grind/sampled.hpp"

namespace nccomp::core::grind {
namespace {

using test::sampled;

// GIVEN random profiles with every kind of feature (noise, steps, spikes, flat runs),
// WHEN the O(N) deque computes the envelope, THEN it equals brute force everywhere, including
// outside the profile (−inf where the wheel reaches no sample).
TEST(Envelope, GivenRandomProfiles_ThenDequeEqualsBruteForce) {
  std::mt19937_64 rng(12345);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int cases = 0;
  for (const double h : {0.0, 0.02, 0.5, 3.0, 24.0}) {
    for (const std::size_t n : {1UL, 2UL, 7UL, 60UL, 400UL}) {
      for (int rep = 0; rep < 4; ++rep) {
        const double dz = 0.5 + unit(rng);
        const double width = dz * (1.0 + 60.0 * unit(rng));
        if (!(h < 0.5 * width)) {
          continue;
        }
        const auto wheel = Wheel::from_arc_height(width, h);
        std::vector<double> f(n);
        double level = 0.0;
        for (auto& v : f) {
          const double kind = unit(rng);
          if (kind < 0.1) {
            level += 5.0 * (unit(rng) - 0.5);  // step
          } else if (kind < 0.5) {
            level += 0.02 * (unit(rng) - 0.5);                     // noise
          }                                                        // else flat run
          v = level + (unit(rng) < 0.03 ? 3.0 * unit(rng) : 0.0);  // spikes
        }
        const std::ptrdiff_t m = half_window_samples(wheel, dz);
        const std::ptrdiff_t first = -m - 3;
        const auto count = n + 2 * static_cast<std::size_t>(m) + 6;
        std::vector<double> fast(count);
        std::vector<double> slow(count);
        EnvelopeScratch scratch;
        max_plus_arc(f, dz, wheel, first, fast, scratch);
        max_plus_arc_brute(f, dz, wheel, first, slow);
        for (std::size_t q = 0; q < count; ++q) {
          if (std::isinf(slow[q])) {
            ASSERT_EQ(fast[q], slow[q]) << "h=" << h << " n=" << n << " q=" << q;
          } else {
            ASSERT_NEAR(fast[q], slow[q], 1e-12) << "h=" << h << " n=" << n << " q=" << q;
          }
        }
        ++cases;
      }
    }
  }
  EXPECT_GT(cases, 60);
}

// Smooth profiles sampled finely: the regime the closed-form crossings are built for.
TEST(Envelope, GivenFineSmoothProfiles_ThenDequeEqualsBruteForce) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const double dz = 0.1;
  const auto sine = sampled(-200.0, dz, 4001, [](double z) { return 0.3 * std::sin(z / 9.0); });
  const auto crown = sampled(-200.0, dz, 4001, [](double z) { return 0.6 - 0.6e-5 * z * z; });
  for (const auto* p : {&sine, &crown}) {
    const std::ptrdiff_t m = half_window_samples(wheel, dz);
    const auto count = p->size() + 2 * static_cast<std::size_t>(m);
    std::vector<double> fast(count);
    std::vector<double> slow(count);
    EnvelopeScratch scratch;
    max_plus_arc(p->u_mm, dz, wheel, -m, fast, scratch);
    max_plus_arc_brute(p->u_mm, dz, wheel, -m, slow);
    for (std::size_t q = 0; q < count; ++q) {
      ASSERT_NEAR(fast[q], slow[q], 1e-12) << q;
    }
  }
}

// GIVEN a straight profile u = a + b·z, THEN inside (full window) U_T = P + R(sqrt(1 + b²) − 1)
// (tangent contact, seeds.md case 1), and for h = 0: U_T = P + |b|·W/2 (an end rides).
TEST(Envelope, GivenStraightProfile_ThenClosedForm) {
  const double b = 0.004;
  const auto p = sampled(0.0, 0.01, 40001, [&](double z) { return 1.0 + b * z; });
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const auto t = exact_trajectory(p, wheel);
  const double lift = wheel.radius_mm() * (std::sqrt(1.0 + b * b) - 1.0);
  for (double z = 80.0; z <= 320.0; z += 7.0) {
    const auto i = static_cast<std::size_t>(std::lround((z - t.z0_mm) / t.spacing_mm));
    const double zt = t.z_at(static_cast<std::ptrdiff_t>(i));
    EXPECT_NEAR(t.u_mm[i], 1.0 + b * zt + lift, 1e-9) << z;
  }
  const auto flat = Wheel::from_arc_height(150.0, 0.0);
  const auto tf = exact_trajectory(p, flat);
  for (double z = 80.0; z <= 320.0; z += 7.0) {
    const auto i = static_cast<std::size_t>(std::lround((z - tf.z0_mm) / tf.spacing_mm));
    EXPECT_NEAR(tf.u_mm[i], 1.0 + b * (tf.z_at(static_cast<std::ptrdiff_t>(i)) + 75.0), 1e-12);
  }
}

// GIVEN circular profiles of radius ρ > R, THEN the wheel's centre keeps the distance ρ ± R
// from the profile's centre: convex U_T = c − ρ − R + sqrt((ρ+R)² − Z²), concave
// U_T = c + ρ − R − sqrt((ρ−R)² − Z²).
TEST(Envelope, GivenCircularProfilesOfRadiusAboveR_ThenAnalyticTrajectory) {
  const auto wheel = Wheel::from_arc_height(100.0, 0.8);  // R ≈ 1562.9 mm
  const double r = wheel.radius_mm();
  const double rho = 4000.0;
  const double c = 2.0;
  const double dz = 0.02;
  const auto convex =
      sampled(-150.0, dz, 15001, [&](double z) { return c + std::sqrt(rho * rho - z * z) - rho; });
  const auto concave =
      sampled(-150.0, dz, 15001, [&](double z) { return c - std::sqrt(rho * rho - z * z) + rho; });
  const auto tv = exact_trajectory(convex, wheel);
  const auto tc = exact_trajectory(concave, wheel);
  double worst_v = 0.0;
  double worst_c = 0.0;
  // Tangent contact at lateral offset s = Z·R/(ρ ± R): inside the arc (|s| ≤ W/2) for
  // |Z| ≤ 78 mm on the concave circle, |Z| ≤ 178 mm on the convex one.
  for (double z = -75.0; z <= 75.0; z += 1.3) {
    const auto i = static_cast<std::size_t>(std::lround((z - tv.z0_mm) / dz));
    const double zt = tv.z_at(static_cast<std::ptrdiff_t>(i));
    const double uv = c - rho - r + std::sqrt((rho + r) * (rho + r) - zt * zt);
    const double uc = c + rho - r - std::sqrt((rho - r) * (rho - r) - zt * zt);
    worst_v = std::max(worst_v, std::abs(tv.u_mm[i] - uv));
    worst_c = std::max(worst_c, std::abs(tc.u_mm[i] - uc));
  }
  // Sampling: the max over s on a 0.02 mm grid misses the continuous maximum by ≤ κΔ²/8.
  EXPECT_LT(worst_v, 1e-7);
  EXPECT_LT(worst_c, 1e-7);
  // And the exact trajectory grinds the circle back (B = P) where the contact is tangent
  // (|slope| = |z|/ρ below the arc's end slope 0.032: |z| < 128 mm).
  const auto bv = ground_profile_fast(tv, convex, wheel);
  const auto bc = ground_profile_fast(tc, concave, wheel);
  for (std::size_t i = 0; i < convex.size(); ++i) {
    if (std::abs(convex.z_at(static_cast<std::ptrdiff_t>(i))) < 120.0) {
      ASSERT_NEAR(bv[i], convex.u_mm[i], 1e-7) << i;
      ASSERT_NEAR(bc[i], concave.u_mm[i], 1e-7) << i;
    }
    // Everywhere, ends included: gouge-free, and within sampling resolution of P.
    ASSERT_GE(bv[i], convex.u_mm[i] - 1e-12);
    ASSERT_GE(bc[i], concave.u_mm[i] - 1e-12);
    ASSERT_LT(bc[i] - concave.u_mm[i], 1e-6);
  }
}

TEST(Envelope, GivenSymmetricCrown_ThenTrajectoryIsSymmetric) {
  const auto p = sampled(-500.0, 0.25, 4001, [](double z) { return 0.6 * (1 - z * z / 2.5e5); });
  const auto t = exact_trajectory(p, Wheel::from_arc_height(150.0, 0.5));
  ASSERT_EQ(t.u_mm.size(), 4001U + 2U * 300U);
  EXPECT_NEAR(t.z0_mm, -575.0, 1e-12);
  for (std::size_t i = 0; i < t.u_mm.size(); ++i) {
    ASSERT_NEAR(t.u_mm[i], t.u_mm[t.u_mm.size() - 1 - i], 1e-12) << i;
  }
  // Middle: the wheel's lowest point sits on the crown's top (slope 0).
  EXPECT_NEAR(t.u_mm[t.u_mm.size() / 2], 0.6, 1e-12);
  // Overhanging the end by W/2 the wheel's end just touches the roll's last sample.
  EXPECT_NEAR(t.u_mm.back(), 0.0 - 0.5, 1e-9);
}

// GIVEN a narrow concave groove (radius ≪ R), THEN B stays above it (unreachable) and touches P
// everywhere else.
TEST(Envelope, GivenNarrowGroove_ThenGroundProfileLeavesItUnreached) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const auto p = sampled(-300.0, 0.1, 6001, [](double z) {
    return std::abs(z) < 10.0 ? -0.05 * (1.0 - z * z / 100.0) : 0.0;
  });
  const auto t = exact_trajectory(p, wheel);
  const auto b = ground_profile_fast(t, p, wheel);
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double z = p.z_at(static_cast<std::ptrdiff_t>(i));
    EXPECT_GE(b[i], p.u_mm[i] - 1e-12);  // gouge-free by construction
    if (std::abs(z) > 12.0) {
      EXPECT_NEAR(b[i], p.u_mm[i], 1e-9) << z;
    }
  }
  // At the groove's bottom the wheel (sagitta g(10 mm) ≈ 8.9 µm) reaches only a little way in.
  EXPECT_NEAR(b[3000] - p.u_mm[3000], 0.05 - wheel.rise_mm(10.0), 2e-4);
}

TEST(Envelope, GivenBadSpacing_ThenThrows) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  EXPECT_THROW(half_window_samples(wheel, 0.0), std::invalid_argument);
  EXPECT_THROW(half_window_samples(wheel, std::nan("")), std::invalid_argument);
  EXPECT_EQ(half_window_samples(wheel, 0.1), 750);  // W/2 a multiple of Δ: not rounded down
}

}  // namespace
}  // namespace nccomp::core::grind
