#include "core/rt/seqlock.hpp"

#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <thread>

#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::rt {
namespace {

// Every word holds the same generation number and a checksum: a torn copy is detectable.
struct Snapshot {
  std::array<std::uint64_t, 15> words{};
  std::uint64_t check{0};
};

Snapshot make(std::uint64_t gen) {
  Snapshot s;
  for (std::size_t i = 0; i < s.words.size(); ++i) {
    s.words[i] = gen * 31U + i;
  }
  s.check = gen ^ 0x5a5a5a5a5a5a5a5aULL;
  return s;
}

bool consistent(const Snapshot& s) {
  const std::uint64_t gen = s.words[0] / 31U;
  for (std::size_t i = 0; i < s.words.size(); ++i) {
    if (s.words[i] != gen * 31U + i) {
      return false;
    }
  }
  return s.check == (gen ^ 0x5a5a5a5a5a5a5a5aULL);
}

TEST(Seqlock, GivenStore_WhenLoaded_ThenSameValue) {
  Seqlock<Snapshot> lock;
  EXPECT_EQ(lock.version(), 1U);
  lock.store(make(7));
  const Snapshot s = lock.load();
  EXPECT_TRUE(consistent(s));
  EXPECT_EQ(s.words[0], 7U * 31U);
  EXPECT_EQ(lock.version(), 2U);
}

TEST(Seqlock, GivenOddSizedPayload_WhenRoundTripped_ThenExact) {
  struct Odd {
    double a;
    std::uint8_t b;
    std::uint16_t c;
  };
  Seqlock<Odd> lock(Odd{1.5, 3, 700});
  const Odd o = lock.load();
  EXPECT_DOUBLE_EQ(o.a, 1.5);
  EXPECT_EQ(o.b, 3);
  EXPECT_EQ(o.c, 700);
}

TEST(Seqlock, GivenConstructedLock_WhenStoringAndLoading_ThenNoAllocation) {
  Seqlock<Snapshot> lock;
  test::AllocationScope scope;
  for (std::uint64_t g = 0; g < 10000; ++g) {
    lock.store(make(g));
    EXPECT_TRUE(consistent(lock.load()));
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
}

// Readers never see a torn value while a writer stores at full speed.
TEST(Seqlock, GivenWriterAtFullSpeed_WhenTwoReadersCopy_ThenNeverTorn) {
#if defined(NCCOMP_TSAN)
  constexpr std::uint64_t kWrites = 300'000;
#else
  constexpr std::uint64_t kWrites = 3'000'000;
#endif
  Seqlock<Snapshot> lock(make(0));
  std::atomic<bool> done{false};
  std::atomic<std::uint64_t> torn{0};
  std::atomic<std::uint64_t> reads{0};
  std::atomic<std::uint64_t> backwards{0};
  auto reader = [&] {
    std::uint64_t last_gen = 0;
    while (!done.load(std::memory_order_acquire)) {
      const Snapshot s = lock.load();
      if (!consistent(s)) {
        torn.fetch_add(1, std::memory_order_relaxed);
      }
      const std::uint64_t gen = s.words[0] / 31U;
      if (gen < last_gen) {
        backwards.fetch_add(1, std::memory_order_relaxed);
      }
      last_gen = gen;
      reads.fetch_add(1, std::memory_order_relaxed);
    }
  };
  std::thread r1(reader);
  std::thread r2(reader);
  for (std::uint64_t g = 1; g <= kWrites; ++g) {
    lock.store(make(g));
  }
  done.store(true, std::memory_order_release);
  r1.join();
  r2.join();
  EXPECT_EQ(torn.load(), 0U);
  EXPECT_EQ(backwards.load(), 0U);
  EXPECT_GT(reads.load(), 0U);
  EXPECT_TRUE(consistent(lock.load()));
}

}  // namespace
}  // namespace nccomp::core::rt
