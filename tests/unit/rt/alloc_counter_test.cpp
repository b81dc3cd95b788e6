// The counting operator new / delete of tests/support counts what it claims to count: every
// zero-allocation test in the repository relies on it, so a counter that silently stopped
// reaching the link (or missed a form of operator new) would let all of them pass vacuously.
#include "tests/support/alloc_counter.hpp"

#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <string>
#include <thread>
#include <vector>

namespace nccomp::test {
namespace {

// Keeps the optimiser from dropping a new/delete pair (new-expressions may be elided).
void escape(const void* p) { __asm__ __volatile__("" : : "r"(p) : "memory"); }

struct alignas(128) OverAligned {
  std::byte bytes[128];
};

TEST(AllocCounter, GivenPlainNewAndDelete_ThenOneAllocationAndOneFree) {
  AllocationScope scope;
  int* p = new int(42);
  escape(p);
  EXPECT_EQ(scope.count(), 1U);
  EXPECT_EQ(scope.frees(), 0U);
  delete p;
  EXPECT_EQ(scope.count(), 1U);
  EXPECT_EQ(scope.frees(), 1U);
}

TEST(AllocCounter, GivenArrayNewAndDelete_ThenCounted) {
  AllocationScope scope;
  int* p = new int[64];
  escape(p);
  delete[] p;
  EXPECT_EQ(scope.count(), 1U);
  EXPECT_EQ(scope.frees(), 1U);
}

TEST(AllocCounter, GivenNothrowForms_ThenCounted) {
  AllocationScope scope;
  void* a = ::operator new(32, std::nothrow);
  void* b = ::operator new[](32, std::nothrow);
  ASSERT_NE(a, nullptr);
  ASSERT_NE(b, nullptr);
  ::operator delete(a, std::nothrow);
  ::operator delete[](b, std::nothrow);
  EXPECT_EQ(scope.count(), 2U);
  EXPECT_EQ(scope.frees(), 2U);
}

TEST(AllocCounter, GivenAlignedForms_ThenCountedAndAligned) {
  AllocationScope scope;
  auto* o = new OverAligned;  // operator new(size_t, align_val_t)
  escape(o);
  EXPECT_EQ(reinterpret_cast<std::uintptr_t>(o) % 128, 0U);
  delete o;  // operator delete(void*, size_t, align_val_t)
  auto* arr = new OverAligned[3];
  escape(arr);
  EXPECT_EQ(reinterpret_cast<std::uintptr_t>(arr) % 128, 0U);
  delete[] arr;
  void* n = ::operator new (100, std::align_val_t{64}, std::nothrow);
  void* m = ::operator new[](100, std::align_val_t{64}, std::nothrow);
  ASSERT_NE(n, nullptr);
  ASSERT_NE(m, nullptr);
  EXPECT_EQ(reinterpret_cast<std::uintptr_t>(n) % 64, 0U);
  ::operator delete (n, std::align_val_t{64}, std::nothrow);
  ::operator delete[](m, std::align_val_t{64}, std::nothrow);
  void* s = ::operator new (10, std::align_val_t{256});
  ::operator delete (s, std::align_val_t{256});
  EXPECT_EQ(scope.count(), 5U);
  EXPECT_EQ(scope.frees(), 5U);
}

TEST(AllocCounter, GivenSizedDelete_ThenCounted) {
  AllocationScope scope;
  void* p = ::operator new(48);
  ::operator delete (p, std::size_t{48});
  void* q = ::operator new[](48);
  ::operator delete[](q, std::size_t{48});
  EXPECT_EQ(scope.count(), 2U);
  EXPECT_EQ(scope.frees(), 2U);
}

TEST(AllocCounter, GivenDeleteOfNull_ThenNotAFree) {
  AllocationScope scope;
  int* p = nullptr;
  escape(&p);
  delete p;
  ::operator delete(nullptr);
  EXPECT_EQ(scope.frees(), 0U);
}

// The standard library's containers allocate through operator new: a zero count around a
// push_back that had to grow would be a lie.
TEST(AllocCounter, GivenLibraryContainers_ThenTheirAllocationsAreCounted) {
  AllocationScope scope;
  {
    std::vector<double> v;
    v.reserve(1000);
    escape(v.data());
    std::string s(200, 'x');
    escape(s.data());
    auto u = std::make_unique<int>(3);
    escape(u.get());
    auto sp = std::make_shared<std::vector<int>>(10);
    escape(sp.get());
  }
  EXPECT_GE(scope.count(), 5U);  // vector, string, unique_ptr, shared control block, its vector
  EXPECT_EQ(scope.frees(), scope.count());
}

// Counts are per thread: another thread's allocations do not appear in this thread's scope.
TEST(AllocCounter, GivenAnotherThreadAllocates_ThenThisThreadCountsNothing) {
  std::uint64_t other_allocs = 0;
  std::uint64_t other_frees = 0;
  AllocationScope scope;
  std::thread t([&] {
    AllocationScope inner;
    for (int i = 0; i < 100; ++i) {
      int* p = new int(i);
      escape(p);
      delete p;
    }
    other_allocs = inner.count();
    other_frees = inner.frees();
  });
  t.join();
  // std::thread's own start-up state is allocated by this thread (not by the new one).
  const std::uint64_t here = scope.count();
  EXPECT_EQ(other_allocs, 100U);
  EXPECT_EQ(other_frees, 100U);
  EXPECT_LT(here, 100U);
}

}  // namespace
}  // namespace nccomp::test
