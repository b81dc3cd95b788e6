#include "core/rt/config_swap.hpp"

#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>

#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::rt {
namespace {

struct Config {
  static inline std::atomic<int> live{0};
  std::uint64_t generation;
  std::array<std::uint64_t, 8> payload{};
  explicit Config(std::uint64_t g) : generation(g) {
    payload.fill(g);
    live.fetch_add(1);
  }
  ~Config() { live.fetch_sub(1); }
  Config(const Config&) = delete;
  Config& operator=(const Config&) = delete;
};

TEST(ConfigSwap, GivenNothingPublished_WhenPickedUp_ThenUnchanged) {
  ConfigSwap<Config> swap(std::make_unique<Config>(1));
  EXPECT_FALSE(swap.pickup());
  EXPECT_EQ(swap.current().generation, 1U);
}

TEST(ConfigSwap, GivenPublished_WhenPickedUp_ThenNewInForceAndOldReclaimedElsewhere) {
  Config::live = 0;
  {
    ConfigSwap<Config> swap(std::make_unique<Config>(1));
    swap.publish(std::make_unique<Config>(2));
    EXPECT_TRUE(swap.pending());
    EXPECT_EQ(swap.current().generation, 1U);  // not before the cycle boundary
    EXPECT_TRUE(swap.pickup());
    EXPECT_EQ(swap.current().generation, 2U);
    EXPECT_EQ(Config::live.load(), 2);  // old one retired, not yet freed
    EXPECT_EQ(swap.reclaim(), 1U);
    EXPECT_EQ(Config::live.load(), 1);
  }
  EXPECT_EQ(Config::live.load(), 0);
}

TEST(ConfigSwap, GivenTwoPublishedBeforePickup_WhenPickedUp_ThenNewestWinsAndNoLeak) {
  Config::live = 0;
  {
    ConfigSwap<Config> swap(std::make_unique<Config>(1));
    swap.publish(std::make_unique<Config>(2));
    swap.publish(std::make_unique<Config>(3));  // supersedes 2, freed by the publisher
    EXPECT_EQ(Config::live.load(), 2);
    EXPECT_TRUE(swap.pickup());
    EXPECT_EQ(swap.current().generation, 3U);
  }
  EXPECT_EQ(Config::live.load(), 0);
}

TEST(ConfigSwap, GivenRetireRingFull_WhenPickedUp_ThenKeepsCurrentUntilReclaimed) {
  ConfigSwap<Config> swap(std::make_unique<Config>(0), 2);
  for (std::uint64_t g = 1; g <= 2; ++g) {
    swap.publish(std::make_unique<Config>(g));
    ASSERT_TRUE(swap.pickup());
  }
  swap.publish(std::make_unique<Config>(3));
  EXPECT_FALSE(swap.pickup());  // no room to retire: never free on the loop thread
  EXPECT_EQ(swap.current().generation, 2U);
  EXPECT_EQ(swap.reclaim(), 2U);
  EXPECT_TRUE(swap.pickup());
  EXPECT_EQ(swap.current().generation, 3U);
}

// The loop thread neither allocates nor frees when it takes a new configuration: the old one is
// freed by reclaim() on the builder's thread (counted there, not on the loop thread).
TEST(ConfigSwap, GivenPending_WhenLoopPicksUp_ThenNoAllocationAndNoFreeOnLoopThread) {
  Config::live = 0;
  ConfigSwap<Config> swap(std::make_unique<Config>(1));
  for (std::uint64_t g = 2; g <= 5; ++g) {
    swap.publish(std::make_unique<Config>(g));
    std::uint64_t loop_allocs = ~std::uint64_t{0};
    std::uint64_t loop_frees = ~std::uint64_t{0};
    bool picked = false;
    std::thread loop([&] {
      test::AllocationScope scope;
      picked = swap.pickup();
      picked = picked && !swap.pickup() && swap.current().generation == g;
      loop_allocs = scope.count();
      loop_frees = scope.frees();
    });
    loop.join();
    EXPECT_TRUE(picked) << "generation " << g;
    EXPECT_EQ(loop_allocs, 0U) << "generation " << g;
    EXPECT_EQ(loop_frees, 0U) << "generation " << g;
    EXPECT_EQ(Config::live.load(), 2);  // the retired one still exists: not freed by the loop
    test::AllocationScope builder;
    EXPECT_EQ(swap.reclaim(), 1U);
    EXPECT_EQ(builder.frees(), 1U);  // freed here, on the builder's thread
    EXPECT_EQ(Config::live.load(), 1);
  }
}

// A loop thread picks up and reads while a builder publishes and reclaims concurrently: the loop
// always sees a whole configuration, generations never go backwards, nothing leaks.
TEST(ConfigSwap, GivenConcurrentPublisher_WhenLoopRuns_ThenConsistentAndNoLeak) {
  Config::live = 0;
  constexpr std::uint64_t kGenerations = 20000;
  {
    ConfigSwap<Config> swap(std::make_unique<Config>(0));
    std::atomic<bool> done{false};
    std::uint64_t bad = 0;
    std::uint64_t backwards = 0;
    std::uint64_t pickups = 0;
    std::thread loop([&] {
      std::uint64_t last = 0;
      while (!done.load(std::memory_order_acquire)) {
        pickups += swap.pickup() ? 1U : 0U;
        const Config& c = swap.current();
        for (auto v : c.payload) {
          bad += (v != c.generation) ? 1U : 0U;
        }
        backwards += (c.generation < last) ? 1U : 0U;
        last = c.generation;
      }
      pickups += swap.pickup() ? 1U : 0U;
    });
    for (std::uint64_t g = 1; g <= kGenerations; ++g) {
      swap.publish(std::make_unique<Config>(g));
      swap.reclaim();
    }
    while (swap.pending()) {
      swap.reclaim();
      std::this_thread::yield();
    }
    done.store(true, std::memory_order_release);
    loop.join();
    EXPECT_EQ(bad, 0U);
    EXPECT_EQ(backwards, 0U);
    EXPECT_GT(pickups, 0U);
    EXPECT_EQ(swap.current().generation, kGenerations);
  }
  EXPECT_EQ(Config::live.load(), 0);
}

}  // namespace
}  // namespace nccomp::core::rt
