// A counting global operator new for tests that prove code paths allocate nothing.
// Link the OBJECT library `nccomp_test_alloc_counter`; it replaces every form of operator new.
// Counts are per thread, so a test measures only the thread it runs on.
#pragma once

#include <cstdint>

namespace nccomp::test {

/// Allocations made by the calling thread since it started.
std::uint64_t thread_allocations() noexcept;

/// Counts the calling thread's allocations between construction and count().
class AllocationScope {
 public:
  AllocationScope() noexcept : start_(thread_allocations()) {}
  [[nodiscard]] std::uint64_t count() const noexcept { return thread_allocations() - start_; }

 private:
  std::uint64_t start_;
};

}  // namespace nccomp::test
