#include "core/rt/spsc_ring.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>

#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::rt {
namespace {

// Tracks constructions and destructions so the ring's placement-new lifecycle can be checked.
struct Tracked {
  static inline int live = 0;
  int value;
  explicit Tracked(int v) noexcept : value(v) { ++live; }
  Tracked(const Tracked& o) noexcept : value(o.value) { ++live; }
  Tracked(Tracked&& o) noexcept : value(o.value) { ++live; }
  Tracked& operator=(const Tracked&) = default;
  Tracked& operator=(Tracked&&) = default;
  ~Tracked() { --live; }
};

TEST(SpscRing, GivenBadCapacity_WhenConstructed_ThenThrows) {
  EXPECT_THROW(SpscRing<int>(0), std::invalid_argument);
  EXPECT_THROW(SpscRing<int>(1), std::invalid_argument);
  EXPECT_THROW(SpscRing<int>(12), std::invalid_argument);
  EXPECT_NO_THROW(SpscRing<int>(16));
}

TEST(SpscRing, GivenEmptyRing_WhenPopped_ThenNothing) {
  SpscRing<int> ring(4);
  int out = -1;
  EXPECT_FALSE(ring.try_pop(out));
  EXPECT_EQ(ring.front(), nullptr);
  EXPECT_EQ(out, -1);
  EXPECT_EQ(ring.size_approx(), 0U);
}

TEST(SpscRing, GivenFullRing_WhenPushed_ThenRefusedAndContentKept) {
  SpscRing<int> ring(4);
  for (int i = 0; i < 4; ++i) {
    ASSERT_TRUE(ring.try_push(i));
  }
  EXPECT_FALSE(ring.try_push(99));
  EXPECT_EQ(ring.size_approx(), 4U);
  EXPECT_EQ(ring.free_slots(), 0U);
  for (int i = 0; i < 4; ++i) {
    int out = -1;
    ASSERT_TRUE(ring.try_pop(out));
    EXPECT_EQ(out, i);
  }
  EXPECT_EQ(ring.front(), nullptr);
}

TEST(SpscRing, GivenManyLaps_WhenPushedAndPopped_ThenOrderKeptAcrossWrapAround) {
  SpscRing<std::uint64_t> ring(8);
  std::uint64_t next_in = 0;
  std::uint64_t next_out = 0;
  for (int lap = 0; lap < 1000; ++lap) {
    const int n = 1 + lap % 8;
    for (int i = 0; i < n; ++i) {
      ASSERT_TRUE(ring.try_push(next_in++));
    }
    for (int i = 0; i < n; ++i) {
      std::uint64_t v = 0;
      ASSERT_TRUE(ring.try_pop(v));
      ASSERT_EQ(v, next_out++);
    }
  }
  EXPECT_EQ(next_out, next_in);
}

TEST(SpscRing, GivenTrackedElements_WhenPoppedOrDestroyed_ThenEveryConstructionDestroyed) {
  Tracked::live = 0;
  {
    SpscRing<Tracked> ring(4);
    ASSERT_TRUE(ring.try_emplace(1));
    ASSERT_TRUE(ring.try_emplace(2));
    ASSERT_TRUE(ring.try_push(Tracked(3)));
    EXPECT_EQ(Tracked::live, 3);
    ASSERT_NE(ring.front(), nullptr);
    EXPECT_EQ(ring.front()->value, 1);
    ring.pop();
    EXPECT_EQ(Tracked::live, 2);
  }
  EXPECT_EQ(Tracked::live, 0);
}

TEST(SpscRing, GivenConstructedRing_WhenPushingAndPopping_ThenNoAllocation) {
  SpscRing<std::uint64_t> ring(1024);
  test::AllocationScope scope;
  for (std::uint64_t i = 0; i < 100000; ++i) {
    ASSERT_TRUE(ring.try_push(i));
    std::uint64_t v = 0;
    ASSERT_TRUE(ring.try_pop(v));
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
}

TEST(SpscRing, Layout_IndicesOnSeparateCacheLines) {
  static_assert(alignof(SpscRing<int>) >= kCacheLine);
  static_assert(sizeof(SpscRing<int>) >= 3 * kCacheLine);
  static_assert(noexcept(std::declval<SpscRing<int>&>().try_push(1)));
  static_assert(noexcept(std::declval<SpscRing<int>&>().front()));
  SUCCEED();
}

// Two threads, ten million items (also under ThreadSanitizer): order kept, nothing lost, nothing
// duplicated. The consumer checks every value against its own count; the loop ends on the count,
// so the item-count check is the ring being empty afterwards.
TEST(SpscRing, GivenTwoThreads_WhenTenMillionItemsPass_ThenOrderAndCountExact) {
  constexpr std::uint64_t kItems = 10'000'000;
  SpscRing<std::uint64_t> ring(1024);
  std::atomic<bool> start{false};
  std::thread producer([&] {
    while (!start.load(std::memory_order_acquire)) {
    }
    for (std::uint64_t i = 0; i < kItems;) {
      if (ring.try_push(i)) {
        ++i;
      } else {
        std::this_thread::yield();  // full: let the consumer run (2 shared cores in CI)
      }
    }
  });
  start.store(true, std::memory_order_release);
  std::uint64_t expected = 0;
  std::uint64_t mismatches = 0;
  std::uint64_t last = ~std::uint64_t{0};
  while (expected < kItems) {
    std::uint64_t v = 0;
    if (ring.try_pop(v)) {
      mismatches += (v != expected) ? 1U : 0U;
      last = v;
      ++expected;
    } else {
      std::this_thread::yield();  // empty
    }
  }
  producer.join();
  EXPECT_EQ(mismatches, 0U);
  EXPECT_EQ(last, kItems - 1);
  std::uint64_t extra = 0;
  EXPECT_FALSE(ring.try_pop(extra));
}

}  // namespace
}  // namespace nccomp::core::rt
