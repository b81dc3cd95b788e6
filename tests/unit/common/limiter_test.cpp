#include "core/common/limiter.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "tests/support/alloc_counter.hpp"

namespace nccomp::core {
namespace {

constexpr TimeNs kMs = 1'000'000;

OffsetLimiter make(double abs_um = 100.0, double step_um = 5.0, double rate = 50.0) {
  OffsetLimiter l;
  l.configure({abs_um, step_um, rate});
  l.reset(0.0, 0);
  return l;
}

TEST(OffsetLimiter, GivenBadLimits_WhenConfigured_ThenThrowsNamingTheField) {
  OffsetLimiter l;
  try {
    l.configure({-1.0, 5.0, 50.0});
    FAIL() << "expected throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_abs_um"), std::string::npos);
  }
  EXPECT_THROW(l.configure({100.0, 0.0, 50.0}), std::invalid_argument);
  EXPECT_THROW(l.configure({100.0, 5.0, std::numeric_limits<double>::infinity()}),
               std::invalid_argument);
}

TEST(OffsetLimiter, GivenSmallChange_WhenApplied_ThenPassedUnchanged) {
  auto l = make();
  const auto r = l.apply(2.0, 100 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kPassed);
  EXPECT_DOUBLE_EQ(r.value_um, 2.0);
}

TEST(OffsetLimiter, GivenNaNOrInf_WhenApplied_ThenRejectedAndHeld) {
  auto l = make();
  ASSERT_DOUBLE_EQ(l.apply(3.0, 100 * kMs).value_um, 3.0);
  auto r = l.apply(std::numeric_limits<double>::quiet_NaN(), 200 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kRejectedNonFinite);
  EXPECT_DOUBLE_EQ(r.value_um, 3.0);
  r = l.apply(-std::numeric_limits<double>::infinity(), 300 * kMs);
  EXPECT_TRUE(r.rejected());
  EXPECT_DOUBLE_EQ(l.output_um(), 3.0);
  EXPECT_EQ(l.counters().rejected_non_finite, 2U);
}

TEST(OffsetLimiter, GivenBeyondAbsolute_WhenApplied_ThenRejectedAndHeld) {
  auto l = make(100.0);
  EXPECT_FALSE(l.admissible(100.5));
  EXPECT_TRUE(l.admissible(-100.0));
  const auto r = l.apply(150.0, 1000 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kRejectedAbsolute);
  EXPECT_DOUBLE_EQ(r.value_um, 0.0);
}

TEST(OffsetLimiter, GivenBigStep_WhenApplied_ThenSlewedByPerWriteLimit) {
  auto l = make(100.0, 5.0, 1000.0);
  auto r = l.apply(12.0, 1000 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kSlewed);
  EXPECT_DOUBLE_EQ(r.value_um, 5.0);
  r = l.apply(12.0, 2000 * kMs);
  EXPECT_DOUBLE_EQ(r.value_um, 10.0);
  r = l.apply(12.0, 3000 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kPassed);
  EXPECT_DOUBLE_EQ(r.value_um, 12.0);
  r = l.apply(-12.0, 4000 * kMs);
  EXPECT_DOUBLE_EQ(r.value_um, 7.0);
}

TEST(OffsetLimiter, GivenFastWrites_WhenApplied_ThenSlewedByPerSecondLimit) {
  auto l = make(100.0, 5.0, 50.0);  // 50 µm/s = 0.05 µm per 1 ms cycle
  double out = 0.0;
  for (int i = 1; i <= 1000; ++i) {
    out = l.apply(30.0, i * kMs).value_um;
  }
  EXPECT_NEAR(out, 30.0, 1e-9);  // 1 s at 50 µm/s reaches 30 µm
  auto l2 = make(100.0, 5.0, 50.0);
  for (int i = 1; i <= 200; ++i) {
    out = l2.apply(30.0, i * kMs).value_um;
  }
  EXPECT_NEAR(out, 10.0, 1e-9);  // 0.2 s at 50 µm/s
}

TEST(OffsetLimiter, GivenRestartWithNcValue_WhenReset_ThenContinuesFromIt) {
  auto l = make();
  l.reset(42.0, 5000 * kMs);
  const auto r = l.apply(43.0, 6000 * kMs);
  EXPECT_DOUBLE_EQ(r.value_um, 43.0);
}

// Pins: the elapsed time is never negative. A write stamped before the previous one (a clock
// step, a reordered event) is allowed no change at all; taken literally, −10 s × 50 µm/s is a
// "budget" of −500 µm whose sign flips into a 500 µm move, beyond both limits.
TEST(OffsetLimiter, GivenAWriteStampedBeforeTheLastOne_WhenApplied_ThenNothingMoves) {
  OffsetLimiter l;
  l.configure({200.0, 5.0, 50.0});
  l.reset(0.0, 10'000 * kMs);
  auto r = l.apply(10.0, 0);
  EXPECT_EQ(r.verdict, LimitVerdict::kSlewed);
  EXPECT_DOUBLE_EQ(r.value_um, 0.0);
  EXPECT_DOUBLE_EQ(l.output_um(), 0.0);
  // The same from a non-zero output toward a smaller target.
  l.reset(20.0, 10'000 * kMs);
  r = l.apply(-30.0, 9'000 * kMs);
  EXPECT_DOUBLE_EQ(r.value_um, 20.0);
  EXPECT_EQ(l.counters().slewed, 2U);
}

// Pins: ±max_abs_um itself is inside the limit (apply() agrees with admissible(), which the
// modules use to refuse a measurement before it changes state); one ulp beyond is rejected.
TEST(OffsetLimiter, GivenExactlyTheAbsoluteLimit_WhenApplied_ThenPassed) {
  auto l = make(100.0, 5.0, 50.0);
  l.reset(98.0, 0);
  auto r = l.apply(100.0, 1000 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kPassed);
  EXPECT_DOUBLE_EQ(r.value_um, 100.0);
  EXPECT_TRUE(l.admissible(100.0));
  l.reset(-98.0, 2000 * kMs);
  r = l.apply(-100.0, 3000 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kPassed);
  EXPECT_DOUBLE_EQ(r.value_um, -100.0);
  EXPECT_TRUE(l.admissible(-100.0));
  const double beyond = std::nextafter(100.0, 200.0);
  EXPECT_FALSE(l.admissible(beyond));
  r = l.apply(beyond, 4000 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kRejectedAbsolute);
  EXPECT_DOUBLE_EQ(r.value_um, -100.0);
  EXPECT_EQ(l.counters().rejected_absolute, 1U);
}

// Pins: the limiter never holds a non-finite output, whatever reset() is given (a read-back is
// filtered by its callers today; the limiter must not rely on that). After reset(NaN / ±inf)
// the output is finite and inside ±max_abs_um, and the next writes are finite and move it by at
// most max_step_um.
TEST(OffsetLimiter, GivenANonFiniteNcValue_WhenReset_ThenTheOutputStaysFinite) {
  const double inf = std::numeric_limits<double>::infinity();
  for (const double bad : {std::numeric_limits<double>::quiet_NaN(), inf, -inf}) {
    SCOPED_TRACE(bad);
    auto l = make(100.0, 5.0, 50.0);
    l.reset(42.0, 0);
    l.reset(bad, 1000 * kMs);
    const double held = l.output_um();
    EXPECT_TRUE(std::isfinite(held));
    EXPECT_LE(std::fabs(held), 100.0);
    EXPECT_TRUE(l.admissible(held));
    for (int i = 1; i <= 3; ++i) {
      const double before = l.output_um();
      const auto r = l.apply(60.0, (1000 + 1000 * i) * kMs);
      EXPECT_TRUE(std::isfinite(r.value_um));
      EXPECT_FALSE(r.rejected());
      EXPECT_LE(std::fabs(r.value_um - before), 5.0);
    }
    // The last known value is kept (42 µm), not 0: a non-finite read-back says nothing about
    // the register, and 0 would be taken for what the NC holds.
    EXPECT_DOUBLE_EQ(held, 42.0);
    // Nothing was counted for the reset: it is not a write.
    EXPECT_EQ(l.counters().rejected_non_finite, 0U);
  }
}

// GIVEN an origin beyond max_abs_um (reset() to what an NC held: 250 µm against 100), WHEN
// slewed toward a target inside, THEN the first value is the bound itself (never 245 µm, which
// lies beyond it), then max_step_um per write as usual; the same from below.
TEST(OffsetLimiter, GivenOriginBeyondAbsolute_WhenSlewed_ThenNeverReturnsAValueBeyondIt) {
  auto l = make(100.0, 5.0, 1000.0);
  l.reset(250.0, 0);
  auto r = l.apply(0.0, 1000 * kMs);
  EXPECT_EQ(r.verdict, LimitVerdict::kSlewed);
  EXPECT_DOUBLE_EQ(r.value_um, 100.0);
  r = l.apply(0.0, 2000 * kMs);
  EXPECT_DOUBLE_EQ(r.value_um, 95.0);
  l.reset(-1e30, 3000 * kMs);
  r = l.apply(-20.0, 4000 * kMs);
  EXPECT_DOUBLE_EQ(r.value_um, -100.0);
  EXPECT_LE(std::fabs(r.value_um), l.config().max_abs_um);
}

TEST(OffsetLimiter, ApplyAllocatesNothing) {
  auto l = make();
  test::AllocationScope scope;
  for (int i = 0; i < 10000; ++i) {
    (void)l.apply(i % 7, i * kMs);
  }
  EXPECT_EQ(scope.count(), 0U);
}

}  // namespace
}  // namespace nccomp::core
