// A counting global operator new / operator delete for tests that prove code paths allocate and
// free nothing. Link the OBJECT library `nccomp_test_alloc_counter`; it replaces every
// replaceable form of operator new and operator delete (plain, array, nothrow, aligned, sized,
// and their combinations). Counts are per thread, so a test measures only the thread it runs on.
// The self-test (tests/unit/rt/alloc_counter_test.cpp) shows that each form is counted, so a
// zero count means "nothing allocated", not "the counter was not linked".
#pragma once

#include <cstdint>

namespace nccomp::test {

/// Allocations (any operator new) made by the calling thread since it started.
std::uint64_t thread_allocations() noexcept;
/// Deallocations (any operator delete of a non-null pointer) made by the calling thread.
std::uint64_t thread_deallocations() noexcept;

/// Counts the calling thread's allocations and frees between construction and count()/frees().
class AllocationScope {
 public:
  AllocationScope() noexcept
      : alloc_start_(thread_allocations()), free_start_(thread_deallocations()) {}
  /// Allocations since construction.
  [[nodiscard]] std::uint64_t count() const noexcept { return thread_allocations() - alloc_start_; }
  /// Deallocations since construction.
  [[nodiscard]] std::uint64_t frees() const noexcept {
    return thread_deallocations() - free_start_;
  }

 private:
  std::uint64_t alloc_start_;
  std::uint64_t free_start_;
};

}  // namespace nccomp::test
