// GIVEN the loop's deadline policy and latency histogram, WHEN fed with a fake clock, THEN the
// loop recovers from an overrun without a burst and the quantiles are the data's.
#include "daemon/timing.hpp"
#include "daemon/logging.hpp"

#include <gtest/gtest.h>

#include <array>
#include <vector>

namespace nccomp::daemon {
namespace {

using config::OverrunPolicy;
constexpr TimeNs kP = 1'000'000;  // 1 ms

TEST(AdvanceDeadline, OnTimeStaysOnTheGrid) {
  const auto d = advance_deadline(10 * kP, 10 * kP + 300'000, kP, OverrunPolicy::kSkipMissed);
  EXPECT_EQ(d.next_ns, 11 * kP);
  EXPECT_EQ(d.missed, 0U);
}

TEST(AdvanceDeadline, SkipMissedKeepsThePhase) {
  // Cycle for deadline 10 ms finished at 13.4 ms: 11, 12, 13 are past; next is 14.
  const auto d = advance_deadline(10 * kP, 13 * kP + 400'000, kP, OverrunPolicy::kSkipMissed);
  EXPECT_EQ(d.next_ns, 14 * kP);
  EXPECT_EQ(d.missed, 3U);
  // Finishing exactly on the next deadline is an overrun of one.
  const auto e = advance_deadline(10 * kP, 11 * kP, kP, OverrunPolicy::kSkipMissed);
  EXPECT_EQ(e.next_ns, 12 * kP);
  EXPECT_EQ(e.missed, 1U);
}

TEST(AdvanceDeadline, RestartStartsANewGridAfterTheLateWakeUp) {
  const auto d = advance_deadline(10 * kP, 13 * kP + 400'000, kP, OverrunPolicy::kRestart);
  EXPECT_EQ(d.next_ns, 14 * kP + 400'000);
  EXPECT_EQ(d.missed, 3U);
}

// ros2_control's recovers_from_overrun, for both policies: one cycle takes 3.5 periods; the loop
// must not run a burst of back-to-back cycles afterwards, and must be on a regular period again.
class RecoversFromOverrun : public ::testing::TestWithParam<OverrunPolicy> {};

TEST_P(RecoversFromOverrun, NoBurstAndRegularAfterwards) {
  TimeNs deadline = kP;
  std::vector<TimeNs> wakes;
  std::uint64_t overruns = 0;
  for (int cycle = 0; cycle < 20; ++cycle) {
    const TimeNs wake = deadline + 50'000;  // 50 µs latency
    wakes.push_back(wake);
    const TimeNs work = cycle == 5 ? 3 * kP + kP / 2 : 200'000;
    const TimeNs done = wake + work;
    const auto next = advance_deadline(deadline, done, kP, GetParam());
    if (next.missed > 0) {
      ++overruns;
    }
    ASSERT_GT(next.next_ns, done) << "a deadline in the past would start a catch-up burst";
    deadline = next.next_ns;
  }
  EXPECT_EQ(overruns, 1U);
  // After the overrun, the gaps between wake-ups are one period again.
  for (std::size_t i = 8; i < wakes.size(); ++i) {
    EXPECT_EQ(wakes[i] - wakes[i - 1], kP) << i;
  }
  // The gap across the overrun covers the long cycle: no wake-up was squeezed in.
  EXPECT_GE(wakes[6] - wakes[5], 3 * kP + kP / 2);
}

INSTANTIATE_TEST_SUITE_P(Policies, RecoversFromOverrun,
                         ::testing::Values(OverrunPolicy::kSkipMissed, OverrunPolicy::kRestart));

TEST(HeartbeatWatch, FeedsOnlyWhileTheLoopAdvances) {
  HeartbeatWatch w(100);
  EXPECT_FALSE(w.advanced(100));  // no cycle since start: a loop stuck before its first cycle
  EXPECT_TRUE(w.advanced(150));
  EXPECT_TRUE(w.advanced(151));
  EXPECT_FALSE(w.advanced(151));  // stalled: systemd's WatchdogSec runs out → restart
  EXPECT_FALSE(w.advanced(151));
  EXPECT_TRUE(w.advanced(152));  // recovered
}

TEST(LatencyHistogram, BucketsAreContiguousAndContainTheirValues) {
  std::uint64_t prev_edge = 0;
  for (std::size_t b = 0; b < LatencyHistogram::kBuckets - 1; ++b) {
    const std::uint64_t edge = LatencyHistogram::upper_edge_us(b);
    ASSERT_GT(edge, prev_edge) << b;
    // The last value below the edge maps to this bucket, the edge to the next.
    ASSERT_EQ(LatencyHistogram::bucket_of(edge - 1), b) << b;
    ASSERT_EQ(LatencyHistogram::bucket_of(edge), b + 1) << b;
    prev_edge = edge;
  }
  // Resolution: 1 µs below 1024 µs, ≤ 1/64 relative above.
  EXPECT_EQ(LatencyHistogram::upper_edge_us(LatencyHistogram::bucket_of(5000)), 5056U);
}

TEST(LatencyHistogram, QuantilesOfKnownData) {
  LatencyHistogram h;
  EXPECT_DOUBLE_EQ(h.quantile_us(0.5), 0.0);
  // 900 samples at 10 µs, 90 at 100 µs, 9 at 2000 µs, 1 at 50 ms.
  for (int i = 0; i < 900; ++i) h.record(10'500);
  for (int i = 0; i < 90; ++i) h.record(100'200);
  for (int i = 0; i < 9; ++i) h.record(2'000'000);
  h.record(50'000'000);
  EXPECT_EQ(h.count(), 1000U);
  EXPECT_DOUBLE_EQ(h.quantile_us(0.5), 11.0);
  EXPECT_DOUBLE_EQ(h.quantile_us(0.99), 101.0);
  EXPECT_DOUBLE_EQ(h.quantile_us(0.999), 2016.0);  // 2000 µs bucket [2000, 2016)
  EXPECT_EQ(h.max_ns(), 50'000'000);
  h.record(-5);  // a clock oddity counts as 0, not as a huge unsigned value
  EXPECT_EQ(h.count(), 1001U);
  h.reset();
  EXPECT_EQ(h.count(), 0U);
}

// The Prometheus histogram's buckets: samples below each edge, counted by hand from the data.
TEST(LatencyHistogram, CountsBelowEdgesAndSumOfKnownData) {
  LatencyHistogram h;
  // 3 samples at 9.999 µs, 2 at 10 µs, 1 at 1999 µs, 1 at 2000 µs, 1 at 7999.9 µs, 1 at 1 s.
  for (int i = 0; i < 3; ++i) h.record(9'999);
  for (int i = 0; i < 2; ++i) h.record(10'000);
  h.record(1'999'000);
  h.record(2'000'000);
  h.record(7'999'900);
  h.record(1'000'000'000);
  const std::array<std::uint64_t, 6> edges = {10, 11, 2000, 2016, 8000, 128000};
  for (const std::uint64_t e : edges) {
    ASSERT_TRUE(LatencyHistogram::is_edge_us(e)) << e;
  }
  std::array<std::uint64_t, 6> below{};
  std::uint64_t total = 0;
  h.count_below_us(edges, below, total);
  EXPECT_EQ(below[0], 3U);  // < 10 µs
  EXPECT_EQ(below[1], 5U);  // < 11 µs
  EXPECT_EQ(below[2], 6U);  // < 2000 µs: 1999 µs is in bucket [1984, 2000)
  EXPECT_EQ(below[3], 7U);  // < 2016 µs
  EXPECT_EQ(below[4], 8U);  // < 8000 µs: 7999.9 µs is in bucket [7936, 8000)
  EXPECT_EQ(below[5], 8U);  // < 128 ms
  EXPECT_EQ(total, 9U);
  EXPECT_DOUBLE_EQ(
      h.sum_s(),
      (3 * 9'999 + 2 * 10'000 + 1'999'000 + 2'000'000 + 7'999'900 + 1'000'000'000) / 1e9);
  h.reset();
  EXPECT_DOUBLE_EQ(h.sum_s(), 0.0);
}

}  // namespace
}  // namespace nccomp::daemon

namespace {

using nccomp::daemon::NoteThrottle;

TEST(NoteThrottle, TheFirstNoteIsLoggedAtOnceAndTheRestOncePerIntervalWithTheirCount) {
  NoteThrottle t(1'000'000'000);
  EXPECT_EQ(t.add(5'000'000'000), 1U);  // the first one: a line at once
  // A note every millisecond for the next 2.5 s: one line per second, each counting all notes
  // since the previous line (1000 each), none in between.
  std::uint64_t lines = 0;
  std::uint64_t counted = 0;
  for (int ms = 1; ms <= 2500; ++ms) {
    const std::uint64_t n = t.add(5'000'000'000 + static_cast<std::int64_t>(ms) * 1'000'000);
    if (n > 0) {
      ++lines;
      counted += n;
      EXPECT_EQ(n, 1000U) << "at " << ms << " ms";
    }
  }
  EXPECT_EQ(lines, 2U);
  EXPECT_EQ(counted + t.pending(), 2500U);  // nothing lost: 500 still pending
  EXPECT_EQ(t.pending(), 500U);
}

TEST(NoteThrottle, ANoteAfterAQuietIntervalIsLoggedAtOnce) {
  NoteThrottle t(1'000'000'000);
  EXPECT_EQ(t.add(0), 1U);
  EXPECT_EQ(t.add(999'999'999), 0U);
  EXPECT_EQ(t.add(3'000'000'000), 2U);
  EXPECT_EQ(t.pending(), 0U);
}

}  // namespace
