// drivers/reconnect_backoff.hpp with a fake clock: the schedule of waits (doubling, capped), the
// reset only after a healthy stretch of reset_after, and no allocation.
#include "drivers/reconnect_backoff.hpp"

#include <gtest/gtest.h>

#include <vector>

#include "tests/support/alloc_counter.hpp"

namespace nccomp::drivers {
namespace {

constexpr core::TimeNs kMs = 1'000'000;

// GIVEN min 100 ms, max 1 s, WHEN the link is lost again and again (never healthy), THEN the
// waits are 100, 200, 400, 800 ms and then 1 s each, counted.
TEST(ReconnectBackoff, WaitsDoubleFromTheMinimumUpToTheCap) {
  ReconnectBackoff b(100 * kMs, 1000 * kMs, 10'000 * kMs);
  std::vector<core::TimeNs> waits;
  core::TimeNs now = 5'000 * kMs;
  for (int i = 0; i < 7; ++i) {
    const core::TimeNs next = b.lost(now);
    waits.push_back(next - now);
    now = next + 3 * kMs;  // the attempt, which fails again
  }
  const std::vector<core::TimeNs> want = {100 * kMs,  200 * kMs,  400 * kMs, 800 * kMs,
                                          1000 * kMs, 1000 * kMs, 1000 * kMs};
  EXPECT_EQ(waits, want);
  EXPECT_EQ(b.waits(), 7U);
  EXPECT_EQ(b.delay_ns(), 1000 * kMs);
  EXPECT_EQ(b.raised_delay_ns(), 1000 * kMs);
}

// Status shows the back-off only while it is raised above the minimum.
TEST(ReconnectBackoff, RaisedDelayIsZeroAtTheMinimum) {
  ReconnectBackoff b(100 * kMs, 1000 * kMs, 2000 * kMs);
  EXPECT_EQ(b.raised_delay_ns(), 0);
  const core::TimeNs next = b.lost(0);  // this wait is the minimum, the next one is not
  EXPECT_EQ(b.raised_delay_ns(), 200 * kMs);
  b.healthy(next, true);
  b.healthy(next + 2000 * kMs, true);
  EXPECT_EQ(b.raised_delay_ns(), 0);
}

// GIVEN a back-off at its cap, WHEN a connection answers (healthy cycles) for less than
// reset_after and is then lost, THEN the wait stays at the cap: one answered read is no reset.
TEST(ReconnectBackoff, AHealthyStretchShorterThanResetAfterDoesNotReset) {
  ReconnectBackoff b(100 * kMs, 1000 * kMs, 2000 * kMs);
  core::TimeNs now = 0;
  for (int i = 0; i < 5; ++i) {
    now = b.lost(now);
  }
  ASSERT_EQ(b.delay_ns(), 1000 * kMs);
  for (core::TimeNs t = now; t < now + 1999 * kMs; t += 10 * kMs) {
    b.healthy(t, true);
  }
  EXPECT_EQ(b.delay_ns(), 1000 * kMs);
  EXPECT_EQ(b.lost(now + 1999 * kMs), now + 1999 * kMs + 1000 * kMs);
}

// GIVEN a back-off at its cap, WHEN the link stays healthy for reset_after, THEN the next loss
// waits the minimum again (and the status shows it as soon as the stretch is complete).
TEST(ReconnectBackoff, ResetsToTheMinimumAfterAHealthyStretchOfResetAfter) {
  ReconnectBackoff b(100 * kMs, 1000 * kMs, 2000 * kMs);
  core::TimeNs now = 0;
  for (int i = 0; i < 5; ++i) {
    now = b.lost(now);
  }
  b.healthy(now, true);
  b.healthy(now + 1999 * kMs, true);
  EXPECT_EQ(b.delay_ns(), 1000 * kMs);
  b.healthy(now + 2000 * kMs, true);
  EXPECT_EQ(b.delay_ns(), 100 * kMs);
  EXPECT_EQ(b.lost(now + 2500 * kMs), now + 2600 * kMs);
  EXPECT_EQ(b.delay_ns(), 200 * kMs);
}

// GIVEN a link that was healthy since t and is lost at t + reset_after before another healthy()
// call, THEN that stretch counts: the wait is the minimum.
TEST(ReconnectBackoff, AStretchEndingInTheLossStillCounts) {
  ReconnectBackoff b(100 * kMs, 1000 * kMs, 2000 * kMs);
  core::TimeNs now = 0;
  for (int i = 0; i < 5; ++i) {
    now = b.lost(now);
  }
  b.healthy(now, true);
  EXPECT_EQ(b.lost(now + 2000 * kMs), now + 2100 * kMs);
}

// GIVEN healthy cycles interrupted by one failed cycle (a timeout, garbage), THEN the healthy
// clock starts again after it: two stretches of 1.5 s do not make one of 2 s.
TEST(ReconnectBackoff, AFailedCycleRestartsTheHealthyClock) {
  ReconnectBackoff b(100 * kMs, 1000 * kMs, 2000 * kMs);
  core::TimeNs now = 0;
  for (int i = 0; i < 5; ++i) {
    now = b.lost(now);
  }
  b.healthy(now, true);
  b.healthy(now + 1500 * kMs, true);
  b.healthy(now + 1510 * kMs, false);
  b.healthy(now + 1520 * kMs, true);
  b.healthy(now + 3000 * kMs, true);
  EXPECT_EQ(b.delay_ns(), 1000 * kMs);
  b.healthy(now + 3520 * kMs, true);
  EXPECT_EQ(b.delay_ns(), 100 * kMs);
}

// GIVEN a loss, THEN the healthy clock of the connection before it is gone: a new connection
// must be healthy for reset_after on its own.
TEST(ReconnectBackoff, ALossRestartsTheHealthyClock) {
  ReconnectBackoff b(100 * kMs, 1000 * kMs, 2000 * kMs);
  b.healthy(0, true);
  const core::TimeNs next = b.lost(1000 * kMs);  // 1 s healthy: not enough
  EXPECT_EQ(next, 1100 * kMs);
  b.healthy(next, true);
  b.healthy(next + 1500 * kMs, true);
  EXPECT_EQ(b.delay_ns(), 200 * kMs);
}

// lost() and healthy() run on the I/O thread: no allocation.
TEST(ReconnectBackoff, AllocatesNothing) {
  ReconnectBackoff b(100 * kMs, 1000 * kMs, 2000 * kMs);
  test::AllocationScope scope;
  core::TimeNs now = 0;
  for (int i = 0; i < 100; ++i) {
    now = b.lost(now);
    b.healthy(now, (i % 3) != 0);
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
}

}  // namespace
}  // namespace nccomp::drivers
